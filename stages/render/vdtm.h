// The `vdtm` render model: view-dependent texture mapping with polygon view maps (Debevec, Yu &
// Borshukov, seed 003), on the CPU, per pixel in one pass instead of the paper's three.
//
// Preprocessing is the texture stage's (texture/view_maps.bin, pipeline/core/view_maps.h): per
// face, the training views that see it entirely (visibility, seed 003 §5) and its view map
// (§7); faces no view sees carry the atlas's hole filling (§6, texture/mesh.obj). Per frame:
//  1. per face covered by the desired view: the desired direction d (unit, from the face centroid
//     toward the desired camera centre) is located in the face's view map, BlendFor(maps, face,
//     FaceFrame(n), d): at most three views and their barycentric weights (§7, Fig. 6). Computed
//     once per face per frame, as the paper does per polygon before drawing (§8); views that are
//     not among the sources (held out, missing) or that are the desired view's own photo
//     (leave-one-out) are dropped and the others renormalised; when none remains, the face's
//     remaining view nearest to the desired direction in the map plane takes weight 1 (what the
//     grid would hold without the dropped views: each sample keeps the nearest view, §7);
//  2. per covered pixel (rasterizer: nearest front-facing face, perspective-correct
//     barycentrics; back faces, the inside of the surface that no photo shows, are culled): the
//     world point p from the barycentrics, projected into each of the face's views (projective
//     texture mapping, §4; done as the barycentric blend of the face's corners projected once per
//     frame, the same point since projection is linear in homogeneous coordinates, in float: about
//     1e-4 pixel from the double-precision projection) and sampled bilinearly; colour = sum w_i I_i(p) / sum w_i over the views where p
//     falls inside the image and, when the sources carry the mesh's depth (SourceView::proxy_depth,
//     computed once per render stage: the image-space form of §5's splitting of partly visible
//     polygons), is not behind it by more than visibility_epsilon of its depth. The view maps list
//     views that see the face's centroid, some of them only partly. This sum is what the three
//     additive passes of §8 accumulate.
//     Where the test drops every blended view, the face's next views by map distance are tried
//     in turn (FaceBlend::fallback) and the first that passes gives the colour;
//  3. no usable view (a face seen by none: count 0, §8 "polygons not visible in any image";
//     or no view passes): the atlas colour (textured.h).
// Hole extension (the render stage's proxy_extend_px, shared with ULR's mesh proxies): pixels
// within that many pixels of the mesh's image take the nearest covered pixel's depth and face.
// Known limits kept on purpose (seed 003 §9): weights are continuous in the viewpoint but not
// across faces (seams), and source resolution is ignored.
//
// Face normal convention: the geometric normal (v1 - v0) x (v2 - v0), unit (counter-clockwise
// faces seen from outside), the frame the texture stage builds the view maps in.
#pragma once

#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/rigid3.h"
#include "pipeline/core/textured_mesh.h"
#include "pipeline/core/view_maps.h"
#include "stages/render/render.h"

namespace ibmr {

// A face's blend for one frame, in source indices: up to three sources, weights summing to 1.
struct FaceBlend {
  int count = 0;                     // 0: no usable view; the atlas colour
  std::array<int, 3> sources{};      // indices into the renderer's sources
  std::array<float, 3> weights{};
  // The face's other views nearest to the desired direction in the map plane, nearest first:
  // where the per-pixel test drops every blended view, the first that passes there gives the
  // colour (what the paper's split polygon would take from its own view list).
  int fallback_count = 0;
  std::array<int, 4> fallback{};
};

// Where a frame's covered pixels took their colour from.
struct VdtmStats {
  size_t blended_pixels = 0;  // from at least one source photo
  size_t atlas_pixels = 0;    // from the atlas (no view sees the face, or every projection outside)
};

class VdtmRenderer {
 public:
  // `mesh`, `maps` and `sources` must outlive the renderer. Face i of `maps` is face i of
  // `mesh`; the maps' views are matched to `sources` by name (SourceView::name ==
  // ViewMaps::view_names[v]), and a view with no source is never sampled. Throws InputError when
  // the face counts differ.
  // `visibility_epsilon`: the per-pixel depth test's tolerance (fraction of depth) for sources with
  // a proxy_depth.
  VdtmRenderer(const TexturedMesh* mesh, const ViewMaps* maps, const std::vector<SourceView>* sources,
               double visibility_epsilon = 0.01);

  // Face `face`'s blend for a desired camera centred at `desired_center`; `exclude_source` (an
  // index into the sources, -1: none) is never used (leave-one-out).
  FaceBlend Blend(int face, const Eigen::Vector3d& desired_center, int exclude_source = -1) const;

  // Renders the desired camera (pinhole; distortion ignored). Rows run in parallel (TBB).
  // Supersampling: call with camera.Scaled(factor), then Downsample. `extend_px` > 0: holes within
  // that many pixels of the mesh take the depth and face of the nearest covered pixel
  // (ExtendIntoHoles, render.h), their points on their own rays, as ULR's mesh proxies do.
  RenderResult Render(const Camera& camera, const Rigid3d& cam_from_world, int exclude_source = -1,
                      VdtmStats* stats = nullptr, int extend_px = 0) const;

  // Number of the maps' views that have a source.
  int MatchedViews() const { return matched_views_; }

 private:
  // The direction from face `face` toward the desired centre, in the face's view map plane.
  Eigen::Vector2d MapToFace(int face, const Eigen::Vector3d& desired_center) const;
  // Blend's views and weights, without the fallbacks, at direction `mapped` (MapToFace);
  // `may_fall_back`: false when the map triangle's views were all dropped and the nearest
  // remaining view was taken (no fallback then).
  FaceBlend BlendViews(int face, const Eigen::Vector2d& mapped, int exclude_source, bool* may_fall_back) const;
  // Fills blend->fallback: the face's views nearest to `mapped` that are sources, not blended and
  // not `exclude_source`, nearest first (at most four).
  void AddFallbacks(int face, const Eigen::Vector2f& mapped, int exclude_source, FaceBlend* blend) const;

  struct Prepared {  // per source: projection constants
    Eigen::Matrix3d rotation;
    Eigen::Vector3d translation;
    double fx, fy, cx, cy;
    int width, height;
  };

  const TexturedMesh* mesh_;
  const ViewMaps* maps_;
  const std::vector<SourceView>* sources_;
  std::vector<int> source_of_view_;  // per view of the maps: index into sources, -1 when absent
  std::vector<Prepared> prepared_;
  int matched_views_ = 0;
  double visibility_epsilon_ = 0.01;
};

}  // namespace ibmr
