// Step 4's assignment of the two-view layered method (layer_labels.h): Potts penalties, semi-global
// aggregation over the labels, the right view's z-buffer and the occlusion costs. Follows seed 000
// lines 5625-5811 (Szeliski, BMVC'99, section 4: boolean pixel assignments B_kl) and 3798-3846
// (slides "Layered Stereo": occluded regions).
#include "stages/layered_stereo/layer_labels.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>

#include "stages/layered_stereo/layered_pair_internal.h"

namespace ibmr {
namespace layered_internal {

namespace {

// Minimum of v[0..n), four chains (the compiler keeps float min reductions scalar).
inline float MinOf(const float* v, int n) {
  float m0 = v[0], m1 = v[0], m2 = v[0], m3 = v[0];
  int l = 0;
  for (; l + 4 <= n; l += 4) {
    m0 = Min(m0, v[l]), m1 = Min(m1, v[l + 1]), m2 = Min(m2, v[l + 2]), m3 = Min(m3, v[l + 3]);
  }
  for (; l < n; ++l) m0 = Min(m0, v[l]);
  return Min(Min(m0, m1), Min(m2, m3));
}

// One step of a semi-global path: out[l] = cost[l] + min(prev[l], min prev + penalty) - min prev.
inline void PathStep(const float* __restrict cost, const float* __restrict prev, float penalty, int num_labels,
                     float* __restrict out) {
  const float m = MinOf(prev, num_labels), jump = m + penalty;
  for (int l = 0; l < num_labels; ++l) out[l] = cost[l] + Min(prev[l], jump) - m;
}

}  // namespace

void EdgePenalties(const cv::Mat& image, const LayeredPairOptions& options, std::vector<float>* right,
                   std::vector<float>* down) {
  const int w = image.cols, h = image.rows, channels = image.channels();
  right->assign(static_cast<size_t>(w) * h, 0.f);
  down->assign(static_cast<size_t>(w) * h, 0.f);
  const float strong = static_cast<float>(options.smoothness);
  const float weak = static_cast<float>(options.smoothness * options.edge_factor);
  auto step = [&](const uint8_t* p, const uint8_t* q) {
    int m = 0;
    for (int c = 0; c < channels; ++c) m = std::max(m, std::abs(p[c] - q[c]));
    return options.edge_threshold > 0 && m >= options.edge_threshold ? weak : strong;
  };
  tbb::parallel_for(0, h, [&](int y) {
    const uint8_t* row = image.ptr<uint8_t>(y);
    const uint8_t* below = image.ptr<uint8_t>(std::min(y + 1, h - 1));
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (x + 1 < w) (*right)[i] = step(row + x * channels, row + (x + 1) * channels);
      if (y + 1 < h) (*down)[i] = step(row + x * channels, below + x * channels);
    }
  });
}

void AssignLabels(const std::vector<float>& cost, int num_labels, int w, int h, const std::vector<float>& right,
                  const std::vector<float>& down, std::vector<float>* sum, cv::Mat* labels) {
  const int nl = num_labels;
  sum->resize(cost.size());
  float* total = sum->data();
  const float* c = cost.data();
  // Horizontal paths, a row per task: left to right into a row buffer, right to left added to it.
  tbb::parallel_for(0, h, [&](int y) {
    std::vector<float> forward(static_cast<size_t>(w) * nl), path(2 * nl);  // per row, not per pixel
    const size_t row = static_cast<size_t>(y) * w;
    std::copy(c + row * nl, c + (row + 1) * nl, forward.data());
    for (int x = 1; x < w; ++x) {
      PathStep(c + (row + x) * nl, forward.data() + (x - 1) * nl, right[row + x - 1], nl, forward.data() + x * nl);
    }
    float* prev = path.data();
    float* cur = prev + nl;
    std::copy(c + (row + w - 1) * nl, c + (row + w) * nl, prev);
    for (int l = 0; l < nl; ++l) total[(row + w - 1) * nl + l] = forward[(w - 1) * nl + l] + prev[l];
    for (int x = w - 2; x >= 0; --x) {
      const size_t i = row + x;
      PathStep(c + i * nl, prev, right[i], nl, cur);
      for (int l = 0; l < nl; ++l) total[i * nl + l] = forward[x * nl + l] + cur[l];
      std::swap(prev, cur);
    }
  });
  // Vertical paths, a block of columns per task: top to bottom into a block buffer, bottom to top
  // added to it and to the horizontal sums, and the label with the lowest total.
  labels->create(h, w, CV_32S);
  constexpr int kColumns = 16;
  // A block's downward paths (h * 16 * layers floats) in a buffer per thread: allocated per block,
  // they would be mapped and faulted in afresh each time.
  tbb::enumerable_thread_specific<std::vector<float>> buffers;
  tbb::parallel_for(0, (w + kColumns - 1) / kColumns, [&](int block) {
    const int x0 = block * kColumns, x1 = std::min(w, x0 + kColumns), bw = x1 - x0;
    const size_t row_size = static_cast<size_t>(bw) * nl;
    std::vector<float>& downward = buffers.local();
    downward.resize(static_cast<size_t>(h) * kColumns * nl);
    std::vector<float> path(2 * row_size);
    for (int x = x0; x < x1; ++x) std::copy(c + x * nl, c + (x + 1) * nl, downward.data() + (x - x0) * nl);
    for (int y = 1; y < h; ++y) {
      const size_t edge_row = static_cast<size_t>(y - 1) * w;
      for (int x = x0; x < x1; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        PathStep(c + i * nl, downward.data() + (y - 1) * row_size + (x - x0) * nl, down[edge_row + x], nl,
                 downward.data() + y * row_size + (x - x0) * nl);
      }
    }
    float* prev = path.data();
    float* cur = prev + row_size;
    for (int y = h - 1; y >= 0; --y) {
      int* label = labels->ptr<int>(y);
      for (int x = x0; x < x1; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        float* up = cur + (x - x0) * nl;
        if (y == h - 1) {
          std::copy(c + i * nl, c + (i + 1) * nl, up);
        } else {
          PathStep(c + i * nl, prev + (x - x0) * nl, down[i], nl, up);
        }
        const float* t = total + i * nl;
        const float* d = downward.data() + y * row_size + (x - x0) * nl;
        int best = 0;
        float best_sum = t[0] + d[0] + up[0];
        for (int l = 1; l < nl; ++l) {
          const float v = t[l] + d[l] + up[l];
          if (v < best_sum) best_sum = v, best = l;
        }
        label[x] = best;
      }
      std::swap(prev, cur);
    }
  });
}

cv::Mat RightZBuffer(const cv::Mat& disparity, const std::vector<uint8_t>& hole) {
  const int w = disparity.cols, h = disparity.rows;
  cv::Mat zbuffer(h, w, CV_32F);
  tbb::parallel_for(0, h, [&](int y) {
    float* z = zbuffer.ptr<float>(y);
    std::fill(z, z + w, -std::numeric_limits<float>::infinity());
    const float* d = disparity.ptr<float>(y);
    const uint8_t* invalid = hole.data() + static_cast<size_t>(y) * w;
    for (int x = 0; x < w; ++x) {
      if (invalid[x]) continue;
      float lo = x - d[x], hi = lo, dmin = d[x];
      if (x + 1 < w && !invalid[x + 1] && std::fabs(d[x + 1] - d[x]) < 1.f) {
        lo = std::min(lo, x + 1 - d[x + 1]), hi = std::max(hi, x + 1 - d[x + 1]), dmin = std::min(d[x], d[x + 1]);
      }
      const int first = std::max(0, RoundToInt(lo));
      const int last = std::min(w - 1, RoundToInt(hi));
      for (int xr = first; xr <= last; ++xr) z[xr] = std::max(z[xr], dmin);
    }
  });
  return zbuffer;
}

void ApplyOcclusion(const std::vector<uint8_t>& hole, const cv::Mat& zbuffer, const std::vector<DisparityPlane>& planes,
                    float occlusion_cost, std::vector<float>* cost) {
  const int w = zbuffer.cols, h = zbuffer.rows, nl = static_cast<int>(planes.size());
  tbb::parallel_for(0, h, [&](int y) {
    const float* z = zbuffer.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (!hole[i]) continue;
      for (int l = 0; l < nl; ++l) {
        const float d = static_cast<float>(planes[l].Disparity(x, y));
        const int xr = RoundToInt(x - d);
        if (xr >= 0 && xr < w && z[xr] > d + kOcclusionMargin) (*cost)[i * nl + l] = occlusion_cost;
      }
    }
  });
}

}  // namespace layered_internal
}  // namespace ibmr
