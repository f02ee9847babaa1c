// Step 4's assignment of the two-view layered method (layered_pair.h): every left pixel gets one
// layer (boolean opacities), the labels minimising the layers' data costs (layer_costs.h) plus a
// Potts term between 4-neighbours, weaker across grey-level edges, by semi-global aggregation over
// the labels along 4 directions; and the occlusion reasoning on those costs: a pixel the left-right
// check rejected whose match under a layer falls on a nearer surface of the initial disparity (the
// right view's z-buffer) is occluded under that layer and costs a constant instead, so that it
// joins the farther layer, where occluded regions belong. Internal to the layered_stereo stage:
// callers use layered_pair.h.
//
// Follows seed 000, lines 5625-5811 (Szeliski, BMVC'99, section 4 "Layered representations":
// boolean pixel assignments B_kl, recomputed by comparing the plane-warped images) and lines
// 3798-3846 (slides "Layered Stereo": pixels assigned to layers, occluded regions).
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "stages/layered_stereo/layered_pair.h"

namespace ibmr {
namespace layered_internal {

// A pixel is occluded under a layer when the right-image pixel it maps to shows a surface this many
// pixels of disparity nearer in the initial disparity.
constexpr float kOcclusionMargin = 1.0f;

// Potts penalties of the edges to the right and below each pixel, weakened across grey-level edges.
void EdgePenalties(const cv::Mat& image, const LayeredPairOptions& options, std::vector<float>* right,
                   std::vector<float>* down);

// Labels minimising sum_p cost(p, l_p) + sum_{pq} penalty_pq [l_p != l_q], approximately, by
// semi-global aggregation of the label costs (pixel-major: cost[i * num_labels + l]) along the 4
// image directions and winner-take-all. `sum` holds the horizontal paths' sums; each pass reads or
// writes it once (the passes are memory-bound).
void AssignLabels(const std::vector<float>& cost, int num_labels, int w, int h, const std::vector<float>& right,
                  const std::vector<float>& down, std::vector<float>* sum, cv::Mat* labels);

// The right view's z-buffer: per row, the largest valid disparity of `disparity` (the initial one)
// landing on each right-image pixel, each pair of valid neighbours less than a pixel of disparity
// apart rasterised as a segment (so that a slanted surface leaves no gaps).
cv::Mat RightZBuffer(const cv::Mat& disparity, const std::vector<uint8_t>& hole);

// Occlusion reasoning at the pixels the initial left-right check rejected: under a layer whose match
// falls on a nearer surface of the initial disparity (zbuffer), the pixel is occluded and costs
// occlusion_cost. A farther layer is occluded there and a nearer is not, so such pixels join the
// background, where occluded regions belong.
void ApplyOcclusion(const std::vector<uint8_t>& hole, const cv::Mat& zbuffer, const std::vector<DisparityPlane>& planes,
                    float occlusion_cost, std::vector<float>* cost);

}  // namespace layered_internal
}  // namespace ibmr
