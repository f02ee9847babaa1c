// Step 4's data costs of the two-view layered method (layer_costs.h): census codes, raw costs of a
// row along a layer's plane, window sums, the residual minimum with its sub-pixel offset. Follows
// seed 000 lines 5625-5811 (Szeliski, BMVC'99, section 4: each layer's match cost through its
// plane, plus a residual depth) and 3798-3846 (slides "Layered Stereo").
#include "stages/layered_stereo/layer_costs.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stages/layered_stereo/layered_pair_internal.h"

namespace ibmr {
namespace layered_internal {

namespace {

// Census window 9x7 (62 comparisons, as plane_sweep's two-view default): cost units 0..62.
constexpr int kCensusRadiusX = 4;
constexpr int kCensusRadiusY = 3;
constexpr int kMaxResidualSlices = 2 * 16 + 1;
// Cost of a negative disparity (behind the cameras' baseline at infinity): the worst census cost.
constexpr float kImpossibleCost = 62.f;

// Costs at the integer disparities floor - R .. floor + R + 1: census Hamming distance, or
// `outside` left of the right image, or kImpossibleCost for a negative disparity. Inlined into a
// popcnt-enabled caller where available.
inline __attribute__((always_inline)) void IntegerCostsImpl(const uint64_t* __restrict left,
                                                           const uint64_t* __restrict right, int w, int range,
                                                           float outside, RawRowScratch* s) {
  static const auto kHamming = [] {  // Hamming distance as float, by table (no int-float conversion)
    std::array<float, 65> table{};
    for (int i = 0; i <= 64; ++i) table[i] = static_cast<float>(i);
    return table;
  }();
  const int32_t* __restrict floor = s->floor.data();
  for (int k = 0; k <= 2 * range + 1; ++k) {
    float* __restrict out = s->integer.data() + static_cast<size_t>(k) * w;
    for (int x = 0; x < w; ++x) {
      const int d = floor[x] - range + k, xr = x - d;
      out[x] = d < 0 ? kImpossibleCost : xr < 0 ? outside : kHamming[__builtin_popcountll(left[x] ^ right[xr])];
    }
  }
}

#if defined(__x86_64__) && defined(__GNUC__)
__attribute__((target("popcnt"))) void IntegerCostsPopcnt(const uint64_t* left, const uint64_t* right, int w,
                                                           int range, float outside, RawRowScratch* s) {
  IntegerCostsImpl(left, right, w, range, outside, s);
}
bool HavePopcnt() {
  static const bool have = [] {
    __builtin_cpu_init();  // may run before libgcc's own initialisation otherwise
    return __builtin_cpu_supports("popcnt") != 0;
  }();
  return have;
}
#endif
void IntegerCostsPortable(const uint64_t* left, const uint64_t* right, int w, int range, float outside,
                          RawRowScratch* s) {
  IntegerCostsImpl(left, right, w, range, outside, s);
}

// Raw (unaggregated) census costs of row y at disparities plane(x, y) + r, r = -R..R, linearly
// interpolated between the integer disparities around each (the plane-stabilised residual sweep):
// slices[k] gets residual k - R. A match left of the right image costs occlusion_cost, a negative
// disparity kImpossibleCost. Float passes over x (vectorised) around the integer pass.
void RawCostRow(const MatchInput& in, const DisparityPlane& plane, int y, int range, float occlusion_cost,
                RawRowScratch* s, float* const* slices) {
  const int w = in.width;
  s->floor.resize(w);
  s->fraction.resize(w);
  s->integer.resize(static_cast<size_t>(2 * range + 2) * w);
  const float e0 = static_cast<float>(std::clamp(plane.Disparity(0, y), -1e6, 1e6));
  const float a = static_cast<float>(std::clamp(plane.a, -kMaxGradient, kMaxGradient));
  int32_t* __restrict floor = s->floor.data();
  float* __restrict fraction = s->fraction.data();
  for (int x = 0; x < w; ++x) {
    const float e = e0 + a * x;
    const int32_t t = static_cast<int32_t>(e);  // towards zero; one less below zero
    floor[x] = t - (e < static_cast<float>(t) ? 1 : 0);
    fraction[x] = e - static_cast<float>(floor[x]);
  }
  const uint64_t* left = in.left.data() + static_cast<size_t>(y) * w;
  const uint64_t* right = in.right.data() + static_cast<size_t>(y) * w;
#if defined(__x86_64__) && defined(__GNUC__)
  if (HavePopcnt()) {
    IntegerCostsPopcnt(left, right, w, range, occlusion_cost, s);
  } else {
    IntegerCostsPortable(left, right, w, range, occlusion_cost, s);
  }
#else
  IntegerCostsPortable(left, right, w, range, occlusion_cost, s);
#endif
  for (int k = 0; k <= 2 * range; ++k) {
    const float* __restrict c0 = s->integer.data() + static_cast<size_t>(k) * w;
    const float* __restrict c1 = c0 + w;
    float* __restrict out = slices[k];
    for (int x = 0; x < w; ++x) out[x] = c0[x] + fraction[x] * (c1[x] - c0[x]);
  }
}

// Raw costs of one layer (RawCostRow) summed over 2r+1 pixels along each row, border replicated:
// scratch->hsum, one image per residual.
void RowWindowSums(const MatchInput& in, const DisparityPlane& plane, const LayeredPairOptions& options,
                   LayerScratch* scratch) {
  const int w = in.width, h = in.height, n = 2 * options.residual_range + 1;
  const int r = options.window_radius, padded = w + 2 * r;
  const size_t image = static_cast<size_t>(w) * h;
  scratch->raw.resize(static_cast<size_t>(n) * padded);
  scratch->hsum.resize(n * image);
  float* rows[kMaxResidualSlices];
  for (int k = 0; k < n; ++k) rows[k] = scratch->raw.data() + static_cast<size_t>(k) * padded + r;
  for (int y = 0; y < h; ++y) {
    RawCostRow(in, plane, y, options.residual_range, static_cast<float>(options.occlusion_cost), &scratch->raw_row,
               rows);
    for (int k = 0; k < n; ++k) {
      float* row = rows[k];
      for (int j = 1; j <= r; ++j) row[-j] = row[0], row[w - 1 + j] = row[w - 1];
      float* __restrict out = scratch->hsum.data() + k * image + static_cast<size_t>(y) * w;
      const float* __restrict src = row - r;
      std::copy(src, src + w, out);
      for (int j = 1; j <= 2 * r; ++j) {
        for (int x = 0; x < w; ++x) out[x] += src[x + j];
      }
    }
  }
}

// Sub-pixel residual: where residual k is the best (best_k[x] == k), d[x] += the offset of the
// parabola's vertex through the costs c0, c1, c2 of residuals k - 1, k, k + 1, within half a pixel.
// Computed at every x and kept by a select, so that the loop is vectorised.
void AddParabolaOffsets(const float* __restrict c0, const float* __restrict c1, const float* __restrict c2,
                        const float* __restrict best_k, int k, int w, float* __restrict d) {
  const float kf = static_cast<float>(k);
  for (int x = 0; x < w; ++x) {
    const float curvature = c0[x] - 2.f * c1[x] + c2[x];
    const bool convex = curvature > 1e-6f;
    const float denominator = convex ? curvature : 1.f;  // (a variable: inline, it stops vectorisation)
    const float offset = 0.5f * (c0[x] - c2[x]) / denominator;
    const float clamped = Min(0.5f, -Min(0.5f, -offset));
    d[x] += ((best_k[x] == kf) & convex) ? clamped : 0.f;  // & not &&: no branch
  }
}

// Costs of one layer at every pixel i = y * width + x: the census cost over the (2r+1)^2 window
// following the plane, minimised over the residual (plus residual_penalty |residual|), plus the
// prior initial_weight * min(|d - initial d|, initial_truncation), written to cost[i]; the disparity
// at the minimum (plane + residual, + parabola sub-pixel) to disparity[i]. Row by row in passes
// over x that the compiler vectorises, except the census lookups.
void LayerCosts(const MatchInput& in, const DisparityPlane& plane, const LayeredPairOptions& options,
                const Prior& prior, LayerScratch* scratch, float* cost, float* disparity) {
  const int w = in.width, h = in.height, range = options.residual_range, n = 2 * range + 1;
  const int r = options.window_radius;
  const size_t image = static_cast<size_t>(w) * h;
  RowWindowSums(in, plane, options, scratch);
  scratch->vsum.resize(static_cast<size_t>(n) * w);
  scratch->best.resize(w);
  scratch->best_k.resize(w);
  // Column sums of the row sums, running down the image (border rows replicated).
  auto hsum_row = [&](int k, int y) {
    return scratch->hsum.data() + k * image + static_cast<size_t>(std::clamp(y, 0, h - 1)) * w;
  };
  auto vsum_row = [&](int k) { return scratch->vsum.data() + static_cast<size_t>(k) * w; };
  for (int k = 0; k < n; ++k) {
    float* v = vsum_row(k);
    std::fill(v, v + w, 0.f);
    for (int j = -r; j <= r; ++j) {
      const float* src = hsum_row(k, j);
      for (int x = 0; x < w; ++x) v[x] += src[x];
    }
  }
  const float scale = 1.f / ((2 * r + 1) * (2 * r + 1));
  const float penalty = static_cast<float>(options.residual_penalty);
  const float truncation = static_cast<float>(options.initial_truncation);
  float* __restrict best = scratch->best.data();
  float* __restrict best_k = scratch->best_k.data();
  for (int y = 0; y < h; ++y) {
    const float* centre = vsum_row(range);
    for (int x = 0; x < w; ++x) best[x] = centre[x] * scale, best_k[x] = static_cast<float>(range);
    for (int k = 0; k < n; ++k) {
      if (k == range) continue;
      const float* v = vsum_row(k);
      const float extra = penalty * std::abs(k - range), kf = static_cast<float>(k);
      for (int x = 0; x < w; ++x) {
        const float c = v[x] * scale + extra;
        best_k[x] = c < best[x] ? kf : best_k[x];
        best[x] = Min(best[x], c);
      }
    }
    const size_t row = static_cast<size_t>(y) * w;
    float* __restrict d = disparity + row;
    const float e0 = static_cast<float>(plane.Disparity(0, y)), a = static_cast<float>(plane.a);
    for (int x = 0; x < w; ++x) d[x] = e0 + a * x + (best_k[x] - range);
    for (int k = 1; options.subpixel && k + 1 < n; ++k) {
      AddParabolaOffsets(vsum_row(k - 1), vsum_row(k), vsum_row(k + 1), best_k, k, w, d);
    }
    const float* __restrict init = prior.disparity.data() + row;
    const float* __restrict weight = prior.weight.data() + row;
    float* __restrict out = cost + row;
    for (int x = 0; x < w; ++x) out[x] = best[x] + weight[x] * Min(std::fabs(init[x] - d[x]), truncation);
    if (y + 1 == h) break;
    for (int k = 0; k < n; ++k) {  // the next row's column sums
      float* __restrict v = vsum_row(k);
      const float* __restrict add = hsum_row(k, y + 1 + r);
      const float* __restrict sub = hsum_row(k, y - r);
      for (int x = 0; x < w; ++x) v[x] += add[x] - sub[x];
    }
  }
}

}  // namespace

std::vector<uint64_t> Census(const cv::Mat& gray) {
  const int w = gray.cols, h = gray.rows;
  cv::Mat padded;
  cv::copyMakeBorder(gray, padded, kCensusRadiusY, kCensusRadiusY, kCensusRadiusX, kCensusRadiusX, cv::BORDER_REPLICATE);
  std::vector<uint64_t> codes(static_cast<size_t>(w) * h, 0);
  // Captured by value: a byte store may alias a captured reference, which would stop vectorisation.
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&codes, &padded, w](const tbb::blocked_range<int>& rows) {
    std::vector<uint8_t> planes(8 * static_cast<size_t>(w));  // per block of rows
    for (int y = rows.begin(); y < rows.end(); ++y) {
      std::fill(planes.begin(), planes.end(), 0);
      const uint8_t* __restrict centre = padded.ptr<uint8_t>(y + kCensusRadiusY) + kCensusRadiusX;
      int bit = 0;
      for (int dy = -kCensusRadiusY; dy <= kCensusRadiusY; ++dy) {
        const uint8_t* row = padded.ptr<uint8_t>(y + kCensusRadiusY + dy) + kCensusRadiusX;
        for (int dx = -kCensusRadiusX; dx <= kCensusRadiusX; ++dx) {
          if (dx == 0 && dy == 0) continue;
          const uint8_t* __restrict neighbour = row + dx;
          uint8_t* __restrict plane = planes.data() + static_cast<size_t>(bit / 8) * w;
          for (int x = 0; x < w; ++x) plane[x] = static_cast<uint8_t>((plane[x] << 1) | (neighbour[x] > centre[x] ? 1 : 0));
          ++bit;
        }
      }
      uint64_t* __restrict code = codes.data() + static_cast<size_t>(y) * w;
      for (int j = 0; j < 8; ++j) {
        const uint8_t* __restrict plane = planes.data() + static_cast<size_t>(j) * w;
        for (int x = 0; x < w; ++x) code[x] |= static_cast<uint64_t>(plane[x]) << (8 * j);
      }
    }
  });
  return codes;
}

Prior MakePrior(const cv::Mat& initial, const std::vector<uint8_t>& hole, double weight) {
  Prior prior;
  prior.disparity.resize(hole.size());
  prior.weight.resize(hole.size());
  for (int y = 0; y < initial.rows; ++y) {
    const float* d = initial.ptr<float>(y);
    for (int x = 0; x < initial.cols; ++x) {
      const size_t i = static_cast<size_t>(y) * initial.cols + x;
      prior.disparity[i] = hole[i] ? 0.f : d[x];
      prior.weight[i] = hole[i] ? 0.f : static_cast<float>(weight);
    }
  }
  return prior;
}

void AllLayerCosts(const MatchInput& match, const std::vector<DisparityPlane>& planes, const Prior& prior,
                   const LayeredPairOptions& options, tbb::enumerable_thread_specific<LayerScratch>* scratch,
                   std::vector<float>* layer_cost, std::vector<float>* cost, std::vector<float>* disparity) {
  const size_t n = static_cast<size_t>(match.width) * match.height;
  const int nl = static_cast<int>(planes.size());
  layer_cost->resize(n * nl);
  disparity->resize(n * nl);
  tbb::parallel_for(0, nl, [&](int l) {
    LayerCosts(match, planes[l], options, prior, &scratch->local(), layer_cost->data() + l * n,
               disparity->data() + l * n);
  });
  cost->resize(n * nl);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& pixels) {
    for (size_t i = pixels.begin(); i < pixels.end(); ++i) {
      for (int l = 0; l < nl; ++l) (*cost)[i * nl + l] = (*layer_cost)[l * n + i];
    }
  });
}

}  // namespace layered_internal
}  // namespace ibmr
