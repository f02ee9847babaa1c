// Layered stereo for one reference view and its neighbours: seed 000 section 4 of Szeliski's BMVC'99
// paper (lines 5625-5811) and the slides (lines 3798-3846), after Baker, Szeliski & Anandan, "A
// layered approach to stereo reconstruction" (CVPR 1998). The scene is a few planar layers, each a
// plane equation, a colour sprite with alpha, and a per-pixel residual depth off the plane. Steps:
//  1. Initial layers: planes fitted to the reference view's depth map (plane_sweep's, made
//     consistent by multi_depth) by sequential RANSAC, largest first (FitPlanesRansac).
//  2. Each plane refined across the views (RefinePlanes): Ceres, a robust (Cauchy) fit of the
//     relative depth difference along each ray, over the depth samples of the reference and its
//     neighbours that lie near the plane and away from depth discontinuities; the paper
//     estimates planes from the views' homographies (lines 5705-5716) and suggests optimising the
//     plane directly (line 5716): optionally (photometric_refinement), after a first assignment
//     (step 3) each plane is then refined by the photo-consistency of its own pixels across the
//     views (RefinePlanesPhotometric), using only pixels whose surroundings (2 pixels around, in
//     the reference and where they land in each neighbour) show the plane alone in the depth
//     maps: nearer, a neighbouring surface's colour bleeds in. Off by default: on the synthetic
//     room (configs/synth_layers.yaml) the depth samples recover 56 of the 58 planes with depth
//     (within 1 degree and 1%), the photometric step 49 with 4 neighbours and 56 with 12 (23 and
//     42 before the surroundings test). It does not recover the two left: a small box face half
//     hidden by an object (views 010 and 011, at 1.1-1.4 degrees): over its truly visible pixels
//     in 13 views the mean Huber photometric error is 1.44 at a plane 2.2 degrees and 1.3% off
//     against 1.42 on the true plane: the two planes cross near the face, whose pixels then land
//     0.04 pixels apart in the farthest view on average (0.14 at most).
//  3. Pixel assignment (AssignPixels): per pixel, each plane's cost is how well the neighbours,
//     warped into the reference through the plane's homography (Eq. 7), agree with it (mean of the
//     two best neighbours, so that one occluded neighbour does not veto), plus how far the pixel's
//     depth lies from the plane; a Potts term between 4-neighbours; a few sweeps of ICM.
//  4. Sprites (BuildSprites): each layer's pixels take the reference's colour; each sprite extends
//     `extend_px` under the nearer layers that hide it in the reference, coloured there by the
//     median of the neighbours that see the plane (the "occluded regions" a layer can represent,
//     line 3835); the residual depth is the depth map's offset from the plane, clamped and
//     median-filtered (Eq. 8's Z_l, here along the reference ray).
//  5. The layer count (ChooseLayerCount): models with the 1, 2, ... largest planes each predict
//     every neighbour from the reference and the other neighbours (held out in turn); the error
//     over the pixels any model covers (uncovered counted black) gives a curve, and the smallest
//     count within `count_tolerance` of the best wins (seed 000 lines 5906-5950: prediction error
//     on held-out views as the quality measure).
// Re-synthesis of the inputs with real-valued alpha (lines 5776-5786) is not done: alpha is 0 or 1.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/layered_sprites.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

struct LayeredOptions {
  int max_layers = 6;               // planes at most, in [1, 16]
  double plane_tolerance = 0.01;    // a depth sample is on a plane within this fraction of its depth, (0, 0.2]
  double min_layer_fraction = 0.02; // a plane needs this fraction of the view's depth samples, (0, 1)
  int ransac_iterations = 400;      // hypotheses per plane, in [10, 100000]
  int sample_step = 2;              // RANSAC and refinement use every this-many-th pixel, in [1, 16]
  // Plane fits use only samples at least this far from a depth discontinuity (a step of 6 plane
  // tolerances in inverse depth, or a pixel without depth), pixels, in [0, 64]: stereo pulls a surface's depth
  // toward the nearer surface beside it, and next to the floor and the objects that bias tilted
  // the synthetic room's back wall by 0.8 degrees. A plane with fewer such samples uses them all.
  int edge_margin_px = 6;
  double max_residual = 0.03;       // residual depth at most this fraction of the plane's depth, [0, 0.5]
  // Residual depth, where the depth map has none, by a plane sweep around each layer's plane with
  // this many (odd) offsets over [-max_residual, max_residual], in [3, 129]; 0: none. Only the
  // sprites written out use it, not the count selection's models.
  int residual_steps = 0;
  double depth_weight = 20.0;       // cost of a pixel's depth one tolerance off the plane, grey levels, >= 0
  double smoothness = 6.0;          // Potts cost between 4-neighbours of different layers, grey levels, >= 0
  int icm_sweeps = 5;               // in [0, 100]
  double max_cost = 40.0;           // a pixel no plane explains better than this (and without depth) stays empty, > 0
  int extend_px = 8;                // sprites extend this far under nearer layers, pixels, in [0, 256]
  double count_tolerance = 0.01;    // smallest count within this fraction of the best held-out error, [0, 1]
  int choose_count = 1;             // 1: choose the count by held-out prediction; 0: use every plane found
  double selection_scale = 0.5;     // the count is chosen on the views scaled by this, (0, 1]
  int photometric_refinement = 0;   // 1: also refine the planes by photo-consistency (step 2b); 0: geometric only

  bool Check(std::string* error) const;  // error starts with the option's name
};

// A view at the depth map's resolution: its photo resized to it, its depth (0: none).
struct LayerView {
  std::string name;
  Camera camera;  // pinhole, the depth map's size
  Rigid3d cam_from_world;
  cv::Mat image;  // CV_8UC3
  cv::Mat depth;  // CV_32F z depth, 0 where none
};

struct WorldPlane {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit
  double offset = 0;                                  // n.X = offset
  size_t support = 0;                                 // inlier samples when found
  // Found as one connected surface (true), or as a plane through scattered surfaces at about the
  // same depth once no connected one was large enough (false; refined over all its samples).
  bool connected = true;
};

// Step 1. Planes largest first; at most max_layers, each with at least min_layer_fraction of the
// samples. Deterministic for a given seed with one standard library (std::uniform_int_distribution
// may draw differently in another).
std::vector<WorldPlane> FitPlanesRansac(const LayerView& reference, const LayeredOptions& options, unsigned seed = 1);

// Step 2, in place. `views[0]` is the reference; the others add their samples near each plane.
void RefinePlanes(const std::vector<const LayerView*>& views, const LayeredOptions& options, std::vector<WorldPlane>* planes);

// Step 2b (photometric_refinement.cc), in place: each plane's textured pixels (labels) mapped into
// the neighbours through its homography should match them in grey level; Ceres adjusts the plane.
// Pixels count only where the depth maps (reference and neighbour) show the plane around them.
void RefinePlanesPhotometric(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                             const cv::Mat& labels, const LayeredOptions& options, std::vector<WorldPlane>* planes);

// Step 3. CV_32S labels (index into planes; -1: empty).
cv::Mat AssignPixels(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                     const std::vector<WorldPlane>& planes, const LayeredOptions& options);

// Step 4. The layers, ordered back to front from the reference (by their median depth there).
LayerSet BuildSprites(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                      const std::vector<WorldPlane>& planes, const cv::Mat& labels, const LayeredOptions& options);

struct LayerCountCurve {
  std::vector<double> rms_error;  // per count 1..n: held-out RMS error (grey levels)
  int chosen = 0;                 // the count
};

// Step 5 (needs at least one neighbour; else every plane is used and the curve is empty). The
// views as given; ReconstructLayers passes them scaled by selection_scale (a quarter of the pixels
// at 0.5: the curve's shape, not its detail, decides the count).
LayerCountCurve ChooseLayerCount(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                                 const std::vector<WorldPlane>& planes, const LayeredOptions& options);

struct LayeredResult {
  LayerSet layers;
  std::vector<WorldPlane> planes;  // all found (refined), largest first
  LayerCountCurve curve;
  double seconds = 0;
};

// Steps 1-5, then the chosen count's sprites from every neighbour.
LayeredResult ReconstructLayers(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                                const LayeredOptions& options);

}  // namespace ibmr
