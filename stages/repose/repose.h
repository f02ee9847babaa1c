// Pose refinement of a view against the other views' depth maps (issue 67: a view whose depth
// disagrees with the others', multi_depth's flag, likely has a wrong pose; here it gets a better
// one from the dense data). Features of the view's photo (SIFT, Lowe IJCV 2004) are matched to
// those of reference views with Lowe's ratio test; each reference keypoint is lifted to 3D through
// the reference's consistent depth map and pose, which multi_depth confirmed against their
// neighbours; the view's pose is then the perspective-n-point solution of these 2D-3D matches:
// RANSAC over minimal EPnP solutions (Lepetit et al. IJCV 2009; Fischler & Bolles 1981), refined
// by Levenberg-Marquardt on the inliers' reprojection error (OpenCV solvePnPRansac,
// solvePnPRefineLM). Seed 000's structure-from-motion refinement (lines 3549-3602) does the same
// for all cameras and points at once; here the references and their points stay fixed, so one
// view's six parameters are all there is to fit. Observations go through Camera::CamFromImg, so
// distorted models work too (the fit runs on normalised coordinates).
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

struct ReposeOptions {
  int max_features = 4000;          // SIFT keypoints per photo, in [100, 100000]
  double ratio = 0.8;               // Lowe's ratio test: best / second-best descriptor distance, in (0, 1]
  double ransac_px = 2.0;           // RANSAC inlier reprojection error, pixels of the view, > 0
  int min_inliers = 40;             // fewer inliers: the pose is kept as it was, >= 6
  double max_rotation_deg = 15.0;   // a larger correction is refused as a wrong solution, degrees, > 0
  int num_neighbors = 6;            // reference views (closest viewing directions), in [1, 64]
  // The pose is kept when the RANSAC inliers already reproject within this RMS under it (pixels,
  // >= 0): the view's disagreement is then not its pose's (templeR0040, flagged on the clean ring
  // for a matcher failure, reprojects within 2.0 px; a 0.25 degree turn there gives ~7 px).
  double min_rms_px = 3.0;

  // False with `error` starting with the YAML key when a value is out of range.
  bool Check(std::string* error) const;
};

// A view in memory: its photo (8-bit grey), camera and pose; `depth` (references only; any
// resolution, z depth, 0 unknown) lifts its keypoints to 3D.
struct ReposeView {
  std::string name;
  cv::Mat gray;
  Camera camera;
  Rigid3d cam_from_world;
  DepthMap depth;
};

struct ReposeResult {
  Rigid3d cam_from_world;       // the refined pose when accepted, else the initial one
  bool accepted = false;
  std::string reason;           // why not accepted ("" when accepted)
  size_t correspondences = 0;   // 2D-3D matches fed to RANSAC
  size_t inliers = 0;
  double rms_before_px = 0;     // RMS reprojection error of the inliers under the initial pose
  double rms_after_px = 0;      // ... under the refined pose
  double rotation_change_deg = 0;  // angle between the initial and refined rotations
  double center_change = 0;        // distance between the initial and refined centres, scene units
};

// Refines `view`'s pose against `references` (their depth maps must be set). Pure; thread-safe.
ReposeResult RefineViewPose(const ReposeView& view, const std::vector<ReposeView>& references, const ReposeOptions& options);

}  // namespace ibmr
