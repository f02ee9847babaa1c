// Measures of the layers against a synthetic scene's ground truth (the synth stage's
// ground_truth/mesh.ply and per-view true depth): which planes of the true mesh a view sees, and
// how far a recovered plane lies from the nearest of them. Evaluation only; not a seed-paper method.
#pragma once

#include <vector>

#include "pipeline/core/mesh.h"
#include "stages/layered_stereo/layers.h"

namespace ibmr {

struct TruthPlane {
  WorldPlane plane;
  double pixel_fraction = 0;  // of the view's pixels with true depth
  double depth_coverage = 0;  // of its pixels, those where the estimated depth map has a value (NaN: none given)
};

// The true mesh's faces grouped by the plane they lie in (normal to 1e-3, offset to 1e-3 of the
// scene size); those on which at least `min_fraction` of the view's true-depth pixels lie (within
// 0.1% of their depth), largest first. `view.depth` must be the true depth; `estimated_depth`
// (same size, or empty) is the depth the layers were fitted to, for `depth_coverage`: a plane the
// stereo left without depth cannot become a layer.
std::vector<TruthPlane> VisibleTruthPlanes(const TriangleMesh& truth, const LayerView& view, double min_fraction,
                                           const cv::Mat& estimated_depth = cv::Mat());

struct PlaneError {
  int truth = -1;          // index into the truth planes; -1: none
  double angle_deg = 0;    // between the normals
  double offset_relative = 0;  // |d - d_true| (normals aligned) / the camera's distance to the true plane
};

// The truth plane nearest to `found` (angle in degrees plus 100 times the relative offset). The
// offset error is relative to the distance from `camera_centre` to the true plane: an offset from
// the world origin would be arbitrary (the synthetic room's floor has offset 0).
PlaneError NearestTruthPlane(const WorldPlane& found, const std::vector<TruthPlane>& truth, const Eigen::Vector3d& camera_centre);

}  // namespace ibmr
