// Surfaces from fused points by oriented particles (surfels) and their triangulation: seed 000
// section 5 (lines 4454-4586), after Szeliski & Tonnesen, "Surface modeling with oriented particle
// systems" (SIGGRAPH 1992). Steps:
//  1. Spacing: the particles' spacing is `spacing_scale` times the median pixel footprint of the
//     fused points (depth / focal length in the nearest-resolution training view that sees them),
//     so the particles are as dense as the photographs support.
//  2. Particles: the fused points averaged per cell of that size (confidence-weighted position,
//     normal, colour; seed 000 section 4's uncertainty survives as the confidence). Points without
//     normals get them from the principal axes of their neighbours, turned toward a camera.
//  3. Pruning: particles that training depth maps see through (free space: a view saw a surface
//     behind them along its ray) in `free_space_views` views or more, particles that land on the
//     background of `silhouette_views` training masks or more (when set), particles outside the hull
//     (when a closed hull mesh is given), and particles with too little data nearby or too few
//     particle neighbours (outliers) are deleted.
//  4. Relaxation: the energy of surfel_potentials.h (co-planarity, co-normality, co-circularity,
//     repulsion and the confidence-weighted data term, the confidences relative to the points'
//     median, so that their calibration does not tip the balance) is lowered by Jacobi sweeps of
//     preconditioned gradient steps: every particle moves by its gradient divided by an upper
//     estimate of its local curvature, all from the previous sweep's state. Why not Ceres: the
//     energy is a sum of short-range pair terms whose neighbour sets change as particles move, so
//     the problem would be rebuilt at every step; local steps are cheap, parallel (TBB), and
//     deterministic (no dependence on thread scheduling, unlike in-place Gauss-Seidel).
//  5. Growth (the stretching rule): between two neighbours whose normals agree and whose distance
//     is more than `stretch_distance` but less than `max_gap` spacings, with no particle near the
//     midpoint, a particle is added there; rounds of growth and relaxation alternate. Gaps wider than
//     `max_gap` stay open, so holes in the data stay holes. The paper's second rule (growing in
//     every tangent direction where a particle has too few neighbours, lines ~4530-4545) is left
//     out on purpose: the particles start from every fused point's cell, so the surface is already
//     covered where there is data, and growing past the data would close the holes the rule above
//     keeps open.
//  6. Triangulation (surfel_mesh.cc, CGAL advancing front): the particles are connected into a
//     manifold mesh whose edges are at most `max_edge` spacings, so it never spans a hole wider
//     than that; faces are oriented by the particles' normals. Pieces of fewer than
//     `min_component_faces` faces are dropped, and openings bounded by at most `max_hole_edges`
//     edges are closed (mesh_cleaning.cc); larger ones stay open. The open borders left then move
//     out by `border_extension` spacings in the surface's tangent plane, to the edge of the border
//     particles' discs rather than their centres.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/rigid3.h"
#include "stages/surfels/surfel_potentials.h"

namespace ibmr {

struct SurfelOptions {
  double spacing_scale = 3.5;      // particle spacing / median pixel footprint of the points, in (0, 100]
  double spacing = -1;             // fixed spacing in scene units (> 0); -1: from the footprints
  int iterations = 15;             // relaxation sweeps per round, in [0, 1000]
  int grow_rounds = 1;             // rounds of growth, each followed by relaxation, in [0, 20]
  ParticleWeights weights;         // potentials (unitless; lengths in spacings), each >= 0
  double stretch_distance = 1.6;   // pairs farther apart than this (spacings) get a midpoint particle, in [1, max_gap)
  double max_gap = 4.0;            // ... unless farther than this (spacings): a hole, in (1, 20]
  double max_normal_angle_deg = 35;  // growth only between neighbours whose normals agree within this, (0, 180]
  int min_support = 3;             // fused points within support_radius needed to keep a particle, in [0, 1000]
  double support_radius = 1.5;     // spacings, in (0, 20]
  double min_support_fraction = 0;  // ... and at least this fraction of the median particle's, in [0, 1]
                                    // (0.2 cost templeRing 0.4 dB held out: it thins the surface too)
  int min_neighbours = 3;          // particles within 2.5 spacings needed to keep a particle, in [0, 100]
  int free_space_views = 2;        // delete a particle that this many depth maps see through, in [1, 1000]
  int silhouette_views = 0;        // delete a particle that lands on this many views' background (masks); 0: off, in [0, 1000]
  int silhouette_color_tolerance = 0;  // ... counting only views whose photo there differs from the particle's
                                   // colour by more than this (largest channel, grey levels): a dark
                                   // backdrop the masks leave out matches its own colour; 0: every
                                   // background landing counts, in [0, 255]
  double free_space_margin = 3.0;  // "see through": the map's depth exceeds the particle's by this many
                                   // spacings and by 0.5% of the depth, in (0, 1000]
  double max_edge = 4.0;           // longest triangle edge, spacings, in [1, 20]
  int max_hole_edges = 24;         // close mesh holes bounded by at most this many edges, in [0, 1000]
  int min_component_faces = 50;    // drop mesh pieces with fewer faces than this, in [0, 1e6]
  double border_extension = 0.75;  // open borders move out by this (spacings): to the border discs' rims, in [0, 2]
  int max_particles = 2000000;     // refuse to run beyond this many particles (memory), in [1000, 5e7]

  bool Check(std::string* error) const;  // error starts with the YAML key
};

// A training view: its camera gives footprints; its depth map (optional) gives free space.
struct SurfelView {
  Camera camera;  // undistorted (pinhole)
  Rigid3d cam_from_world;
  DepthMap depth;  // z depth, any resolution (scaled to the camera); empty: no free-space test
  cv::Mat mask;    // CV_8UC1 silhouette (0 background), camera size; empty: no silhouette test
  cv::Mat image;   // CV_8UC3 BGR photo, the mask's size; empty: no colour check on the background
};

struct SurfelStats {
  size_t input_points = 0;
  size_t dropped_nonfinite = 0;     // points with NaN / infinite coordinates or normals, dropped
  bool estimated_normals = false;   // the input had no normals
  double median_footprint = 0;      // scene units per pixel
  double spacing = 0;               // scene units
  size_t initial_particles = 0;
  size_t removed_free_space = 0;
  size_t removed_outside_hull = 0;
  size_t removed_off_silhouette = 0;
  bool hull_closed = false;         // a hull was given and is a closed mesh (otherwise not used)
  size_t removed_unsupported = 0;   // too little data or too few neighbours
  size_t grown = 0;
  size_t particles = 0;
  size_t vertices = 0, faces = 0;
  size_t holes_filled = 0;
  size_t small_component_faces = 0;  // faces of small pieces removed
  size_t border_edges_extended = 0;  // open border edges moved out by border_extension
  double mean_step_last_sweep = 0;  // mean particle displacement of the last sweep, spacings
  double spacing_spread = 0;        // coefficient of variation of nearest-neighbour distances
  double prune_seconds = 0, relax_seconds = 0, triangulate_seconds = 0;  // wall time per phase
};

struct SurfelResult {
  PointCloud surfels;  // positions, unit normals, radius, colours, confidence
  TriangleMesh mesh;   // vertices = the surfels (then the centres of filled holes), normals, colours
  SurfelStats stats;
};

// Steps 1-6 above. `hull` (optional) is a closed mesh; particles outside it are removed.
// Throws InputError when no usable point is left or the spacing would make too many particles.
SurfelResult ReconstructSurfels(const PointCloud& points, const std::vector<SurfelView>& views,
                                const TriangleMesh* hull, const SurfelOptions& options,
                                ProgressReporter* progress = nullptr);

// --- The steps, for tests and benchmarks ---

// Unit normals from the 12 nearest neighbours' principal axes, turned toward the first view that
// sees the point (in front, inside its image), else away from the points' centroid.
void EstimateNormals(const std::vector<SurfelView>& views, PointCloud* points);

// Median over points of the smallest depth / focal length among the views that see them; 0 when
// no view sees any point.
double MedianFootprint(const PointCloud& points, const std::vector<SurfelView>& views);

// Confidence-weighted averages of the points per cell of side `spacing` (normals, colours and
// confidence averaged likewise; confidence 1 when absent).
PointCloud ThinToSpacing(const PointCloud& points, double spacing);

// `sweeps` Jacobi sweeps of the particle energy with `data` as the data term. Returns the mean
// displacement of the last sweep in spacings. `particles` keeps its size.
double RelaxParticles(const PointCloud& data, double spacing, const ParticleWeights& weights, int sweeps,
                      PointCloud* particles);

// Per particle, how many views' depth maps see through it: the depth at its projection and at
// the 8 pixels around it is beyond the particle's by the margin (see free_space_margin).
std::vector<int> FreeSpaceViolations(const std::vector<Eigen::Vector3f>& positions,
                                     const std::vector<SurfelView>& views, double spacing, double margin_spacings);

// Per particle, in how many views with a mask it projects onto the background (nearest pixel).
// With colours and color_tolerance > 0, a view with a photo counts only where the photo's pixel
// differs from the particle's colour (RGB) by more than color_tolerance in some channel: a floater
// the stereo pushed off a bright edge lands on black, while the dark cloth behind an object, which
// the masks' threshold leaves out, lands on pixels of its own colour and is not evidence against it.
std::vector<int> OffSilhouette(const std::vector<Eigen::Vector3f>& positions, const std::vector<Color3u8>& colors,
                               const std::vector<SurfelView>& views, int color_tolerance);

// Coefficient of variation (std / mean) of each particle's nearest-neighbour distance.
double NearestNeighbourSpread(const std::vector<Eigen::Vector3f>& positions);

// surfel_mesh.cc (CGAL): the advancing-front triangulation with edges at most `max_edge_length`,
// faces turned to agree with the particles' normals; the mesh's vertices are the particles. Large
// clouds are triangulated in overlapping slabs, in parallel (see surfel_mesh.cc).
TriangleMesh TriangulateParticles(const PointCloud& particles, double max_edge_length);
// mesh_cleaning.cc: per face, an id of the connected piece it belongs to (faces sharing a vertex).
std::vector<int> ConnectedPieces(const TriangleMesh& mesh);
// mesh_cleaning.cc: closes the mesh's holes bounded by at most `max_edges` edges (a fan around a
// new centroid vertex); returns how many. Larger holes, loops through a vertex twice, and the outer
// border of a small piece (fewer than 2 L^2 faces for a loop of L edges) stay open.
size_t FillSmallHoles(int max_edges, TriangleMesh* mesh);
// mesh_cleaning.cc: removes the faces of connected pieces with fewer than `min_faces` faces (their
// vertices stay, unused); returns how many faces. Hand-written rather than OpenMesh: a halfedge
// structure refuses the non-manifold vertices the advancing front occasionally leaves.
size_t RemoveSmallComponents(int min_faces, TriangleMesh* mesh);
// mesh_cleaning.cc: moves every open border out by `distance`: each border vertex (one border edge
// in, one out) gets a copy moved along its edges' outward directions in the tangent plane of its
// normal, and each border edge whose ends both moved gets a strip of two faces to them. Returns
// how many border edges were extended. Vertices where openings touch stay put.
size_t ExtendBorders(float distance, TriangleMesh* mesh);

// surfel_mesh.cc (CGAL): which points lie inside a closed mesh, by the parity of ray crossings
// (all true when it is not closed, with `closed` set false; up to 0.5% open edges are tolerated).
std::vector<char> InsideClosedMesh(const TriangleMesh& mesh, const std::vector<Eigen::Vector3f>& points,
                                   bool* closed);

}  // namespace ibmr
