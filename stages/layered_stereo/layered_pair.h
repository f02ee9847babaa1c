// Two-view layered stereo on a rectified pair: the scene as a few planar layers, each a plane
// equation plus a per-pixel residual disparity, and every left pixel assigned to one layer.
//
// Follows seed 000, lines 5625-5811 (Szeliski, BMVC'99, section 4 "Layered representations":
// layers with an explicit plane equation, boolean pixel assignments B_kl first, a per-pixel
// residual depth offset Z_l searched by a plane sweep "favoring small disparities" in the plane's
// frame, pixel assignments recomputed by comparing the plane-warped images) and lines 3798-3846
// (slides "Layered Stereo": plane per sprite, plane plus parallax residual, occluded regions), after
// Baker, Szeliski & Anandan, "A layered approach to stereo reconstruction", CVPR 1998.
//
// On a rectified pair a 3D plane is an affine function of disparity, d(x, y) = a x + b y + c (x, y:
// left pixel centres, d: left x minus right x, pixels), so a layer's homography is a per-pixel
// horizontal shift. The method here keeps boolean opacities (the first part of the paper's
// framework; no sprites, no alpha):
//   1. an initial disparity (the caller's; LayeredTwoView takes plane_sweep's, left-right checked,
//      holes <= 0 or NaN);
//   2. initial layers by sequential RANSAC of disparity planes on its valid pixels (MSAC score, the
//      three samples near each other, least-squares refits on the inliers);
//   3. each plane refined by robust least squares (Ceres, Cauchy loss) on its inliers;
//   4. per pixel and layer, the census matching cost aggregated over a window that follows the
//      plane, minimised over a residual r in [-R, R] around it (the plane-stabilised residual sweep,
//      "favoring small disparities": a penalty per pixel of |r|), plus a truncated prior towards the
//      initial disparity where it is valid. A pixel the left-right check rejected whose match under
//      a layer falls on a nearer surface of the initial disparity is occluded under that layer and
//      costs a constant instead, so that it joins the farther layer, where occluded regions belong.
//      Labels minimise these costs plus a Potts term (weaker across grey-level edges) by semi-global
//      aggregation over the labels along 4 directions;
//   5. disparity = plane of the label + residual (+ parabola sub-pixel), the plane alone where the
//      pixel is occluded under its layer; optionally the planes are re-fitted to the assignment and
//      step 4 repeated (refinement_passes; on the Middlebury pairs it does not help, default 0).
// Every pixel gets a label and a disparity (> 0): the output has no holes. Deterministic for a
// given seed. Parallel with TBB (layers, rows, column blocks); all buffers per call or per task.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/two_view_methods.h"

namespace ibmr {

struct LayeredPairOptions {
  // ---- layers (steps 2-3)
  int max_layers = 16;             // planes found by sequential RANSAC, at most; in [1, 64]
  double inlier_tolerance = 0.5;   // |d - plane(x, y)| of a RANSAC inlier, pixels of disparity; in (0, 16]
  double min_layer_fraction = 0.004;  // a layer needs this fraction of the valid initial pixels as
                                      // inliers (RANSAC stops below it), in (0, 1)
  int ransac_iterations = 400;     // plane hypotheses per layer, in [1, 100000]
  int sample_radius = 24;          // the 2nd and 3rd sample lie within this many pixels of the 1st
                                   // (one surface, more likely), in [2, 4096]
  uint32_t seed = 1;               // RANSAC random seed (deterministic results)
  double loss_scale = 0.5;         // Cauchy loss scale of the plane refinement, pixels; in (0, 16]
  // ---- matching (step 4); cost units: census Hamming distance, mean over the window, 0..62
  int residual_range = 1;          // R: residual disparities searched around the plane, -R..R
                                   // pixels (plus sub-pixel); in [0, 16]
  double residual_penalty = 4.0;   // added cost per pixel of |residual|, cost units; >= 0
  int window_radius = 2;           // box window (2r+1)^2 of the census costs, following the plane;
                                   // in [0, 10]
  double initial_weight = 5.0;     // prior towards the initial disparity where it is valid: cost
                                   // units per pixel of |d - initial d|, >= 0 (0: none)
  double initial_truncation = 2.0; // ... counted up to this many pixels (an outlier costs no more), > 0
  // ---- assignment (step 4)
  double smoothness = 10.0;        // Potts penalty between 4-neighbours with different layers,
                                   // cost units; >= 0
  double edge_threshold = 16.0;    // grey-level (max over colour channels) step at which the Potts
                                   // penalty is weakened, grey levels; >= 0 (0: never)
  double edge_factor = 0.5;        // Potts penalty multiplier across such an edge, in [0, 1]
  double occlusion_cost = 16.0;    // data cost of a pixel occluded under a layer, and of a match
                                   // outside the right image, cost units; >= 0
  // ---- refinement (step 5)
  int refinement_passes = 0;       // times the planes are re-fitted to the assignment and the
                                   // assignment recomputed; in [0, 5]
  bool subpixel = true;            // parabola through the residual costs

  // Returns false and sets `error` (starting with the option's name) when a value is out of range.
  bool Check(std::string* error) const;
};

// d(x, y) = a x + b y + c, in left-image pixels (x, y of pixel centres, origin at the top-left pixel).
struct DisparityPlane {
  double a = 0, b = 0, c = 0;
  size_t support = 0;  // initial-disparity inliers when found; pixels assigned after the assignment
  double Disparity(double x, double y) const { return a * x + b * y + c; }
};

struct LayeredPairResult {
  cv::Mat disparity;  // CV_32F, left view, in [0.001, max(1, max_disparity - 1)] everywhere (no holes)
  cv::Mat labels;     // CV_32S, index into `planes` per left pixel
  std::vector<DisparityPlane> planes;
  double seconds = 0;  // wall time of LayeredStereoPair (not of the initial disparity)
};

// `left`, `right`: rectified images (8-bit grey or BGR) of equal size; disparities 0..max_disparity-1.
// `initial_disparity`: CV_32F of the same size, <= 0 or NaN where unknown (e.g. left-right check
// failed; values below 0.5, winners at the range's end, count as unknown too); at least 3 valid
// pixels. Throws std::invalid_argument on bad inputs or options.
LayeredPairResult LayeredStereoPair(const cv::Mat& left, const cv::Mat& right, const cv::Mat& initial_disparity,
                                    int max_disparity, const LayeredPairOptions& options);

// The two-view method "layered" (signature of TwoViewMethod, pipeline/core/two_view_methods.h):
// the initial disparity from the registered "plane_sweep" method with {"fill": "false"} (throws
// std::runtime_error when no stage registered it), then LayeredStereoPair. Options by name:
// max_layers, inlier_tolerance, min_layer_fraction, ransac_iterations, sample_radius, seed,
// loss_scale, residual_range, residual_penalty, window_radius, initial_weight, initial_truncation,
// smoothness, edge_threshold, edge_factor, occlusion_cost, refinement_passes, subpixel
// (true/false), as LayeredPairOptions; an unknown or unparsable one, or a value out of range,
// throws std::invalid_argument naming it (before any work). Facts: layers, planes ([{a, b, c,
// pixels}]), initial_seconds, layered_seconds, seconds.
TwoViewOutput LayeredTwoView(const cv::Mat& left, const cv::Mat& right, int max_disparity,
                             const TwoViewOptions& options);

}  // namespace ibmr
