// Fusion of depth maps into points with normals, colour and confidence by uncertainty-weighted
// merging (seed 000 section 4 "3D points from stereo", lines 4352-4453): every depth sample becomes
// a 3D point with a 3x3 covariance (along the viewing ray from the depth variance, which falls with
// the stereo confidence; across it a constant, half a pixel's footprint); views are added one at a
// time and a sample merges with an earlier point when that point re-projects into the sample's
// pixel ("image plane centres within a small distance", line ~4410) and their depths overlap in
// a 1-D uncertainty-weighted distance. Merging sums the information matrices, so the merged point
// is the inverse-covariance-weighted mean with a reduced uncertainty. Samples of one view never
// merge with each other (each earlier point is a candidate for one pixel only), so the output is at
// least as dense as one input image. Points seen in fewer than `min_views` views are dropped.
// A point's confidence is its samples' mean confidence times their agreement: the chi-square of
// the samples about the merged position under their own covariances (the uncertainty section 4
// propagates) says whether the views disagree more than their stereo uncertainty allows, as they
// do where a camera is off or a match is wrong. Then, over the whole cloud, times a surface
// factor: how far the point lies from the plane through its nearest neighbours (SurfaceFactors).
// Noise scatters a view's samples about the surface, and a point that merged few of them keeps
// its share of that scatter, which no single view's stereo certainty or chi-square sees; its
// neighbours' plane averages it out. (The idea of judging a point by its neighbourhood is the
// statistical outlier test of point-cloud libraries; here it is a factor, not a filter.)
//
// Evaluation against a true mesh (used when ground_truth/ exists) is pipeline/core/surface_accuracy.h.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rigid3.h"
#include "pipeline/core/surface_accuracy.h"

namespace ibmr {

struct FuseOptions {
  double relative_depth_sigma = 0.003;  // depth std / depth of a confidence-1 sample, in (0, 0.2]
  double lateral_sigma_pixels = 0.5;    // std across the ray, in pixels of footprint, in (0, 10]
  double merge_sigmas = 3.0;            // 1-D uncertainty-weighted depth distance for a merge, in (0, 100]
  double merge_pixel_radius = 0.71;     // re-projection within this of the centre of the pixel it falls in, pixels,
                                        // in (0, 0.71] (0.71: anywhere in that pixel)
  double max_normal_angle_deg = 60.0;   // normals of merged samples within this, degrees, in (0, 180]
  // Samples below this confidence are skipped, in [0, 1]. 0.02: multi_depth's confidence includes
  // the geometric consistency (geometric_sigma 0.003), on which 0.1 dropped 40% of the fused
  // surface of the synthetic ring with image noise 0.5 (completeness 0.82 -> 0.50).
  double min_confidence = 0.02;
  int min_views = 2;                    // views that must have contributed to a point, in [1, 1000]
  // A point's confidence: the mean of its samples' confidences, times (when on) its samples'
  // agreement: 1 while they scatter about the merged position no more than their covariances
  // predict (chi-square per degree of freedom <= 1), exp(-(chi2 / dof - 1) / 2) beyond.
  bool agreement_weighting = true;
  // The surface factor (SurfaceFactors): neighbours the plane is fitted through (0: off, else
  // [4, 256]) and the residual scale in medians of the cloud's residuals (> 0). 32 and 2:
  // measured on the stability matrix's synthetic ring (configs/stability.yaml), fused points'
  // confidence-error rho with image noise 1 -0.21 -> -0.43, clean -0.26 -> -0.37, textureless 1
  // -0.36 -> -0.33 (k 64: -0.54, -0.39, -0.29: the textureless cloud's wrong sheets are planar
  // too, and a wider plane ranks them worse); the surfel mesh built on them, synth_dense.yaml:
  // accuracy 0.00652 -> 0.00609, completeness 0.9246 -> 0.9248.
  int surface_neighbours = 32;
  double surface_residual_scale = 2.0;

  bool Check(std::string* error) const;  // error starts with the YAML key
};

// One view's maps (same size) and photo, in memory. normals/confidence/image may be empty.
struct FuseView {
  Camera camera;
  Rigid3d cam_from_world;
  DepthMap depth;
  FloatMap normals;     // 3 channels, camera frame; empty: computed from the depth map
  FloatMap confidence;  // 1 channel in [0, 1]; empty: 1
  cv::Mat image;        // CV_8UC3 BGR, any size (sampled at the scaled pixel); empty: grey
};

struct FuseStats {
  size_t samples = 0;        // samples used
  size_t merged = 0;         // samples merged into an existing point
  size_t points = 0;         // points before the min_views filter
  size_t kept_points = 0;    // after it
};

// Per point of `positions`, exp(-(r / (scale * median r))^2 / 2), r its distance to the
// least-squares plane through its `neighbours` nearest points (itself included): 1 on the local
// surface, falling for points its neighbours do not bear out. neighbours < 4 or fewer points than
// neighbours + 1: all 1. Where the median residual is 0 (an exactly planar cloud) the scale is
// floored at 1e-9 of the cloud's extent. Parallel over points.
std::vector<float> SurfaceFactors(const std::vector<Eigen::Vector3f>& positions, int neighbours, double scale);

// Streams views into a growing set of merged points; memory is the points, not the maps.
class PointFuser {
 public:
  explicit PointFuser(const FuseOptions& options);
  ~PointFuser();
  void AddView(const FuseView& view);
  // Points seen in >= min_views views: position, unit normal, mean colour, confidence (the mean
  // times the agreement factor, FuseOptions::agreement_weighting).
  PointCloud Finish(FuseStats* stats) const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace ibmr
