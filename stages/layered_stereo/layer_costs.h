// Step 4's data costs of the two-view layered method (layered_pair.h): 9x7 census codes of both
// images and, per pixel and layer, the census matching cost aggregated over a window that follows
// the layer's plane, minimised over a residual r in [-R, R] around it (the plane-stabilised residual
// sweep, "favoring small disparities": a penalty per pixel of |r|), plus a truncated prior towards
// the initial disparity where it is valid; the disparity at the minimum (plane + residual, +
// parabola sub-pixel) with it. Internal to the layered_stereo stage: callers use layered_pair.h.
//
// Follows seed 000, lines 5625-5811 (Szeliski, BMVC'99, section 4 "Layered representations": a
// per-pixel residual depth offset Z_l searched by a plane sweep "favoring small disparities" in
// the plane's frame) and lines 3798-3846 (slides "Layered Stereo": plane plus parallax residual).
#pragma once

#include <tbb/enumerable_thread_specific.h>

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "stages/layered_stereo/layered_pair.h"

namespace ibmr {
namespace layered_internal {

struct MatchInput {
  int width = 0, height = 0;
  std::vector<uint64_t> left, right;  // census codes
};

// Row buffers of RawCostRow (in layer_costs.cc).
struct RawRowScratch {
  std::vector<int32_t> floor;   // floor of the plane's disparity
  std::vector<float> fraction;  // the disparity minus its floor
  std::vector<float> integer;   // (2R + 2) rows: costs at the integer disparities floor - R + k
};

// Per-task working memory of LayerCosts (in layer_costs.cc), reused from layer to layer.
struct LayerScratch {
  std::vector<float> raw;   // per residual, one row of raw costs with r replicated values each side
  std::vector<float> hsum;  // per residual, an image of window sums along rows
  std::vector<float> vsum;  // per residual, one row of window sums (the running column sums)
  std::vector<float> best, best_k;  // one row each
  RawRowScratch raw_row;
};

// What LayerCosts (in layer_costs.cc) needs besides the images: the initial disparity as a prior
// (0 at holes) and its weight per pixel (options.initial_weight, 0 at holes).
struct Prior {
  std::vector<float> disparity, weight;
};

// 9x7 census codes (bit set: neighbour brighter than the centre), image border replicated. The
// comparisons go offset by offset over whole rows into eight byte planes (16 pixels per vector
// instruction), which are then packed into one 64-bit code per pixel.
std::vector<uint64_t> Census(const cv::Mat& gray);

// The prior of LayerCosts from the initial disparity: its value and `weight` where it is valid, 0 at
// the holes.
Prior MakePrior(const cv::Mat& initial, const std::vector<uint8_t>& hole, double weight);

// Step 4's data costs of every layer: `cost` pixel-major (cost[i * layers + l], for the assignment),
// `disparity` layer-major (disparity[l * pixels + i]). The layers are computed in parallel, each
// into its own layer-major slice (no two tasks write one cache line), then transposed.
void AllLayerCosts(const MatchInput& match, const std::vector<DisparityPlane>& planes, const Prior& prior,
                   const LayeredPairOptions& options, tbb::enumerable_thread_specific<LayerScratch>* scratch,
                   std::vector<float>* layer_cost, std::vector<float>* cost, std::vector<float>* disparity);

}  // namespace layered_internal
}  // namespace ibmr
