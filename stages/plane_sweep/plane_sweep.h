// Plane-sweep stereo on the CPU: per reference view, fronto-parallel planes uniform in inverse
// depth, neighbours warped by the plane homographies, a matching cost (census, SAD or ZNCC)
// combined over neighbours by best-k (tolerates occlusion in some of them), box and semi-global
// aggregation, winner-take-all, parabola sub-pixel, certainty from the cost curve; depth, normals
// (from the depth gradient) and confidence maps out. The same engine runs two-view stereo on a
// rectified pair (planes = integer disparities, homography = shift), with a left-right check and
// hole filling.
//
// Follows seed 000, lines 3659-3760 (dense stereo along epipolar lines, multiple baselines),
// 5300-5525 (section 2, "Depth maps": generalized disparity space, matching cost, aggregation,
// winner-take-all, sub-pixel, certainty) and 4352-4453 (section 4: parabola sub-pixel and its
// variance). Census: Zabih & Woodfill 1994; semi-global matching: Hirschmueller 2008. The
// confidence combines cost-curve measures of Hu & Mordohai (PAMI 2012): the margin below the
// curve's mean and the peak ratio against a second minimum (cost_curve_confidence.h).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/rigid3.h"
#include "pipeline/core/sparse_model.h"

namespace ibmr {

enum class MatchCost { kCensus, kSad, kZncc };
enum class CostAggregation { kBox, kSemiGlobal };

struct PlaneSweepOptions {
  int num_planes = 128;           // depth hypotheses, uniform in inverse depth, in [2, 1024]
  int num_neighbors = 4;          // neighbour views per reference view, in [1, 16]
  int best_k = 2;                 // neighbours whose costs are averaged per pixel and plane, in [1, num_neighbors]
  MatchCost cost = MatchCost::kCensus;
  int census_radius_x = 4;        // census window half width, pixels; (2rx+1)(2ry+1) - 1 <= 64
  int census_radius_y = 3;        // census window half height, pixels
  // The census cost between pixels: interpolated along the epipolar line (two codes, the default)
  // or bilinearly (four codes; the cost before; sweep_engine.h, CensusSampling).
  bool census_bilinear = false;
  int window_radius = 1;          // box window radius of the cost, pixels, in [0, 15] (ZNCC: >= 1)
  CostAggregation aggregation = CostAggregation::kSemiGlobal;
  int sgm_paths = 8;              // semi-global paths, 4 or 8
  int p1 = 240;                   // small-jump penalty, cost units (1000 ~ worst match), in [0, 2000]
  int p2 = 1200;                  // large-jump penalty, cost units, in [p1, 6000]
  double p2_gamma = 12.0;         // P2 / (1 + |grey step| / gamma) at edges, grey levels; 0: constant
  double confidence_scale = 3.0;  // margin factor = Saturate(scale * (mean cost - winner cost) / mean
                                  // cost): the value up to 1/2, then smoothly below 1; > 0
                                  // (cost_curve_confidence.h)
  // Peak-ratio factor = Saturate(scale * (1 - c1 / c2m)): c1 the winner's aggregated cost, c2m the
  // lowest other local minimum of the aggregated cost curve (Hu & Mordohai 2012, PKR); 0 where
  // another depth is about as cheap after aggregation (repetitive texture). In [0, 100]; 0: off.
  // The confidence is the margin factor times the peak-ratio factor times the texture factor.
  double peak_ratio_scale = 20.0;
  double confidence_threshold = 0.5;   // depth set to 0 where the margin factor times the texture
                                       // factor (the confidence without the peak ratio) < this, in [0, 1]
  double texture_scale = 6.0;     // grey-level std. dev. over the census window at which the
                                  // texture factor of the confidence reaches 1, >= 0 (0: off)
  // The texture factor against the photo's noise (issue 67): with n the reference photo's noise
  // deviation (pipeline/core/noise_estimate.h), the factor is also at most the window's signal
  // deviation sqrt(max(0, var - n^2)) over noise_snr * n, so that contrast the noise makes is not
  // taken for texture and a noisy photo's weakly textured pixels are less certain. >= 0; 0: off.
  // Off by default: on the synthetic ring with image noise at strength 1 (every view equally
  // noisy) it lowered stereo's share within 1% (0.365 -> 0.263 at 2, 0.08 at 4) without making
  // the confidence rank the errors better (rho -0.27 -> -0.25, -0.21).
  double noise_snr = 0;
  double min_depth = -1;          // fallback depth bounds, scene units (-1: none)
  double max_depth = -1;
  double depth_margin = 0.1;      // relative margin around sparse-point depths, in [0, 2]
  // Quantile of a view's sparse-point depths that sets its near bound (DepthBoundsFromPoints), in
  // [0, 0.5]. 0.02 by default; forward-facing configs take LLFF's 0.001 (its poses_bounds' near
  // depth is the 0.1 percentile), so that thin occluders near the cameras, which hold few points,
  // stay inside the sweep.
  double near_quantile = 0.02;
  double min_angle_deg = 3.0;     // neighbour triangulation angle range, degrees
  double max_angle_deg = 50.0;
  double target_angle_deg = 15.0; // preferred triangulation angle, degrees
  // Memory of one view's sweep, MB (0: unlimited). When the whole image's cost volumes do not fit,
  // the reference is swept in bands of rows, each with kBandContextRows of context above and below
  // (see PlaneSweep); within the limit the image is swept whole.
  int max_view_memory_mb = 1024;
  // Threads each semi-global pass steps its paths on, 1 or 2 (EngineOptions::sgm_threads): 2 for
  // a view swept while no other is (the stage's memory budget holds one view at a time). The
  // depth maps are the same.
  int sgm_threads = 1;
  // Two-view only.
  bool lr_check = true;           // left-right consistency check
  int lr_tolerance = 1;           // pixels
  bool fill_holes = true;         // fill rejected pixels from the nearer-background side
  int median_radius = 2;          // median filter radius on the disparity (0: none), in [0, 2]

  // Returns false and sets `error` (starting with the YAML key) when a value is out of range.
  bool Check(std::string* error) const;
};

// ---------------------------------------------------------------- two-view stereo
struct StereoPairResult {
  cv::Mat disparity;           // CV_32F, left view; <= 0 or NaN: no estimate
  double unfilled_fraction = 0;  // fraction of pixels without an estimate
  int64_t evaluations = 0;     // plane(disparity)-pixel-neighbour cost evaluations
  double seconds = 0;          // wall time of the matching
};
// `left`, `right`: rectified images (8-bit grey or BGR) of equal size; disparities 0..max_disparity-1.
StereoPairResult StereoPair(const cv::Mat& left, const cv::Mat& right, int max_disparity,
                            const PlaneSweepOptions& options);

// ---------------------------------------------------------------- multi-view plane sweep
struct SweepView {
  std::string name;
  cv::Mat gray;          // CV_8UC1, undistorted
  Camera camera;         // without distortion (PINHOLE or SIMPLE_PINHOLE)
  Rigid3d cam_from_world;
  // Optional: sweep::CensusTransform(gray) with the options' census radii, which a caller that
  // matches each view against several references computes once (null: PlaneSweep computes it).
  std::shared_ptr<const std::vector<uint64_t>> census;
};

// Context rows a band of a banded sweep matches beyond its own rows, above and below, so that its
// census windows, box windows and semi-global paths see the surface around it (see PlaneSweep).
constexpr int kBandContextRows = 48;

// Bytes of one view's sweep besides its cost volumes, per reference pixel: the grey images of the
// view and its neighbours, winners, texture factor, plane ranges and the three output maps.
double SweepFixedBytesPerPixel(int num_neighbors);
// Bytes of the cost volumes (the data cost and the semi-global sums, which the box filter and the
// two passes update in place; 16 bits per plane, planes padded to 16) per reference row of width
// `width`.
double SweepVolumeBytesPerRow(int width, int num_planes);
// Bands of rows a sweep of a width x height part of a reference of `view_pixels` pixels (-1: the
// part is the whole reference) takes within options.max_view_memory_mb (1: the whole part at once).
int SweepBands(int width, int height, const PlaneSweepOptions& options, int64_t view_pixels = -1);

struct PlaneSweepResult {
  DepthMap depth;        // z depth, 0: no estimate (confidence below the threshold)
  FloatMap normals;      // 3 channels, camera frame, towards the camera; 0 where no depth
  FloatMap confidence;   // 1 channel in [0, 1]
  int64_t evaluations = 0;       // plane-pixel-neighbour cost evaluations done
  double evaluation_seconds = 0;  // the threads' CPU time spent on them, summed (sweep::VolumeWork)
  double box_filter_seconds = 0;  // the threads' CPU time in the box filter, summed (sweep::VolumeWork)
  // CPU time of the view's own thread in the semi-global passes and the winners (with sgm_threads
  // 2 the helper thread's share is not in it; 0 without semi-global aggregation, whose winners a
  // parallel loop picks).
  double aggregation_seconds = 0;
  int64_t full_evaluations = 0;  // ... that sweeping every plane at every pixel would do
  double valid_fraction = 0;  // fraction of pixels with depth
  double noise_sigma = 0;     // the reference photo's estimated noise deviation, grey levels (noise_snr > 0)
  size_t volume_bytes = 0;    // bytes of the cost volumes held for this view (its largest band)
  int bands = 1;              // bands of rows swept one after the other (1: all at once; 0: no pixel to match)
};

// Per-pixel depth bounds of the reference view (z): `near`, e.g. the nearest surface of a visual
// hull along each pixel's ray, 0 where the pixel is unbounded (the hull does not cover it); `far`
// the farthest (empty: the sweep's far bound; behind a hull's back the background can show).
struct PixelDepthBounds {
  DepthMap near, far;
};

// Sweeps `near`..`far` (z in the reference camera, 0 < near < far). With `pixel_bounds`, each
// bounded pixel matches only the planes within its bounds widened by options.depth_margin (and one
// plane), and a winner that smoothing carried outside them is dropped; unbounded pixels sweep every
// plane. Only the box of the pixels that are matched (widened by twice the filter radius) is swept:
// the winners are those of the whole image (see the comment in PlaneSweep). When the cost volumes
// of that part exceed options.max_view_memory_mb, it is swept in bands of rows (SweepBands): each
// band is matched with kBandContextRows more rows above and below (as a part at its origin in the
// reference, sweep::BuildCostVolume) and keeps the winners of its own rows. Inside a band's rows
// the result differs from the whole image's only where a semi-global path would have carried
// information from beyond the context rows.
PlaneSweepResult PlaneSweep(const SweepView& reference, const std::vector<SweepView>& neighbours, double near,
                            double far, const PlaneSweepOptions& options,
                            const PixelDepthBounds* pixel_bounds = nullptr);

// Neighbour choice: indices into `views` (not `reference_index`), best first. With sparse points
// the score sums, over points seen by both, a weight of the triangulation angle; without, the
// angle at the point on the reference optical axis at depth `scene_depth`.
std::vector<int> SelectNeighbors(const SparseModel& model, const std::vector<int>& image_ids, int reference_index,
                                 double scene_depth, const PlaneSweepOptions& options);

// Depth range of the sparse points seen in (or projecting into) `image`, widened by `margin`;
// false when fewer than 8 points. Far: the 98% quantile. Near: the `near_quantile` quantile (at
// 0.001 and under 1000 points, the nearest point, as LLFF's bound). A thin occluder near the
// cameras holds few points (synth's forward-facing scene: its nearer pole holds 2 of a view's 790,
// which a 2% quantile left out of every sweep and so out of every later model); a nearer bound
// costs resolution in inverse depth for the rest of the scene (the room's floor near the cameras:
// with 128 planes its walls are no longer placed within 1%), hence the choice per config.
bool DepthBoundsFromPoints(const SparseModel& model, const Image& image, double margin, double near_quantile, double* near,
                           double* far);

// Normals (camera frame, unit, facing the camera) from the depth gradient; 0 where undefined.
FloatMap NormalsFromDepth(const DepthMap& depth, const Camera& camera);

}  // namespace ibmr
