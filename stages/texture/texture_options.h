// Options of the texture stage (inverse texture mapping, seed 000 §6 lines 4587-4654; view maps,
// seed 003 §5-7), with Check() naming the first invalid one.
#pragma once

#include <string>

namespace ibmr {

struct TextureOptions {
  // Weight of the Potts smoothness term of the view selection (a face labelled unlike a neighbour
  // costs this much; data costs are qualities normalised to [-1, 0]). 0: each face its best view.
  double smoothness = 0.3;
  int max_iterations = 30;         // sweeps of iterated conditional modes (stops earlier when stable)
  // A face is seen by a view when its vertices and centroid pass the z-buffer test within this
  // fraction of their depth (seed 003 §5 samples points of each polygon against the item buffer).
  double visibility_epsilon = 0.005;
  double min_cos_angle = 0.05;     // faces seen more obliquely than this (cosine) are not used
  // Views whose mean luminance of a face differs from the median of its views by more than this
  // fraction (at least 20 levels) are not used for it (photo-consistency); 0: keep every view.
  double consistency_tolerance = 0.25;
  bool gain_compensation = true;   // per-view exposure gains, solved jointly
  double gain_sigma = 0.3;         // prior on the gains: sigma of (gain - 1)
  bool seam_leveling = true;       // per-vertex colour offsets, sparse least squares
  double leveling_smoothness = 10; // weight of equal offsets along a patch's edges against seam steps
  int max_texture_size = 4096;     // atlas pages are at most this many texels wide and high
  int padding = 2;                 // texels of image around each patch (edge bleeding)
  int hole_cell = 4;               // texels of the square cell of a face no view sees
  int view_map_grid = 24;          // samples per side of each face's view map (seed 003 §7)
  // A view that sees a face only partly (a corner or its centroid hidden, or from behind its
  // normal) counts this much farther (radians in the map plane) when the view map's samples pick
  // their nearest view: such views fill the directions no whole view is near, and the renderer's
  // per-pixel depth test keeps the parts they see (seed 003 splits the polygon instead).
  double view_map_partial_penalty = 0.3;

  bool Check(std::string* error) const;
};

}  // namespace ibmr
