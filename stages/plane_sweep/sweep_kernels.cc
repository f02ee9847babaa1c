// The engine's inner loops: census transform, cost volume (census, SAD, ZNCC; best-k over
// neighbours; box aggregation), semi-global aggregation and winner-take-all. See sweep_engine.h for
// the method and the seed-paper sections it follows.
//
// This file is compiled three times (stages/plane_sweep/CMakeLists.txt), into namespace
// ibmr::sweep::IBMR_SWEEP_ISA:
//  * `portable`: the baseline instruction set (x86-64-v2 on x86: SSE4.2 and POPCNT);
//  * `avx2`: the same source under `#pragma GCC target` for AVX2 (with BMI2 and POPCNT), where
//    the compiler vectorises the same loops over 256-bit registers (16 x 16-bit lanes) and the
//    census cost stays the scalar POPCNT loop (AVX2 has no vector popcount; the nibble-table
//    method costs more shuffles than POPCNT costs cycles on 64-bit codes);
//  * `avx512`: the same source under `#pragma GCC target` for AVX-512 (F, BW, DQ, VL, VPOPCNTDQ),
//    where the compiler vectorises the 16-bit box loops over 32 lanes and the census cost uses
//    the explicit VPOPCNTQ kernels below: a lane per reference pixel for warped neighbours (codes
//    fetched by contiguous loads and permutes, BestKCostsAcrossPixels; two codes a lane when the
//    cost is interpolated along one axis, CensusSampling), a lane per plane with gathers otherwise.
// The semi-global steps and winner-take-all are written once over vectors of 16-bit lanes (8 in
// the portable build, 16 in the AVX2 build, 16 or 32 in the AVX-512 build; see Lanes).
// sweep_engine.cc picks one at run time. The pragma (not -march on the command line) keeps
// the AVX-512 code inside this file's own functions: template code from headers (std::vector,
// TBB) is compiled for the baseline, so the linker cannot hand an AVX-512 copy of it to the
// portable path. Both builds give bit-identical results: costs are integers, every float step
// is an elementwise IEEE operation, and floating-point contraction (FMA) is off for this file.
#include "stages/plane_sweep/sweep_kernels.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <limits>
#include <thread>
#include <opencv2/imgproc.hpp>
#if defined(__SSE4_1__)  // x86-64-v2, the baseline of every build on x86
#include <smmintrin.h>
#endif

#if IBMR_SWEEP_AVX512
#include <immintrin.h>
#pragma GCC push_options
#pragma GCC target("avx2,fma,bmi,bmi2,popcnt,avx512f,avx512bw,avx512dq,avx512vl,avx512cd,avx512vpopcntdq")
#elif IBMR_SWEEP_AVX2
#include <immintrin.h>
#pragma GCC push_options
#pragma GCC target("avx2,fma,bmi,bmi2,popcnt")
#endif

#ifndef IBMR_SWEEP_ISA
#error "compile with -DIBMR_SWEEP_ISA=portable, avx2 or avx512 (see CMakeLists.txt)"
#endif

namespace ibmr {
namespace sweep {
namespace IBMR_SWEEP_ISA {

namespace {

constexpr int16_t kSentinel = 0x3FFF;

int RoundUp16(int n) { return (n + 15) / 16 * 16; }

// Cost of a pixel whose correspondence falls outside the neighbour: neutral, so that best-k
// prefers neighbours that see the point.
constexpr uint16_t kOutsideCost = 600;

// CPU time of a parallel loop's tasks, summed over the threads (VolumeWork's times). Each task
// times its own work with a Scope: a clock around the loop would also count the other tasks its
// thread ran while it waited.
class TaskSeconds {
 public:
  class Scope {
   public:
    explicit Scope(TaskSeconds* total) : slot_(total->seconds_.local()), started_(ThreadCpuSeconds()) {}
    ~Scope() { slot_ += ThreadCpuSeconds() - started_; }
    Scope(const Scope&) = delete;
    Scope& operator=(const Scope&) = delete;

   private:
    double& slot_;
    double started_;
  };
  double Total() { return seconds_.combine(std::plus<double>()); }

 private:
  tbb::enumerable_thread_specific<double> seconds_{0.0};
};

// Per-worker scratch for one plane.
struct PlaneScratch {
  std::vector<std::vector<uint16_t>> slices;  // per neighbour, W*H
  std::vector<uint32_t> row_sums;
  std::vector<float> warped, wsum, wsq, wcross;
};

bool IsIntegerTranslation(const Eigen::Matrix3d& h, int* dx, int* dy) {
  if (h(2, 0) != 0 || h(2, 1) != 0 || h(2, 2) != 1 || h(0, 0) != 1 || h(1, 1) != 1 || h(0, 1) != 0 ||
      h(1, 0) != 0) {
    return false;
  }
  if (h(0, 2) != std::round(h(0, 2)) || h(1, 2) != std::round(h(1, 2))) return false;
  *dx = static_cast<int>(h(0, 2));
  *dy = static_cast<int>(h(1, 2));
  return true;
}

// Bilinear warp of the neighbour's grey image by the plane homography, for the w x h pixels from
// `origin` of the image the homography maps from; NaN outside.
void WarpGray(const cv::Mat& src, int w, int h, cv::Point origin, const Eigen::Matrix3d& hom, float* out) {
  const float h00 = hom(0, 0), h01 = hom(0, 1), h02 = hom(0, 2), h10 = hom(1, 0), h11 = hom(1, 1),
              h12 = hom(1, 2), h20 = hom(2, 0), h21 = hom(2, 1), h22 = hom(2, 2);
  const int sw = src.cols, sh = src.rows;
  for (int y = 0; y < h; ++y) {
    const float yc = (y + origin.y) + 0.5f;
    for (int x = 0; x < w; ++x) {
      const float xc = (x + origin.x) + 0.5f;
      const float z = h20 * xc + h21 * yc + h22;
      const float u = (h00 * xc + h01 * yc + h02) / z - 0.5f, v = (h10 * xc + h11 * yc + h12) / z - 0.5f;
      float value = std::numeric_limits<float>::quiet_NaN();
      if (z > 0 && u >= 0 && v >= 0 && u <= sw - 1 && v <= sh - 1) {
        const int x0 = std::min(static_cast<int>(u), sw - 2 < 0 ? 0 : sw - 2);
        const int y0 = std::min(static_cast<int>(v), sh - 2 < 0 ? 0 : sh - 2);
        const float fx = u - x0, fy = v - y0;
        const uint8_t* p0 = src.ptr<uint8_t>(y0) + x0;
        const uint8_t* p1 = src.ptr<uint8_t>(std::min(y0 + 1, sh - 1)) + x0;
        const int xo = x0 + 1 < sw ? 1 : 0;
        value = (1 - fy) * ((1 - fx) * p0[0] + fx * p0[xo]) + fy * ((1 - fx) * p1[0] + fx * p1[xo]);
      }
      out[static_cast<size_t>(y) * w + x] = value;
    }
  }
}

// In-place box mean of a uint16 slice with radius r (borders: window clipped to the image).
void BoxMean(uint16_t* slice, int w, int h, int r, std::vector<uint32_t>* tmp) {
  if (r <= 0) return;
  tmp->assign(static_cast<size_t>(w) * h, 0);
  uint32_t* t = tmp->data();
  // Vertical sums.
  std::vector<uint32_t> col(w, 0);
  for (int y = 0; y < std::min(r, h); ++y)
    for (int x = 0; x < w; ++x) col[x] += slice[static_cast<size_t>(y) * w + x];
  for (int y = 0; y < h; ++y) {
    if (y + r < h)
      for (int x = 0; x < w; ++x) col[x] += slice[static_cast<size_t>(y + r) * w + x];
    if (y - r - 1 >= 0)
      for (int x = 0; x < w; ++x) col[x] -= slice[static_cast<size_t>(y - r - 1) * w + x];
    std::copy(col.begin(), col.end(), t + static_cast<size_t>(y) * w);
  }
  const int ny_full = 2 * r + 1;
  for (int y = 0; y < h; ++y) {
    const int ny = std::min(h - 1, y + r) - std::max(0, y - r) + 1;
    const uint32_t* c = t + static_cast<size_t>(y) * w;
    uint16_t* o = slice + static_cast<size_t>(y) * w;
    uint32_t sum = 0;
    for (int x = 0; x < std::min(r, w); ++x) sum += c[x];
    for (int x = 0; x < w; ++x) {
      if (x + r < w) sum += c[x + r];
      if (x - r - 1 >= 0) sum -= c[x - r - 1];
      const int nx = std::min(w - 1, x + r) - std::max(0, x - r) + 1;
      o[x] = static_cast<uint16_t>((sum + (nx * ny) / 2) / (nx * ny));
    }
  }
  (void)ny_full;
}

// Box sums of a float image (NaN-free input) with clipped borders, as means.
void BoxMeanFloat(const float* in, float* out, int w, int h, int r) {
  cv::Mat src(h, w, CV_32F, const_cast<float*>(in)), dst(h, w, CV_32F, out);
  cv::boxFilter(src, dst, CV_32F, cv::Size(2 * r + 1, 2 * r + 1), cv::Point(-1, -1), true, cv::BORDER_REFLECT);
}

void SadSlice(const cv::Mat& ref, cv::Point origin, const cv::Mat& src, const Eigen::Matrix3d& hom, PlaneScratch* s,
              uint16_t* out) {
  const int w = ref.cols, h = ref.rows;
  s->warped.resize(static_cast<size_t>(w) * h);
  WarpGray(src, w, h, origin, hom, s->warped.data());
  for (int y = 0; y < h; ++y) {
    const uint8_t* r = ref.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      const float v = s->warped[static_cast<size_t>(y) * w + x];
      out[static_cast<size_t>(y) * w + x] =
          std::isnan(v) ? kOutsideCost : static_cast<uint16_t>(std::min(1020.f, 4.f * std::fabs(v - r[x])));
    }
  }
}

void ZnccSlice(const cv::Mat& ref, cv::Point origin, const cv::Mat& ref_mean, const cv::Mat& ref_var, const cv::Mat& src,
               const Eigen::Matrix3d& hom, int radius, PlaneScratch* s, uint16_t* out) {
  const int w = ref.cols, h = ref.rows;
  const size_t n = static_cast<size_t>(w) * h;
  s->warped.resize(n);
  s->wsum.resize(n);
  s->wsq.resize(n);
  s->wcross.resize(n);
  WarpGray(src, w, h, origin, hom, s->warped.data());
  std::vector<uint8_t> outside(n);
  for (size_t i = 0; i < n; ++i) {
    outside[i] = std::isnan(s->warped[i]);
    if (outside[i]) s->warped[i] = 0;
  }
  for (int y = 0; y < h; ++y) {
    const uint8_t* r = ref.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      s->wsq[i] = s->warped[i] * s->warped[i];
      s->wcross[i] = s->warped[i] * r[x];
    }
  }
  BoxMeanFloat(s->warped.data(), s->wsum.data(), w, h, radius);
  BoxMeanFloat(s->wsq.data(), s->wsq.data(), w, h, radius);
  BoxMeanFloat(s->wcross.data(), s->wcross.data(), w, h, radius);
  for (int y = 0; y < h; ++y) {
    const float* rm = ref_mean.ptr<float>(y);
    const float* rv = ref_var.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const float var = s->wsq[i] - s->wsum[i] * s->wsum[i];
      const float cov = s->wcross[i] - s->wsum[i] * rm[x];
      const float ncc = cov / std::sqrt(std::max(1e-3f, var * rv[x]) + 4.f);
      out[i] = outside[i] ? kOutsideCost : static_cast<uint16_t>(std::clamp(500.f * (1.f - ncc), 0.f, 1000.f));
    }
  }
}

// Vectors of 16-bit lanes (GCC vector extensions). Every operation on them is an elementwise
// integer one, so all builds give the same values whatever the width. `Lanes` is one register of
// the build: 16 lanes in the AVX2 and AVX-512 builds, 8 in the portable one (a 16-lane vector
// there became two SSE registers, handled poorly: 2.7 times slower). `WideLanes` is the widest the
// build has: 32 lanes (one AVX-512 register) in the AVX-512 build, else `Lanes`; the semi-global
// steps use it where the planes come in multiples of it (teddy's 64: 15-20% less time than 16
// lanes). Volume strides are multiples of 16.
typedef int16_t Lanes8 __attribute__((vector_size(16)));
typedef int16_t Lanes16 __attribute__((vector_size(32)));
typedef uint16_t UnsignedLanes8 __attribute__((vector_size(16)));
typedef uint16_t UnsignedLanes16 __attribute__((vector_size(32)));
#if IBMR_SWEEP_AVX512
typedef int16_t Lanes32 __attribute__((vector_size(64)));
typedef uint16_t UnsignedLanes32 __attribute__((vector_size(64)));
#endif
#if IBMR_SWEEP_AVX2 || IBMR_SWEEP_AVX512
typedef Lanes16 Lanes;
typedef UnsignedLanes16 UnsignedLanes;
#else
typedef Lanes8 Lanes;
typedef UnsignedLanes8 UnsignedLanes;
#endif
#if IBMR_SWEEP_AVX512
typedef Lanes32 WideLanes;
#else
typedef Lanes WideLanes;
#endif
template <class V>
constexpr int kLanesOf = static_cast<int>(sizeof(V) / sizeof(int16_t));
constexpr int kLaneCount = kLanesOf<Lanes>;

template <class V>
inline V LoadLanes(const void* p) {
  V v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <class V>
inline void StoreLanes(void* p, V v) {
  std::memcpy(p, &v, sizeof v);
}
template <class V>
inline V SplatLanes(int16_t x) {
  return V{} + x;
}
template <class V>
inline V MinLanes(V a, V b) {
  return a < b ? a : b;
}
// uint16 sums wrap (signed vector overflow would not be defined).
inline Lanes8 AddWrapping(Lanes8 a, Lanes8 b) {
  return reinterpret_cast<Lanes8>(reinterpret_cast<UnsignedLanes8>(a) + reinterpret_cast<UnsignedLanes8>(b));
}
// The entries at d - 1 and d + 1 when `here` holds entries d.., `before` the lanes below and
// `after` those above: built in registers from whole-vector loads rather than loaded at an offset
// of one entry. A path's previous entries were often stored by the step just before (the row
// path's always): a load one entry off such a store spans two stores, which the CPU cannot
// forward, so each step of the row path waited for the last one's stores to reach the cache.
// (__builtin_shufflevector: GCC 12 and clang both have it; the fuzz build uses clang.)
inline Lanes8 EntriesBelow(Lanes8 before, Lanes8 here) {
  return __builtin_shufflevector(before, here, 7, 8, 9, 10, 11, 12, 13, 14);
}
inline Lanes8 EntriesAbove(Lanes8 here, Lanes8 after) {
  return __builtin_shufflevector(here, after, 1, 2, 3, 4, 5, 6, 7, 8);
}
#if IBMR_SWEEP_AVX2 || IBMR_SWEEP_AVX512  // (the portable build has no 256-bit registers to pass them in)
inline Lanes16 AddWrapping(Lanes16 a, Lanes16 b) {
  return reinterpret_cast<Lanes16>(reinterpret_cast<UnsignedLanes16>(a) + reinterpret_cast<UnsignedLanes16>(b));
}
inline Lanes16 EntriesBelow(Lanes16 before, Lanes16 here) {
  return __builtin_shufflevector(before, here, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30);
}
inline Lanes16 EntriesAbove(Lanes16 here, Lanes16 after) {
  return __builtin_shufflevector(here, after, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16);
}
#endif
// The least lane, unsigned (generic: any width, any build).
template <class U>
inline uint16_t LowestUnsignedLane(U v) {
  uint16_t m = v[0];
  for (int i = 1; i < kLanesOf<U>; ++i) m = std::min<uint16_t>(m, v[i]);
  return m;
}
#if defined(__SSE4_1__)
inline uint16_t LowestUnsignedLane(__m128i v) {
  return static_cast<uint16_t>(_mm_cvtsi128_si32(_mm_minpos_epu16(v)) & 0xFFFF);
}
inline uint16_t LowestUnsignedLane(UnsignedLanes8 v) {
  __m128i x;
  std::memcpy(&x, &v, sizeof x);
  return LowestUnsignedLane(x);
}
#if IBMR_SWEEP_AVX2 || IBMR_SWEEP_AVX512
inline uint16_t LowestUnsignedLane(UnsignedLanes16 v) {
  __m128i low, high;
  std::memcpy(&low, &v, sizeof low);
  std::memcpy(&high, reinterpret_cast<const char*>(&v) + sizeof low, sizeof high);
  return LowestUnsignedLane(_mm_min_epu16(low, high));
}
#endif
#endif
#if IBMR_SWEEP_AVX512
inline Lanes32 AddWrapping(Lanes32 a, Lanes32 b) {
  return reinterpret_cast<Lanes32>(reinterpret_cast<UnsignedLanes32>(a) + reinterpret_cast<UnsignedLanes32>(b));
}
inline Lanes32 EntriesBelow(Lanes32 before, Lanes32 here) {
  return __builtin_shufflevector(before, here, 31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44, 45, 46,
                                                 47, 48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62);
}
inline Lanes32 EntriesAbove(Lanes32 here, Lanes32 after) {
  return __builtin_shufflevector(here, after, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16,
                                                17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32);
}
inline uint16_t LowestUnsignedLane(UnsignedLanes32 v) {
  __m512i z;
  std::memcpy(&z, &v, sizeof z);
  const __m256i y = _mm256_min_epu16(_mm512_castsi512_si256(z), _mm512_extracti64x4_epi64(z, 1));
  return LowestUnsignedLane(_mm_min_epu16(_mm256_castsi256_si128(y), _mm256_extracti128_si256(y, 1)));
}
#endif
// The least lane of lanes that are all >= 0 (so the unsigned minimum is the signed one).
inline int16_t LowestLane(Lanes8 v) { return static_cast<int16_t>(LowestUnsignedLane(reinterpret_cast<UnsignedLanes8>(v))); }
#if IBMR_SWEEP_AVX2 || IBMR_SWEEP_AVX512
inline int16_t LowestLane(Lanes16 v) { return static_cast<int16_t>(LowestUnsignedLane(reinterpret_cast<UnsignedLanes16>(v))); }
#endif
#if IBMR_SWEEP_AVX512
inline int16_t LowestLane(Lanes32 v) { return static_cast<int16_t>(LowestUnsignedLane(reinterpret_cast<UnsignedLanes32>(v))); }
#endif
// The first lane holding x, or -1.
inline int FirstLaneEqual(UnsignedLanes v, uint16_t x) {
#if defined(__SSE4_1__)
  const UnsignedLanes equal = v == (UnsignedLanes{} + x);
  __m128i low, high = _mm_setzero_si128();
  std::memcpy(&low, &equal, sizeof low);
  if constexpr (kLaneCount == 16) std::memcpy(&high, reinterpret_cast<const char*>(&equal) + sizeof low, sizeof high);
  const uint32_t bits = static_cast<uint32_t>(_mm_movemask_epi8(low)) | static_cast<uint32_t>(_mm_movemask_epi8(high)) << 16;
  return bits == 0 ? -1 : __builtin_ctz(bits) / 2;
#else
  for (int i = 0; i < kLaneCount; ++i)
    if (v[i] == x) return i;
  return -1;
#endif
}

// One semi-global path step over the planes of one vector, d.., from the previous pixel's entries
// (here = L(p-r, d..), before and after the lanes on either side):
//   L(p,d) = C(p,d) + min(L(p-r,d), L(p-r,d+-1) + P1, min L(p-r) + P2) - min L(p-r).
// `min_p2` = min L(p-r) + P2, `min_prev` = min L(p-r). All values stay below 2^15 (costs below
// 2^11, penalties at most 6000): signed 16-bit lanes never overflow.
template <class V>
inline V PathLanes(V cost, V before, V here, V after, V p1, V min_p2, V min_prev) {
  const V t = MinLanes(MinLanes(here, EntriesBelow(before, here) + p1), MinLanes(EntriesAbove(here, after) + p1, min_p2));
  return cost + t - min_prev;
}

// One pixel's semi-global step along K paths at once (PathLanes' formula, path by path), for all
// n planes (a multiple of 16): sum[d] = sum over k of L_k(p,d) (or, kAccumulate, sum[d] plus that).
// `prev[k]` is path k's previous pixel; a path that starts here reads the zero row with min 0,
// which makes L = C. `cur[k]` receives L_k, `min_out[k]` its minimum. The sums wrap as uint16,
// like the volume they are added into, in any order.
template <int K, bool kAccumulate, class V>
inline void PathSteps(const uint16_t* __restrict c, int n, const int16_t* const* prev, const int16_t* min_prev,
                      const int16_t* p2, int16_t p1, int16_t* const* cur, int16_t* min_out, uint16_t* __restrict sum) {
  constexpr int kLanes = kLanesOf<V>;
  const V p1v = SplatLanes<V>(p1), sentinel = SplatLanes<V>(kSentinel);
  V min_p2[K], min_v[K], m[K], before[K], here[K];
  for (int k = 0; k < K; ++k) {
    min_p2[k] = SplatLanes<V>(static_cast<int16_t>(min_prev[k] + p2[k]));
    min_v[k] = SplatLanes<V>(min_prev[k]);
    m[k] = SplatLanes<V>(0x7FFF);
    before[k] = sentinel;
    here[k] = LoadLanes<V>(prev[k]);
  }
  for (int d = 0; d < n; d += kLanes) {
    const V cost = LoadLanes<V>(c + d);
    V total = kAccumulate ? LoadLanes<V>(sum + d) : V{};
#pragma GCC unroll 4
    for (int k = 0; k < K; ++k) {
      const V after = d + kLanes < n ? LoadLanes<V>(prev[k] + d + kLanes) : sentinel;
      const V l = PathLanes(cost, before[k], here[k], after, p1v, min_p2[k], min_v[k]);
      StoreLanes(cur[k] + d, l);
      m[k] = MinLanes(m[k], l);
      total = AddWrapping(total, l);
      before[k] = here[k];
      here[k] = after;
    }
    StoreLanes(sum + d, total);
  }
  for (int k = 0; k < K; ++k) min_out[k] = LowestLane(m[k]);
}

// One semi-global path step for all n planes along one path (PathSteps with K = 1): L(p, .) into
// `cur`, and into `sum` (kAssign) or added to it. `prev` holds L(p-r, .); outside 0..n-1 a path
// reads the sentinel. Returns min over d of L.
template <bool kAssign, class V>
inline int16_t PathStep(const uint16_t* __restrict c, const int16_t* prev, int16_t min_prev, int16_t p1,
                        int16_t p2, int n, int16_t* cur, uint16_t* __restrict sum) {
  int16_t min_out;
  PathSteps<1, !kAssign, V>(c, n, &prev, &min_prev, &p2, p1, &cur, &min_out, sum);
  return min_out;
}

template <bool kAssign>
inline int16_t PathStart(const uint16_t* __restrict c, int n, int16_t* __restrict cur, uint16_t* __restrict sum) {
  int16_t m = 0x7FFF;
  for (int d = 0; d < n; ++d) {
    const int16_t v = static_cast<int16_t>(c[d]);
    cur[d] = v;
    sum[d] = kAssign ? static_cast<uint16_t>(v) : static_cast<uint16_t>(sum[d] + v);
    m = std::min(m, v);
  }
  return m;
}

// The large-jump penalty by grey step |g0 - g1|: P2 / (1 + step / gamma), at least P1 + 1.
void FillP2Table(const EngineOptions& o, int16_t table[256]) {
  for (int g = 0; g < 256; ++g) {
    const double p2 = o.p2_gamma <= 0 ? o.p2 : o.p2 / (1.0 + g / o.p2_gamma);
    table[g] = static_cast<int16_t>(std::max<double>(static_cast<int16_t>(o.p1) + 1, p2));
  }
}

// Sets the padding entries of a pixel's sums `s` to 0xFFFF and returns the sums' minimum.
inline uint16_t PadAndMinimum(uint16_t* s, int np, int stride) {
  std::fill(s + np, s + stride, static_cast<uint16_t>(0xFFFF));
  UnsignedLanes low = UnsignedLanes{} + static_cast<uint16_t>(0xFFFF);
  for (int d = 0; d < stride; d += kLaneCount) {
    const UnsignedLanes sum = reinterpret_cast<UnsignedLanes>(LoadLanes<Lanes>(s + d));
    low = low < sum ? low : sum;
  }
  return LowestUnsignedLane(low);
}

// A pixel's winner from its sums `s` (`stride` entries, those past the `np` planes at 0xFFFF, out of
// the minimum's way) and their minimum `lowest`: the first plane at the minimum, with a parabola's
// sub-pixel offset, and, given `data` (the pixel's data-cost curve), the certainty: how far the
// winner's matching cost lies below the curve's mean (0: the curve is flat, as on untextured
// surfaces, or the winner matches no better than a random plane, as where it is occluded in the
// best neighbours; times the peak ratio, cost_curve_confidence.h) and its margin factor alone.
// Inlined: a call per pixel cost the two-view pairs 5-8% of their time.
__attribute__((always_inline)) inline void WinnerOf(const uint16_t* s, uint16_t lowest, int np, const uint16_t* data,
                                                    const CertaintyOptions& certainty, float* plane, float* confidence,
                                                    float* margin) {
  int best = 0;
  for (int d = 0;; d += kLaneCount) {
    const int lane = FirstLaneEqual(reinterpret_cast<UnsignedLanes>(LoadLanes<Lanes>(s + d)), lowest);
    if (lane >= 0) {
      best = d + lane;
      break;
    }
  }
  float sub = static_cast<float>(best);
  if (best > 0 && best < np - 1) {
    const float l = s[best - 1], c = s[best], r = s[best + 1];
    const float denom = l - 2 * c + r;
    if (denom > 0) sub += std::clamp(0.5f * (l - r) / denom, -0.5f, 0.5f);
  }
  *plane = sub;
  if (data == nullptr) return;
  *confidence = CurveConfidence(data, s, np, best, certainty, margin);
}

// Where a backward pass that completes the sums puts each matched pixel's winner (AggregateAndPick)
// instead of storing its sum: row-major maps of the volume's size.
struct PickTarget {
  float* plane = nullptr;       // sub-pixel plane index (left untouched at unmatched pixels)
  float* confidence = nullptr;  // certainty in [0, 1]
  float* margin = nullptr;      // its margin factor alone, in [0, 1]
  CertaintyOptions certainty;

  // Pixel `pixel`'s winner from its completed sums `s` (`stride` entries; the padding ones are
  // overwritten) and its data-cost curve `data`.
  void Pick(uint16_t* s, int np, int stride, const uint16_t* data, size_t pixel) const {
    WinnerOf(s, PadAndMinimum(s, np, stride), np, data, certainty, plane + pixel, confidence + pixel, margin + pixel);
  }
};

// Where a pass keeps each matched pixel's sums in `out` (unmatched pixels' sums are never read):
//  * pixel-indexed (Aggregate, whose winners are searched row by row afterwards): pixel * stride;
//  * `matched_only` (AggregateAndPick, whose passes visit the pixels in scan order and back): the
//    matched pixels one after the other in scan order, so that the sums take the matched pixels'
//    share of the memory instead of the whole view's: on templeSparseRing the largest view's sums
//    take 44 MB instead of 72, and the rest of the pooled buffer's pages are never touched.
// A pass counts the matched pixels as it goes: the first one (s = +1) from slot 0 up, the backward
// one (s = -1) from the last slot down, so both reach a pixel at the same slot.
struct SumSlots {
  bool matched_only = false;
  size_t count = 0;      // slots in `out`
  ptrdiff_t next = 0;    // the next matched pixel's slot (matched_only)

  SumSlots(const CostVolume& v, bool matched_only_, int s) : matched_only(matched_only_) {
    const size_t pixels = static_cast<size_t>(v.width) * v.height;
    count = matched_only && !v.unmatched.empty()
                ? pixels - static_cast<size_t>(std::count(v.unmatched.begin(), v.unmatched.end(), uint8_t{1}))
                : pixels;
    next = s > 0 ? 0 : static_cast<ptrdiff_t>(count) - 1;
  }
  // The slot of matched pixel `pixel`, the next one in the pass's order `s`.
  size_t Take(size_t pixel, int s) {
    const size_t slot = matched_only ? static_cast<size_t>(next) : pixel;
    next += s;
    return slot;
  }
  // The slot `ahead` matched pixels on in the pass's order (for prefetching), or -1 past the end.
  ptrdiff_t Ahead(size_t pixel, int s, int ahead) const {
    const ptrdiff_t slot = (matched_only ? next : static_cast<ptrdiff_t>(pixel)) + static_cast<ptrdiff_t>(s) * ahead;
    return slot >= 0 && slot < static_cast<ptrdiff_t>(count) ? slot : -1;
  }
};

// One pass over the image in scan order `s` (+1: top-left to bottom-right; -1: reverse) along the
// paths arriving from the previous pixel and, when `diagonals`, the previous row's three pixels
// (else only the one above); `out` receives their sum or, `accumulate`, has it added, or, with
// `pick`, a matched pixel's completed sum (`out`'s plus this pass's) gives its winner and is not
// stored. `matched_only`: `out` holds the matched pixels' sums only (SumSlots).
template <class V>
void SgmPassPerPath(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, int s, bool accumulate,
                    bool matched_only, LargeBuffer<uint16_t>* out, const PickTarget* pick) {
  const int w = v.width, h = v.height, n = v.stride, ps = n + 2;
  const bool diagonals = o.paths == 8;
  SumSlots slots(v, matched_only, s);
  // A matched pixel's entries are assigned by the row path first.
  if (!accumulate) out->resize(slots.count * n);
  const int ndir = diagonals ? 3 : 1;  // row paths: from (x - s, y - s), (x, y - s), (x + s, y - s)
  std::vector<int16_t> prev_row(static_cast<size_t>(ndir) * w * ps, kSentinel), cur_row(prev_row.size(), kSentinel);
  std::vector<int16_t> prev_min(static_cast<size_t>(ndir) * w, 0), cur_min(prev_min.size(), 0);
  std::vector<int16_t> left(ps, kSentinel), left_cur(ps, kSentinel);
  std::vector<uint16_t> discarded(n);  // the sums of unmatched pixels, which no one reads
  std::vector<uint16_t> pixel_sums(pick != nullptr ? n : 0);  // a picked pixel's sums
  const int16_t p1 = static_cast<int16_t>(o.p1);
  int16_t p2_table[256];
  FillP2Table(o, p2_table);
  auto p2_for = [&](int g0, int g1) -> int16_t { return p2_table[std::abs(g0 - g1)]; };
  for (int yi = 0; yi < h; ++yi) {
    const int y = s > 0 ? yi : h - 1 - yi;
    const uint8_t* g = gray.ptr<uint8_t>(y);
    const uint8_t* gp = yi > 0 ? gray.ptr<uint8_t>(y - s) : nullptr;
    int16_t left_min = 0;
    for (int xi = 0; xi < w; ++xi) {
      const int x = s > 0 ? xi : w - 1 - xi;
      const uint16_t* c = v.At(x, y);
      const size_t pixel = static_cast<size_t>(y) * w + x;
      const bool matched = v.Matched(pixel);
      uint16_t* sum = matched ? out->data() + slots.Take(pixel, s) * n : discarded.data();
      if (matched && pick != nullptr) {  // the forward pass's sums, completed here and not stored
        std::memcpy(pixel_sums.data(), sum, sizeof(uint16_t) * n);
        sum = pixel_sums.data();
      }
      // From the previous pixel on the row.
      if (xi == 0) {
        left_min = accumulate ? PathStart<false>(c, n, left_cur.data() + 1, sum) : PathStart<true>(c, n, left_cur.data() + 1, sum);
      } else {
        const int16_t p2 = p2_for(g[x], g[x - s]);
        left_min = accumulate ? PathStep<false, V>(c, left.data() + 1, left_min, p1, p2, n, left_cur.data() + 1, sum)
                              : PathStep<true, V>(c, left.data() + 1, left_min, p1, p2, n, left_cur.data() + 1, sum);
      }
      std::swap(left, left_cur);
      // From the previous row.
      for (int k = 0; k < ndir; ++k) {
        const int dx = diagonals ? (k - 1) * s : 0;  // source pixel x offset
        const int xs = x + dx;
        int16_t* cur = cur_row.data() + (static_cast<size_t>(k) * w + x) * ps + 1;
        int16_t& cm = cur_min[static_cast<size_t>(k) * w + x];
        if (yi == 0 || xs < 0 || xs >= w) {
          cm = PathStart<false>(c, n, cur, sum);
        } else {
          const int16_t* pv = prev_row.data() + (static_cast<size_t>(k) * w + xs) * ps + 1;
          cm = PathStep<false, V>(c, pv, prev_min[static_cast<size_t>(k) * w + xs], p1, p2_for(g[x], gp[xs]), n, cur, sum);
        }
      }
      if (matched && pick != nullptr) {
        pick->Pick(sum, v.planes, n, c, pixel);
      }
    }
    std::swap(prev_row, cur_row);
    std::swap(prev_min, cur_min);
  }
}

// Rows of a pass handed from one thread to another (SgmPassPaths with two threads): the thread
// stepping some of a pixel's paths publishes how many rows it has finished; the one stepping the
// others, which adds to the same sums after it, waits for the row before it starts it.
struct RowHandOff {
  std::atomic<int> rows_done{0};
  void Publish(int rows) { rows_done.store(rows, std::memory_order_release); }
  void AwaitRow(int row) const {
    while (rows_done.load(std::memory_order_acquire) <= row) {
#if defined(__x86_64__)
      _mm_pause();
#endif
    }
  }
};

// One pass over the image in scan order `s` (+1: top-left to bottom-right; -1: reverse) along
// some of its paths: the one from the previous pixel on the row (kRowPath) and those from the
// previous row's pixels whose x offsets (times s) kFromRow holds as bits: bit 0 (x - s), bit 1
// (x), bit 2 (x + s). `out` receives the sum of those paths or, `accumulate`, has it added (with
// `pick` and `matched_only` as in SgmPassPerPath: the completed sum gives the winner and is not
// stored). `publish` (optional) receives each finished row; `await` (optional): each row starts
// once that hand-off has it (the other paths' thread has assigned or added its sums there).
// The cost and sum entries of the pixel kPrefetchPixels ahead are fetched early: the backward
// pass walks the volume from its end, and waiting on those loads had been the largest stall.
// Paths cross the pixels the volume leaves out (CostVolume::slots) without a step each: see
// FlatRuns.
constexpr int kPrefetchPixels = 6;

// Semi-global paths across the pixels a volume leaves out, stepped at once at the end of each run
// of them. A left-out pixel's curve is flat (one cost c at every plane: kOutsideCost, as
// BuildCostVolume leaves it; SgmPassPaths checks), so a path's step
// there is L(p,d) = c + min(L'(d), L'(d-1) + P1, L'(d+1) + P1, P2) with L' = L(p-r) - min L(p-r):
// an erosion of L' by P1 a plane, capped at P2. Erosion commutes with taking the minimum with a
// constant, so after m such steps from the state S the path holds
//   c + min(E^m(S - min S), the least P2 of the m steps),
// where E^m(f)(d) = min over d' within m planes of f(d') + P1 |d - d'|; terms ceil(cap / P1) or
// more planes away are at least the cap, so E^m stops changing after ceil(cap / P1) - 1 steps (P1
// 0: the curve's length). A pass therefore keeps, per path and run, a copy of S, the run's length
// and its least P2, and the first stored pixel after the run takes min(m, that many) steps (at
// least one) of the same formula on the flat curve with that cap: the same integers as a step at
// every pixel. On templeSparseRing 40-50% of the part a view sweeps is left out, the background
// around the object. (SgmPassPerPath, the portable and AVX2 builds' loop for many planes, still
// steps every pixel: the same sums.)
template <class V>
class FlatRuns {
 public:
  // `paths` paths, slots for `lines` runs each (one per pixel of a row); a state has `v.stride` entries.
  FlatRuns(const CostVolume& v, int paths, int lines, int16_t p1)
      : n_(v.stride), lines_(lines), p1_(p1), flat_(v.flat.data()),
        frozen_(static_cast<size_t>(paths) * lines * n_), frozen_min_(static_cast<size_t>(paths) * lines),
        thawed_(lines > 0 ? static_cast<size_t>(paths) * 2 * n_ : 0), discarded_(lines > 0 ? n_ : 0) {}
  // A run of path k starts on line `line` from the state `state` (n entries; the start row's
  // zeros at a path's start) whose minimum is `state_min`.
  void Start(int k, int line, const int16_t* state, int16_t state_min) {
    std::memcpy(frozen_.data() + (static_cast<size_t>(k) * lines_ + line) * n_, state, sizeof(int16_t) * n_);
    frozen_min_[static_cast<size_t>(k) * lines_ + line] = state_min;
  }
  // The state of path k at the last pixel of its run on `line` (`length` left-out pixels, least
  // P2 `cap`), and its minimum; valid until the next call for path k.
  const int16_t* Thaw(int k, int line, int32_t length, int16_t cap, int16_t* state_min) {
    const int reach = p1_ > 0 ? (cap + p1_ - 1) / p1_ - 1 : n_;  // the steps after which E^m stops changing
    const int steps = std::max(1, static_cast<int>(std::min<int32_t>(length, reach)));
    const int16_t* prev = frozen_.data() + (static_cast<size_t>(k) * lines_ + line) * n_;
    int16_t prev_min = frozen_min_[static_cast<size_t>(k) * lines_ + line];
    int16_t* buffers[2] = {thawed_.data() + static_cast<size_t>(2 * k) * n_, thawed_.data() + static_cast<size_t>(2 * k + 1) * n_};
    for (int t = 0; t < steps; ++t) {
      int16_t* cur = buffers[t & 1];
      int16_t cur_min;
      PathSteps<1, false, V>(flat_, n_, &prev, &prev_min, &cap, p1_, &cur, &cur_min, discarded_.data());
      prev = cur;
      prev_min = cur_min;
    }
    *state_min = prev_min;
    return prev;
  }

 private:
  int n_, lines_;
  int16_t p1_;
  const uint16_t* flat_;
  LargeBuffer<int16_t> frozen_, frozen_min_;  // uninitialised: Start fills a line before Thaw reads it
  std::vector<int16_t> thawed_;
  std::vector<uint16_t> discarded_;
};

// kRuns: the volume leaves pixels out (FlatRuns); a template argument, so that the passes over
// volumes that store every pixel (the two-view pairs) carry none of its bookkeeping.
template <bool kRowPath, int kFromRow, class V, bool kRuns>
void SgmPassPathsOf(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, int s, bool accumulate,
                    bool matched_only, LargeBuffer<uint16_t>* out, const PickTarget* pick, RowHandOff* publish,
                    const RowHandOff* await) {
  constexpr int kRowPaths = __builtin_popcount(kFromRow);
  constexpr int K = (kRowPath ? 1 : 0) + kRowPaths;  // the row path first, then the paths from the previous row
  constexpr int kRow = kRowPath ? 1 : 0;
  int dx_of[3] = {0, 0, 0};  // the k-th path from the previous row: x offset in units of s
  for (int bit = 0, k = 0; bit < 3; ++bit) {
    if (kFromRow & (1 << bit)) dx_of[k++] = bit - 1;
  }
  const int w = v.width, h = v.height, n = v.stride, ps = n + 2;
  SumSlots slots(v, matched_only, s);
  if (!accumulate) out->resize(slots.count * n);  // every matched pixel's entries are assigned
  // Two of each (previous and current), swapped as pointers (swapping the vectors themselves made
  // GCC 12 warn, falsely, of freeing a pointer into the middle of a block).
  const size_t row_size = static_cast<size_t>(kRowPaths) * w * ps, min_size = static_cast<size_t>(kRowPaths) * w;
  std::vector<int16_t> rows(2 * row_size, kSentinel), mins(2 * min_size, 0), lefts(2 * static_cast<size_t>(ps), kSentinel);
  int16_t *prev_row = rows.data(), *cur_row = prev_row + row_size, *prev_min = mins.data(), *cur_min = prev_min + min_size;
  int16_t *left = lefts.data(), *left_cur = left + ps;
  const std::vector<int16_t> start(ps, 0);  // the previous pixel of a path that starts: L = C
  std::vector<uint16_t> discarded(n);         // the sums of unmatched pixels, which no one reads
  std::vector<uint16_t> pixel_sums(pick != nullptr ? n : 0);  // a picked pixel's sums
  const int16_t p1 = static_cast<int16_t>(o.p1);
  int16_t p2_table[256];
  FillP2Table(o, p2_table);
  const int16_t* prev[K];
  int16_t* cur[K];
  int16_t min_prev[K], min_out[K], p2[K];
  int16_t left_min = 0;
  // Runs of left-out pixels (FlatRuns): per path state, how many left-out pixels it is past the
  // last stepped one (0: none, the state is stored) and their least P2. A run's line: the row
  // for the row path; for a path from the previous row, x + dx s yi, the same at every pixel of
  // the path, modulo w (the pixels of one row are on distinct lines).
  FlatRuns<V> flat_runs(v, K, kRuns ? w : 0, p1);
  std::vector<int32_t> run_rows(kRuns ? 2 * min_size : 0, 0);
  std::vector<int16_t> cap_rows(kRuns ? 2 * min_size : 0, 0);
  int32_t *prev_run = run_rows.data(), *cur_run = prev_run + (kRuns ? min_size : 0);
  int16_t *prev_cap = cap_rows.data(), *cur_cap = prev_cap + (kRuns ? min_size : 0);
  int32_t left_run = 0;
  int16_t left_cap = 0;
  int32_t run[K];
  int16_t cap[K];
  int run_line[K];
  for (int yi = 0; yi < h; ++yi) {
    if (await != nullptr) await->AwaitRow(yi);
    const int y = s > 0 ? yi : h - 1 - yi;
    const uint8_t* g = gray.ptr<uint8_t>(y);
    const uint8_t* gp = yi > 0 ? gray.ptr<uint8_t>(y - s) : nullptr;
    for (int xi = 0; xi < w; ++xi) {
      const int x = s > 0 ? xi : w - 1 - xi;
      if constexpr (kRowPath) {  // from the previous pixel on the row
        prev[0] = xi == 0 ? start.data() + 1 : left + 1;
        min_prev[0] = xi == 0 ? 0 : left_min;
        p2[0] = xi == 0 ? 0 : p2_table[std::abs(g[x] - g[x - s])];
        cur[0] = left_cur + 1;
        if constexpr (kRuns) {
          run[0] = xi == 0 ? 0 : left_run;
          cap[0] = left_cap;
          run_line[0] = 0;
        }
      }
      // From the previous row: (x - s, y - s), (x, y - s), (x + s, y - s), those in kFromRow.
      for (int k = 0; k < kRowPaths; ++k) {
        const int xs = x + dx_of[k] * s;
        cur[kRow + k] = cur_row + (static_cast<size_t>(k) * w + x) * ps + 1;
        if (yi == 0 || xs < 0 || xs >= w) {
          prev[kRow + k] = start.data() + 1;
          min_prev[kRow + k] = 0;
          p2[kRow + k] = 0;
          if constexpr (kRuns) run[kRow + k] = 0;
        } else {
          prev[kRow + k] = prev_row + (static_cast<size_t>(k) * w + xs) * ps + 1;
          min_prev[kRow + k] = prev_min[static_cast<size_t>(k) * w + xs];
          p2[kRow + k] = p2_table[std::abs(g[x] - gp[xs])];
          if constexpr (kRuns) {
            run[kRow + k] = prev_run[static_cast<size_t>(k) * w + xs];
            cap[kRow + k] = prev_cap[static_cast<size_t>(k) * w + xs];
          }
        }
        if constexpr (kRuns) run_line[kRow + k] = ((x + dx_of[k] * s * yi) % w + w) % w;
      }
      const size_t pixel = static_cast<size_t>(y) * w + x;
      if constexpr (kRuns) {
        if (!v.Stored(pixel)) {  // left out (and so not matched): each path's run grows
          for (int k = 0; k < K; ++k) {
            if (run[k] == 0) flat_runs.Start(k, run_line[k], prev[k], min_prev[k]);
            const int32_t length = run[k] == 0 ? 1 : std::min(run[k] + 1, int32_t{1} << 30);
            const int16_t least = run[k] == 0 ? p2[k] : std::min(cap[k], p2[k]);
            if (kRowPath && k == 0) {
              left_run = length, left_cap = least;
            } else {
              cur_run[static_cast<size_t>(k - kRow) * w + x] = length, cur_cap[static_cast<size_t>(k - kRow) * w + x] = least;
            }
          }
          continue;
        }
        for (int k = 0; k < K; ++k) {  // a run that ends here: the state at its last pixel
          if (run[k] > 0) prev[k] = flat_runs.Thaw(k, run_line[k], run[k], cap[k], &min_prev[k]);
          if (k >= kRow) cur_run[static_cast<size_t>(k - kRow) * w + x] = 0;
        }
        left_run = 0;
      }
      const bool matched = v.Matched(pixel);
      const ptrdiff_t sums_ahead = slots.Ahead(pixel, s, kPrefetchPixels);
      uint16_t* sum = matched ? out->data() + slots.Take(pixel, s) * n : discarded.data();
      if (matched && pick != nullptr) {  // the sums so far, completed here and not stored
        std::memcpy(pixel_sums.data(), sum, sizeof(uint16_t) * n);
        sum = pixel_sums.data();
      }
      if (xi + kPrefetchPixels < w) {
        const uint16_t* ahead = v.At(x + s * kPrefetchPixels, y);
        for (int line = 0; line < n; line += 32) __builtin_prefetch(ahead + line, 0);
      }
      if (sums_ahead >= 0) {
        for (int line = 0; line < n; line += 32) __builtin_prefetch(out->data() + static_cast<size_t>(sums_ahead) * n + line, 1);
      }
      if (accumulate) {  // the same every pixel: a branch the predictor always gets right
        PathSteps<K, true, V>(v.At(x, y), n, prev, min_prev, p2, p1, cur, min_out, sum);
      } else {
        PathSteps<K, false, V>(v.At(x, y), n, prev, min_prev, p2, p1, cur, min_out, sum);
      }
      if (matched && pick != nullptr) {
        pick->Pick(sum, v.planes, n, v.At(x, y), pixel);
      }
      if constexpr (kRowPath) {
        left_min = min_out[0];
        std::swap(left, left_cur);
      }
      for (int k = 0; k < kRowPaths; ++k) cur_min[static_cast<size_t>(k) * w + x] = min_out[kRow + k];
    }
    std::swap(prev_row, cur_row);
    std::swap(prev_min, cur_min);
    std::swap(prev_run, cur_run);
    std::swap(prev_cap, cur_cap);
    if (publish != nullptr) publish->Publish(yi + 1);
  }
}

template <bool kRowPath, int kFromRow, class V>
void SgmPassPaths(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, int s, bool accumulate,
                  bool matched_only, LargeBuffer<uint16_t>* out, const PickTarget* pick, RowHandOff* publish = nullptr,
                  const RowHandOff* await = nullptr) {
  // (A volume built elsewhere with a curve for left-out pixels that is not one cost everywhere is
  // stepped pixel by pixel: the same sums, through At.)
  auto one_cost = [&] { return !v.flat.empty() && std::all_of(v.flat.begin(), v.flat.end(), [&](uint16_t c) { return c == v.flat[0]; }); };
  if (v.slots.empty() || !one_cost()) {
    SgmPassPathsOf<kRowPath, kFromRow, V, false>(v, gray, o, s, accumulate, matched_only, out, pick, publish, await);
  } else {
    SgmPassPathsOf<kRowPath, kFromRow, V, true>(v, gray, o, s, accumulate, matched_only, out, pick, publish, await);
  }
}

// A pass's paths split over two threads (EngineOptions::sgm_threads): the row path and those from
// the pixels above and above-behind (x - s) on a thread of its own, which assigns (or adds to) the
// sums row by row, and the other diagonal on the calling thread, a row behind, which adds to them
// (or, with `pick`, completes them into the winners: the picking weighs about two paths; with 4
// paths: the row path, then the one from above). On the full-size Sceaux castle, one view in
// flight, the diagonals and the picking on one thread took twice the other's time.
// The sums wrap as uint16 whatever the order: the same sums and winners as SgmPassPaths with all
// paths at once. The helper is a thread of its own, not a TBB task: the calling thread waits on
// it, which a task that no worker had picked up yet would never end.
template <class V>
void SgmPassTwoThreads(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, int s, bool accumulate,
                       bool matched_only, LargeBuffer<uint16_t>* out, const PickTarget* pick) {
  if (!accumulate) out->resize(SumSlots(v, matched_only, s).count * v.stride);  // before either thread takes its address
  RowHandOff first;
  const bool eight = o.paths == 8;
  std::thread helper([&] {
    if (eight) {
      SgmPassPaths<true, 0b011, V>(v, gray, o, s, accumulate, matched_only, out, nullptr, &first);
    } else {
      SgmPassPaths<true, 0, V>(v, gray, o, s, accumulate, matched_only, out, nullptr, &first);
    }
  });
  if (eight) {
    SgmPassPaths<false, 0b100, V>(v, gray, o, s, true, matched_only, out, pick, nullptr, &first);
  } else {
    SgmPassPaths<false, 0b010, V>(v, gray, o, s, true, matched_only, out, pick, nullptr, &first);
  }
  helper.join();
}

// One semi-global pass, into `out` or (`accumulate`) added to it, or (`pick`) completed into each
// matched pixel's winner. With few planes (two-view pairs:
// 16-64) the per-pixel overhead dominates and stepping the paths together wins (venus 2 threads:
// 13.0 ms against 14.3). With many (a multi-view sweep's 128) the AVX-512 build steps them
// together as well: its 32 registers hold the four paths' state (templeSparseRing plane_sweep,
// alternated: 1.52-1.54 s against 1.83-1.92), while the AVX2 and portable builds, with 16, do no
// better that way (3.34-3.69 s against 3.38-3.49, and 5.60-6.35 against 5.35-5.93) and take one
// loop per path. Both give the same sums.
void SgmPass(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, int s, bool accumulate, bool matched_only,
             LargeBuffer<uint16_t>* out, const PickTarget* pick = nullptr) {
  const bool wide = v.stride % kLanesOf<WideLanes> == 0;
  const bool m = matched_only;
  if (o.sgm_threads == 2 && v.height > 1) {
    wide ? SgmPassTwoThreads<WideLanes>(v, gray, o, s, accumulate, m, out, pick)
         : SgmPassTwoThreads<Lanes>(v, gray, o, s, accumulate, m, out, pick);
  } else if (v.stride > 64 && !IBMR_SWEEP_AVX512) {
    wide ? SgmPassPerPath<WideLanes>(v, gray, o, s, accumulate, m, out, pick)
         : SgmPassPerPath<Lanes>(v, gray, o, s, accumulate, m, out, pick);
  } else if (o.paths == 8) {
    wide ? SgmPassPaths<true, 0b111, WideLanes>(v, gray, o, s, accumulate, m, out, pick)
         : SgmPassPaths<true, 0b111, Lanes>(v, gray, o, s, accumulate, m, out, pick);
  } else {
    wide ? SgmPassPaths<true, 0b010, WideLanes>(v, gray, o, s, accumulate, m, out, pick)
         : SgmPassPaths<true, 0b010, Lanes>(v, gray, o, s, accumulate, m, out, pick);
  }
}

// One output row of the box mean from the horizontal sums of its kRows rows (`rows`, those of the
// clipped window): sum / area by a fixed-point reciprocal, (sum * inv) >> 16, inv = 2^16 / area + 1
// (exact enough for costs below 2^11 * area). With at most 7 rows of at most 7 costs of 1023 the
// sums fit in 16 bits, and so does inv (area >= 2), so the product's high half is the 16-bit
// multiply the vector units have; the values are those of a 32-bit running sum.
// The fixed-point reciprocal of a box window's area: sum / area is (sum * inv) >> 16.
inline uint32_t BoxReciprocal(uint32_t area) { return (1u << 16) / area + 1; }
template <int kRows>
void BoxMeanRow(const uint16_t* const* rows, int w, int n, int r, int ny, uint16_t* __restrict out) {
  for (int x = 0; x < w; ++x) {
    const uint32_t area = static_cast<uint32_t>(ny * (std::min(w - 1, x + r) - std::max(0, x - r) + 1));
    const size_t at = static_cast<size_t>(x) * n;
    uint16_t* __restrict o = out + at;
    if (area == 1) {  // a one-pixel image: the mean is the cost (and 2^16 + 1 has no 16 bits)
      std::copy(rows[0] + at, rows[0] + at + n, o);
      continue;
    }
    const uint16_t inv = static_cast<uint16_t>(BoxReciprocal(area));
    for (int d = 0; d < n; ++d) {
      uint16_t sum = rows[0][at + d];
      for (int k = 1; k < kRows; ++k) sum = static_cast<uint16_t>(sum + rows[k][at + d]);
      o[d] = static_cast<uint16_t>((static_cast<uint32_t>(sum) * inv) >> 16);
    }
  }
}

// Box mean of the volume over (2r+1)^2 pixels per plane, borders clipped; in place, in bands of
// rows (one task each) swept top to bottom. A row's horizontal sums go into a ring of the last
// 2r + 2 rows and a running vertical sum; a row is overwritten once its own sums are in the ring,
// and only the rows below it are still read. The r rows above and below a band belong to its
// neighbours, which overwrite them: their horizontal sums are taken before any band starts. So
// the filter needs no second volume (a volume's first touch costs more than the filter itself).
// Returns the threads' CPU time in it, summed (VolumeWork::box_filter_seconds).
double BoxFilterVolume(CostVolume* v, int r) {
  if (r <= 0) return 0;
  const int w = v->width, h = v->height, n = v->stride;
  const size_t row = static_cast<size_t>(w) * n;
  // Horizontal sums of row y (at most 31 costs of 1023: 16 bits suffice). For r <= 2 each pixel's
  // sum is added up directly from its (clipped) window. For wider windows each pixel's sum comes
  // from its left neighbour's: out(x) = out(x - 1) + in(x + r) - in(x - r - 1). That chain runs
  // through memory: with few planes (a two-view pair's 16) the load of out(x - 1) waits on the
  // store just made, which the AVX-512 build could not forward (the box filter took 2.8 times
  // the portable build's samples on tsukuba). The sums are the same integers either way.
  // Row y's horizontal sums from its pixels' costs `at(x)`: a row of the volume in a piece, or, in a
  // volume that leaves pixels out, through its slots (a stored pixel's neighbours on the row need not
  // lie next to it in memory).
  auto horizontal_from = [&](auto at, uint16_t* __restrict out) {
    if (r <= 2) {
      for (int x = 0; x < w; ++x) {
        uint16_t* __restrict o = out + static_cast<size_t>(x) * n;
        if (x >= r && x + r < w) {  // the whole window: one pass over the planes
          const uint16_t* __restrict a = at(x - 1);
          const uint16_t* __restrict c = at(x);
          const uint16_t* __restrict b = at(x + 1);
          if (r == 1) {
            for (int d = 0; d < n; ++d) o[d] = static_cast<uint16_t>(a[d] + c[d] + b[d]);
          } else {
            const uint16_t* __restrict aa = at(x - 2);
            const uint16_t* __restrict bb = at(x + 2);
            for (int d = 0; d < n; ++d) o[d] = static_cast<uint16_t>(aa[d] + a[d] + c[d] + b[d] + bb[d]);
          }
          continue;
        }
        const int x0 = std::max(0, x - r), x1 = std::min(w - 1, x + r);  // clipped at the borders
        const uint16_t* __restrict first = at(x0);
        std::copy(first, first + n, o);
        for (int xx = x0 + 1; xx <= x1; ++xx) {
          const uint16_t* __restrict add = at(xx);
          for (int d = 0; d < n; ++d) o[d] = static_cast<uint16_t>(o[d] + add[d]);
        }
      }
      return;
    }
    std::fill(out, out + n, static_cast<uint16_t>(0));
    for (int x = 0; x <= std::min(r, w - 1); ++x) {
      const uint16_t* add = at(x);
      for (int d = 0; d < n; ++d) out[d] = static_cast<uint16_t>(out[d] + add[d]);
    }
    for (int x = 1; x < w; ++x) {
      uint16_t* __restrict o = out + static_cast<size_t>(x) * n;
      const uint16_t* __restrict left = o - n;
      const uint16_t* __restrict add = at(std::min(x + r, w - 1));
      const uint16_t* __restrict sub = at(std::max(x - r - 1, 0));
      const uint16_t keep_add = x + r < w ? 0xFFFF : 0, keep_sub = x - r - 1 >= 0 ? 0xFFFF : 0;
      for (int d = 0; d < n; ++d) o[d] = static_cast<uint16_t>(left[d] + (add[d] & keep_add) - (sub[d] & keep_sub));
    }
  };
  const CostVolume& in = *v;
  auto horizontal = [&](int y, uint16_t* __restrict out) {
    if (in.slots.empty()) {
      const uint16_t* row_costs = in.At(0, y);
      horizontal_from([row_costs, n](int x) { return row_costs + static_cast<size_t>(x) * n; }, out);
    } else {
      horizontal_from([&in, y](int x) { return in.At(x, y); }, out);
    }
  };
  const int band_rows = std::max(16, std::min(64, (h + 7) / 8));
  const int bands = (h + band_rows - 1) / band_rows;
  // Per band, the horizontal sums of the r rows above it and the r rows below it.
  std::vector<std::vector<uint16_t>> halo(bands);
  auto halo_row = [&](int band, int y) {
    const int first = band * band_rows;
    const int slot = y < first ? y - (first - r) : r + (y - (first + band_rows));
    return halo[band].data() + static_cast<size_t>(slot) * row;
  };
  TaskSeconds seconds;  // VolumeWork::box_filter_seconds
  tbb::parallel_for(0, bands, [&](int band) {
    const TaskSeconds::Scope timed(&seconds);
    const int first = band * band_rows, end = std::min(h, first + band_rows);
    halo[band].resize(2 * static_cast<size_t>(r) * row);
    for (int y = std::max(0, first - r); y < first; ++y) horizontal(y, halo_row(band, y));
    for (int y = end; y < std::min(h, end + r); ++y) horizontal(y, halo_row(band, y));
  });
  tbb::parallel_for(0, bands, [&](int band) {
    const TaskSeconds::Scope timed(&seconds);
    const int first = band * band_rows, end = std::min(h, first + band_rows);
    const int ring_rows = 2 * r + 2;
    std::vector<uint16_t> ring(static_cast<size_t>(ring_rows) * row);
    // Row y's output: in place, or, where the volume leaves pixels out, a row to copy the stored
    // pixels' costs from (commit).
    std::vector<uint16_t> out_row(v->slots.empty() ? 0 : row);
    auto output = [&](int y) { return v->slots.empty() ? v->At(0, y) : out_row.data(); };
    auto commit = [&](int y) {
      if (v->slots.empty()) return;
      for (int x = 0; x < w; ++x) {
        if (!v->Stored(static_cast<size_t>(y) * w + x)) continue;
        const uint16_t* filtered = out_row.data() + static_cast<size_t>(x) * n;
        std::copy(filtered, filtered + n, v->At(x, y));
      }
    };
    std::vector<uint32_t> acc(r <= 3 ? 0 : row, 0u);  // the running vertical sum of wider windows
    // Row y's horizontal sums, made (from the band's own rows, still unfiltered) or taken (halo).
    auto take = [&](int y) {
      uint16_t* slot = ring.data() + static_cast<size_t>(y % ring_rows) * row;
      if (y < first || y >= end) {
        const uint16_t* saved = halo_row(band, y);
        std::copy(saved, saved + row, slot);
      } else {
        horizontal(y, slot);
      }
      return slot;
    };
    if (r <= 3) {  // 16-bit sums of the window's rows, straight from the ring (BoxMeanRow)
      for (int yy = std::max(0, first - r); yy <= std::min(h - 1, first + r - 1); ++yy) take(yy);
      for (int y = first; y < end; ++y) {
        if (y + r < h) take(y + r);
        const int y0 = std::max(0, y - r), y1 = std::min(h - 1, y + r), ny = y1 - y0 + 1;
        const uint16_t* rows[7];
        for (int yy = y0; yy <= y1; ++yy) rows[yy - y0] = ring.data() + static_cast<size_t>(yy % ring_rows) * row;
        uint16_t* out = output(y);
        switch (ny) {
          case 1: BoxMeanRow<1>(rows, w, n, r, ny, out); break;
          case 2: BoxMeanRow<2>(rows, w, n, r, ny, out); break;
          case 3: BoxMeanRow<3>(rows, w, n, r, ny, out); break;
          case 4: BoxMeanRow<4>(rows, w, n, r, ny, out); break;
          case 5: BoxMeanRow<5>(rows, w, n, r, ny, out); break;
          case 6: BoxMeanRow<6>(rows, w, n, r, ny, out); break;
          default: BoxMeanRow<7>(rows, w, n, r, ny, out); break;
        }
        commit(y);
      }
      return;
    }
    for (int yy = std::max(0, first - r); yy <= std::min(h - 1, first + r - 1); ++yy) {
      const uint16_t* in = take(yy);
      for (size_t i = 0; i < row; ++i) acc[i] += in[i];
    }
    for (int y = first; y < end; ++y) {
      if (y + r < h) {
        const uint16_t* in = take(y + r);
        for (size_t i = 0; i < row; ++i) acc[i] += in[i];
      }
      if (y - r - 1 >= std::max(0, first - r)) {  // rows before the band's window were never added
        const uint16_t* in = ring.data() + static_cast<size_t>((y - r - 1) % ring_rows) * row;
        for (size_t i = 0; i < row; ++i) acc[i] -= in[i];
      }
      const int ny = std::min(h - 1, y + r) - std::max(0, y - r) + 1;
      uint16_t* out = output(y);
      for (int x = 0; x < w; ++x) {
        const uint32_t area = static_cast<uint32_t>(ny * (std::min(w - 1, x + r) - std::max(0, x - r) + 1));
        const uint32_t* a = acc.data() + static_cast<size_t>(x) * n;
        uint16_t* o = out + static_cast<size_t>(x) * n;
        // Multiply by a fixed-point reciprocal (exact enough for costs below 2^11 * area).
        const uint32_t inv = BoxReciprocal(area);
        for (int d = 0; d < n; ++d) o[d] = static_cast<uint16_t>((a[d] * inv) >> 16);
      }
      commit(y);
    }
  });
  return seconds.Total();
}

// Where one plane's correspondence of a reference pixel falls in a neighbour: the index of the
// top-left of the four codes around it (-1: outside the neighbour, or behind it) and the
// bilinear weights of the right and lower codes in 1/256 (kWeightOne).
constexpr int kWeightShift = 8, kWeightOne = 1 << kWeightShift;

// Which way a neighbour's census cost is interpolated (CensusSampling): bilinearly, or linearly
// along the rows (the nearest row: the lower weight is 0) or along the columns (the nearest
// column: the right weight is 0). With a weight of 0 the bilinear formula gives the linear one's
// integers, so every kernel computes the same costs whichever codes it reads.
enum class TapAxis { kBoth, kRows, kColumns };

// The largest correspondence coordinates (u, v) inside a neighbour of sw x sh codes: the four
// codes from the top-left one exist. Rounding to the nearest row (column) reaches the next one
// half a pixel sooner than truncating.
inline void TapLimits(TapAxis axis, int sw, int sh, float* max_u, float* max_v) {
  *max_u = static_cast<float>(sw - 1) - (axis == TapAxis::kColumns ? 0.5f : 0.f);
  *max_v = static_cast<float>(sh - 1) - (axis == TapAxis::kRows ? 0.5f : 0.f);
}
struct Taps {
  std::vector<int32_t> index, wx, wy;
  void Resize(size_t n) {
    index.assign(n, -1);  // padding planes stay outside
    wx.assign(n, 0);
    wy.assign(n, 0);
  }
};

// The taps of plane p from its correspondence (u, v) (pixel centres at integers) and depth z: the
// top-left code's index (-1 outside the neighbour or behind it) and the weights (`axis`).
// Outside (even NaN) coordinates become 0 before the conversion, which stays defined.
// One coordinate c (every build takes these steps, lane by lane): across the axis (`nearest`),
// the nearest code with weight 0, at most `max`, the one before the last: a coordinate just below
// the limit (sh - 1.5) can round up to the last one (at sh = 2, v + 0.5f gives 1 from
// 0.49999997); else the code below c and the next one's weight.
inline void CoordinateTap(float c, float max, bool nearest, int* code, int32_t* weight) {
  if (nearest) {
    *code = std::min(static_cast<int>(c + 0.5f), static_cast<int>(max));
    *weight = 0;
  } else {
    *code = static_cast<int>(c);
    *weight = static_cast<int32_t>((c - static_cast<float>(*code)) * kWeightOne + 0.5f);
  }
}
inline void StoreTap(float z, float u, float v, float max_u, float max_v, int sw, int p, TapAxis axis, Taps* taps) {
  const bool inside = z > 0 && u >= 0 && v >= 0 && u < max_u && v < max_v;
  int x0, y0;
  CoordinateTap(inside ? u : 0.f, max_u, axis == TapAxis::kColumns, &x0, &taps->wx[p]);
  CoordinateTap(inside ? v : 0.f, max_v, axis == TapAxis::kRows, &y0, &taps->wy[p]);
  taps->index[p] = inside ? y0 * sw + x0 : -1;
}

#if IBMR_SWEEP_AVX512
// StoreTap's steps for 16 lanes (16 planes of a pixel, or one plane of 16 pixels), kept in registers.
// (The top-left code's index, row * sw + column, is left to the callers that need it: the lane
// kernel finds most codes from the rows and columns alone.)
struct LaneTaps {
  __m512i wx, wy;
  __m512i column, row;  // of the top-left code (0 outside)
  __mmask16 inside;
};
// CoordinateTap for 16 lanes.
inline void CoordinateTap(__m512 c, float max, bool nearest, __m512i* code, __m512i* weight) {
  const __m512 half = _mm512_set1_ps(0.5f), one = _mm512_set1_ps(static_cast<float>(kWeightOne));
  if (nearest) {
    *code = _mm512_min_epi32(_mm512_cvttps_epi32(_mm512_add_ps(c, half)), _mm512_set1_epi32(static_cast<int>(max)));
    *weight = _mm512_setzero_si512();
  } else {
    *code = _mm512_cvttps_epi32(c);
    *weight = _mm512_cvttps_epi32(_mm512_add_ps(_mm512_mul_ps(_mm512_sub_ps(c, _mm512_cvtepi32_ps(*code)), one), half));
  }
}
// (The axis is a template argument: along one axis only the weight kept is computed. The lane
// kernel took 5% less time on templeSparseRing, medians of 5 alternated pairs.)
template <TapAxis kAxis>
inline LaneTaps TapsOf(__m512 z, __m512 u, __m512 v, float max_u, float max_v) {
  const __m512 zero = _mm512_setzero_ps();
  LaneTaps t;
  t.inside = _mm512_cmp_ps_mask(z, zero, _CMP_GT_OQ) & _mm512_cmp_ps_mask(u, zero, _CMP_GE_OQ) &
             _mm512_cmp_ps_mask(v, zero, _CMP_GE_OQ) & _mm512_cmp_ps_mask(u, _mm512_set1_ps(max_u), _CMP_LT_OQ) &
             _mm512_cmp_ps_mask(v, _mm512_set1_ps(max_v), _CMP_LT_OQ);
  const __m512 uc = _mm512_maskz_mov_ps(t.inside, u), vc = _mm512_maskz_mov_ps(t.inside, v);
  CoordinateTap(uc, max_u, kAxis == TapAxis::kColumns, &t.column, &t.wx);
  CoordinateTap(vc, max_v, kAxis == TapAxis::kRows, &t.row, &t.wy);
  return t;
}
inline LaneTaps TapsOf(__m512 z, __m512 u, __m512 v, float max_u, float max_v, TapAxis axis) {
  switch (axis) {
    case TapAxis::kRows: return TapsOf<TapAxis::kRows>(z, u, v, max_u, max_v);
    case TapAxis::kColumns: return TapsOf<TapAxis::kColumns>(z, u, v, max_u, max_v);
    default: return TapsOf<TapAxis::kBoth>(z, u, v, max_u, max_v);
  }
}

// Each lane's top-left code index, row * sw + column (any value outside).
inline __m512i LaneIndex(const LaneTaps& t, int sw) {
  return _mm512_add_epi32(_mm512_mullo_epi32(t.row, _mm512_set1_epi32(sw)), t.column);
}

// StoreTap for planes p..p+15, the same operations lane by lane.
inline void StoreTaps16(__m512 z, __m512 u, __m512 v, float max_u, float max_v, int sw, int p, TapAxis axis, Taps* taps) {
  const LaneTaps t = TapsOf(z, u, v, max_u, max_v, axis);
  _mm512_storeu_si512(taps->wx.data() + p, t.wx);
  _mm512_storeu_si512(taps->wy.data() + p, t.wy);
  _mm512_storeu_si512(taps->index.data() + p, _mm512_mask_blend_epi32(t.inside, _mm512_set1_epi32(-1), LaneIndex(t, sw)));
}
#elif IBMR_SWEEP_AVX2
// CoordinateTap for 8 lanes.
inline void CoordinateTap(__m256 c, float max, bool nearest, __m256i* code, __m256i* weight) {
  const __m256 half = _mm256_set1_ps(0.5f), one = _mm256_set1_ps(static_cast<float>(kWeightOne));
  if (nearest) {
    *code = _mm256_min_epi32(_mm256_cvttps_epi32(_mm256_add_ps(c, half)), _mm256_set1_epi32(static_cast<int>(max)));
    *weight = _mm256_setzero_si256();
  } else {
    *code = _mm256_cvttps_epi32(c);
    *weight = _mm256_cvttps_epi32(_mm256_add_ps(_mm256_mul_ps(_mm256_sub_ps(c, _mm256_cvtepi32_ps(*code)), one), half));
  }
}
// StoreTap for planes p..p+7, the same operations lane by lane (the masks are all-ones lanes).
inline void StoreTaps8(__m256 z, __m256 u, __m256 v, float max_u, float max_v, int sw, int p, TapAxis axis, Taps* taps) {
  const __m256 zero = _mm256_setzero_ps();
  const __m256 inside = _mm256_and_ps(
      _mm256_and_ps(_mm256_and_ps(_mm256_cmp_ps(z, zero, _CMP_GT_OQ), _mm256_cmp_ps(u, zero, _CMP_GE_OQ)),
                    _mm256_and_ps(_mm256_cmp_ps(v, zero, _CMP_GE_OQ), _mm256_cmp_ps(u, _mm256_set1_ps(max_u), _CMP_LT_OQ))),
      _mm256_cmp_ps(v, _mm256_set1_ps(max_v), _CMP_LT_OQ));
  const __m256 uc = _mm256_and_ps(inside, u), vc = _mm256_and_ps(inside, v);  // outside (or NaN): 0
  __m256i x0, y0, wx, wy;
  CoordinateTap(uc, max_u, axis == TapAxis::kColumns, &x0, &wx);
  CoordinateTap(vc, max_v, axis == TapAxis::kRows, &y0, &wy);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(taps->wx.data() + p), wx);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(taps->wy.data() + p), wy);
  const __m256i at = _mm256_add_epi32(_mm256_mullo_epi32(y0, _mm256_set1_epi32(sw)), x0);
  _mm256_storeu_si256(reinterpret_cast<__m256i*>(taps->index.data() + p),
                      _mm256_blendv_epi8(_mm256_set1_epi32(-1), at, _mm256_castps_si256(inside)));
}
#endif

// Taps of pixel centre (xc, yc) for planes p0..p1-1 (multiples of 16); `hom` holds the nine
// homography entries as rows of `n` planes (padding planes all zero: outside). The float steps are
// the same elementwise IEEE operations, in the same order, in both builds.
void ComputeTaps(const float* hom, int n, int p0, int p1, float xc, float yc, int sw, int sh, TapAxis axis, Taps* taps) {
  float max_u, max_v;
  TapLimits(axis, sw, sh, &max_u, &max_v);
#if IBMR_SWEEP_AVX512
  const __m512 x = _mm512_set1_ps(xc), y = _mm512_set1_ps(yc), half = _mm512_set1_ps(0.5f);
  auto row = [&](int e, int p) { return _mm512_loadu_ps(hom + static_cast<size_t>(e) * n + p); };
  for (int p = p0; p < p1; p += 16) {
    const __m512 z = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(row(6, p), x), _mm512_mul_ps(row(7, p), y)), row(8, p));
    const __m512 un = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(row(0, p), x), _mm512_mul_ps(row(1, p), y)), row(2, p));
    const __m512 vn = _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(row(3, p), x), _mm512_mul_ps(row(4, p), y)), row(5, p));
    StoreTaps16(z, _mm512_sub_ps(_mm512_div_ps(un, z), half), _mm512_sub_ps(_mm512_div_ps(vn, z), half), max_u, max_v, sw,
                p, axis, taps);
  }
#elif IBMR_SWEEP_AVX2
  const __m256 x = _mm256_set1_ps(xc), y = _mm256_set1_ps(yc), half = _mm256_set1_ps(0.5f);
  auto row = [&](int e, int p) { return _mm256_loadu_ps(hom + static_cast<size_t>(e) * n + p); };
  for (int p = p0; p < p1; p += 8) {
    const __m256 z = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(row(6, p), x), _mm256_mul_ps(row(7, p), y)), row(8, p));
    const __m256 un = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(row(0, p), x), _mm256_mul_ps(row(1, p), y)), row(2, p));
    const __m256 vn = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(row(3, p), x), _mm256_mul_ps(row(4, p), y)), row(5, p));
    StoreTaps8(z, _mm256_sub_ps(_mm256_div_ps(un, z), half), _mm256_sub_ps(_mm256_div_ps(vn, z), half), max_u, max_v, sw, p,
               axis, taps);
  }
#else
  for (int p = p0; p < p1; ++p) {
    const float z = hom[6 * n + p] * xc + hom[7 * n + p] * yc + hom[8 * n + p];
    const float u = (hom[0 * n + p] * xc + hom[1 * n + p] * yc + hom[2 * n + p]) / z - 0.5f;
    const float v = (hom[3 * n + p] * xc + hom[4 * n + p] * yc + hom[5 * n + p]) / z - 0.5f;
    StoreTap(z, u, v, max_u, max_v, sw, p, axis, taps);
  }
#endif
}

// Census costs of a rectified pair's planes p0..p1-1 (plane p moves the pixel by shift[p] along its
// row): one Hamming distance each, 16 units per bit. `disparity_order`: shift[p] = -p for all p.
void ShiftCensusCosts(uint64_t code, const uint64_t* src, const int* shift, bool disparity_order, int p0, int p1, int x,
                      int y, int sw, int sh, uint16_t* out) {
  if (y >= sh) {
    std::fill(out + p0, out + p1, kOutsideCost);
    return;
  }
  const uint64_t* row = src + static_cast<size_t>(y) * sw;
  int p = p0;
#if IBMR_SWEEP_AVX512
  // Disparity order (shift[p] = -p, as rectified pairs have): plane p reads code x - p, so eight
  // planes read eight consecutive codes, loaded at once and reversed.
  const __m512i code_v = _mm512_set1_epi64(static_cast<long long>(code));
  const __m512i reverse = _mm512_set_epi64(0, 1, 2, 3, 4, 5, 6, 7);
  for (; disparity_order && p + 8 <= p1; p += 8) {
    const int first = x - p - 7;  // the code of plane p + 7, the lowest address
    if (first < 0 || x - p >= sw) break;  // the row's ends: one plane at a time
    const __m512i codes = _mm512_permutexvar_epi64(reverse, _mm512_loadu_si512(row + first));
    const __m512i distances = _mm512_popcnt_epi64(_mm512_xor_si512(codes, code_v));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + p), _mm_slli_epi16(_mm512_cvtepi64_epi16(distances), 4));
  }
#endif
  // Disparity order, planes whose code lies on the row (p <= x): no shift table, no bounds test.
  if (disparity_order && x < sw) {
    for (const int end = std::min(p1, x + 1); p < end; ++p) {
      out[p] = static_cast<uint16_t>(__builtin_popcountll(code ^ row[x - p]) << 4);
    }
  }
  for (; p < p1; ++p) {
    const int xs = x + shift[p];
    const bool inside = xs >= 0 && xs < sw;
    const uint16_t cost = static_cast<uint16_t>(__builtin_popcountll(code ^ row[inside ? xs : 0]) << 4);
    out[p] = inside ? cost : kOutsideCost;
  }
}

// A family of homographies affine in the plane index, H_p = base + p * step (fronto-parallel planes
// uniform in inverse depth: H_p = K' (R + t n^T / d_p) K^-1 with 1/d_p linear in p): the taps of a
// pixel then need two 3-vectors per pixel and one multiply-add per coordinate and plane.
struct AffineFamily {
  float base[9], step[9];
};

// True (and the family) when `homographies` are affine in the index to 1e-9 of their largest entry.
bool FindAffineFamily(const std::vector<Eigen::Matrix3d>& homographies, AffineFamily* family) {
  const int np = static_cast<int>(homographies.size());
  if (np < 2) return false;
  const Eigen::Matrix3d step = (homographies.back() - homographies.front()) / (np - 1);
  double scale = 0;
  for (const Eigen::Matrix3d& h : homographies) scale = std::max(scale, h.cwiseAbs().maxCoeff());
  for (int p = 0; p < np; ++p) {
    if ((homographies[p] - (homographies.front() + p * step)).cwiseAbs().maxCoeff() > 1e-9 * scale) return false;
  }
  for (int e = 0; e < 9; ++e) {
    family->base[e] = static_cast<float>(homographies.front()(e / 3, e % 3));
    family->step[e] = static_cast<float>(step(e / 3, e % 3));
  }
  return true;
}

// ComputeTaps for an affine family (same outputs' meaning; the same float steps in both builds).
void ComputeAffineTaps(const AffineFamily& f, int p0, int p1, float xc, float yc, int sw, int sh, TapAxis axis, Taps* taps) {
  float max_u, max_v;
  TapLimits(axis, sw, sh, &max_u, &max_v);
  // Per pixel: the homogeneous image of the pixel under H_0, and its change per plane.
  const float u0 = f.base[0] * xc + f.base[1] * yc + f.base[2], du = f.step[0] * xc + f.step[1] * yc + f.step[2];
  const float v0 = f.base[3] * xc + f.base[4] * yc + f.base[5], dv = f.step[3] * xc + f.step[4] * yc + f.step[5];
  const float z0 = f.base[6] * xc + f.base[7] * yc + f.base[8], dz = f.step[6] * xc + f.step[7] * yc + f.step[8];
#if IBMR_SWEEP_AVX512
  const __m512 half = _mm512_set1_ps(0.5f);
  const __m512 u0v = _mm512_set1_ps(u0), duv = _mm512_set1_ps(du), v0v = _mm512_set1_ps(v0), dvv = _mm512_set1_ps(dv);
  const __m512 z0v = _mm512_set1_ps(z0), dzv = _mm512_set1_ps(dz);
  const __m512i lanes = _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
  for (int p = p0; p < p1; p += 16) {
    const __m512 pf = _mm512_cvtepi32_ps(_mm512_add_epi32(_mm512_set1_epi32(p), lanes));
    const __m512 z = _mm512_add_ps(z0v, _mm512_mul_ps(pf, dzv));
    const __m512 u = _mm512_sub_ps(_mm512_div_ps(_mm512_add_ps(u0v, _mm512_mul_ps(pf, duv)), z), half);
    const __m512 v = _mm512_sub_ps(_mm512_div_ps(_mm512_add_ps(v0v, _mm512_mul_ps(pf, dvv)), z), half);
    StoreTaps16(z, u, v, max_u, max_v, sw, p, axis, taps);
  }
#elif IBMR_SWEEP_AVX2
  const __m256 half = _mm256_set1_ps(0.5f);
  const __m256 u0v = _mm256_set1_ps(u0), duv = _mm256_set1_ps(du), v0v = _mm256_set1_ps(v0), dvv = _mm256_set1_ps(dv);
  const __m256 z0v = _mm256_set1_ps(z0), dzv = _mm256_set1_ps(dz);
  const __m256i lanes = _mm256_set_epi32(7, 6, 5, 4, 3, 2, 1, 0);
  for (int p = p0; p < p1; p += 8) {
    const __m256 pf = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_set1_epi32(p), lanes));
    const __m256 z = _mm256_add_ps(z0v, _mm256_mul_ps(pf, dzv));
    const __m256 u = _mm256_sub_ps(_mm256_div_ps(_mm256_add_ps(u0v, _mm256_mul_ps(pf, duv)), z), half);
    const __m256 v = _mm256_sub_ps(_mm256_div_ps(_mm256_add_ps(v0v, _mm256_mul_ps(pf, dvv)), z), half);
    StoreTaps8(z, u, v, max_u, max_v, sw, p, axis, taps);
  }
#else
  for (int p = p0; p < p1; ++p) {
    const float pf = static_cast<float>(p);
    const float z = z0 + pf * dz;
    StoreTap(z, (u0 + pf * du) / z - 0.5f, (v0 + pf * dv) / z - 0.5f, max_u, max_v, sw, p, axis, taps);
  }
#endif
}

#if IBMR_SWEEP_AVX512
// The bilinear census cost of 16 lanes from the Hamming distances to the four codes around the
// correspondence (CensusCosts' formula), kOutsideCost where not `valid`, as 16 x uint16.
// a (1 - w) + b w in fixed point (w in 1/kWeightOne): a kWeightOne + (b - a) w. The product by
// VPMADDWD, one micro-op where VPMULLD takes two (and half its latency, on Intel): b - a fits 16
// bits (distances are at most 64, and one weighted step at most 64 kWeightOne) and w's high half
// is 0, so the high halves' product adds nothing, whatever b - a's sign.
inline __m512i Lerp(__m512i a, __m512i b, __m512i w) {
  return _mm512_add_epi32(_mm512_slli_epi32(a, kWeightShift), _mm512_madd_epi16(_mm512_sub_epi32(b, a), w));
}
// A weighted sum of `shift` fractional bits as cost units (16 a bit), rounded; kOutsideCost where
// not `valid`; as 16 x uint16.
inline __m256i CostUnits(__m512i sum, int shift, __mmask16 valid) {
  const __m512i round = _mm512_set1_epi32(1 << (shift - 5)), outside = _mm512_set1_epi32(kOutsideCost);
  return _mm512_cvtepi32_epi16(_mm512_mask_blend_epi32(valid, outside, _mm512_srai_epi32(_mm512_add_epi32(sum, round), shift - 4)));
}
inline __m256i BilinearCost(__m512i d00, __m512i d01, __m512i d10, __m512i d11, __m512i wx, __m512i wy, __mmask16 valid) {
  return CostUnits(Lerp(Lerp(d00, d01, wx), Lerp(d10, d11, wx), wy), 2 * kWeightShift, valid);
}

// Where the contiguous loads of a group of 16 lanes' codes start: each half's (8 lanes') window
// starts at the lesser of its first and last lanes' column and row (a homography maps a run of
// pixels to a run of codes in order, increasing or decreasing). `column` and `row`: each lane's
// top-left code relative to its half's window; `fast`: the valid lanes within `max_column`
// columns and 2 rows of it whose window's `rows_read` rows of 16 codes exist (sw * sh codes:
// fewer than 2^31, as indices are int32); `second`: the lanes on the window's second row.
struct LaneWindows {
  __m512i column, row;
  __mmask16 fast, second;
  int starts[2];
};
inline LaneWindows WindowsOf(const LaneTaps& t, __mmask16 valid, int sw, int sh, int max_column, int rows_read) {
  const __m512i first_lane = _mm512_set_epi32(8, 8, 8, 8, 8, 8, 8, 8, 0, 0, 0, 0, 0, 0, 0, 0);
  const __m512i last_lane = _mm512_set_epi32(15, 15, 15, 15, 15, 15, 15, 15, 7, 7, 7, 7, 7, 7, 7, 7);
  const __m512i x_min = _mm512_min_epi32(_mm512_permutexvar_epi32(first_lane, t.column), _mm512_permutexvar_epi32(last_lane, t.column));
  const __m512i y_min = _mm512_min_epi32(_mm512_permutexvar_epi32(first_lane, t.row), _mm512_permutexvar_epi32(last_lane, t.row));
  LaneWindows w;
  w.column = _mm512_sub_epi32(t.column, x_min);
  w.row = _mm512_sub_epi32(t.row, y_min);
  const __m512i start = _mm512_add_epi32(_mm512_mullo_epi32(y_min, _mm512_set1_epi32(sw)), x_min);
  w.fast = valid & _mm512_cmple_epu32_mask(w.column, _mm512_set1_epi32(max_column)) &
           _mm512_cmple_epu32_mask(w.row, _mm512_set1_epi32(1)) &
           _mm512_cmple_epi32_mask(start, _mm512_set1_epi32(sw * (sh - (rows_read - 1)) - 16));
  w.second = _mm512_cmpgt_epi32_mask(w.row, _mm512_setzero_si512());
  w.starts[0] = _mm_cvtsi128_si32(_mm512_castsi512_si128(start));
  w.starts[1] = _mm_cvtsi128_si32(_mm512_extracti32x4_epi32(start, 2));
  return w;
}

// Hamming distances between 16 reference codes (one a lane; `codes[0]` holds lanes 0-7,
// `codes[1]` lanes 8-15) and the codes `t`'s lanes weigh (kAxis): at index, index + 1, index + sw
// and index + sw + 1 (kBoth), at index and index + 1 (kRows: the lower codes' weight is 0) or at
// index and index + sw (kColumns), as 8 x int64 per half and code: d[h][k] in that order (any
// value in lanes not `valid`; Join packs two halves into 16 x int32 with one permute). One plane
// maps neighbouring reference pixels to nearby codes: when a half's 8 top-left codes lie within
// 15 columns and two rows of each other, contiguous loads of 16 codes from the rows involved
// (three at most; two along the rows) and in-register permutes fetch them, else gathers do.
// (Epipolar lines that are not horizontal cross rows often: on the Middlebury temple ring, half of
// the groups of 8 span two rows.) Both halves' windows are found at once, in vector registers.
template <TapAxis kAxis>
inline void Distances(const __m512i codes[2], const LaneTaps& t, __mmask16 valid, const uint64_t* src, int sw, int sh,
                      __m512i d[2][4]) {
  constexpr bool kRight = kAxis != TapAxis::kColumns;  // a lane reads the code right of its own
  constexpr bool kBelow = kAxis != TapAxis::kRows;     // and the one below
  constexpr int kCodes = kRight && kBelow ? 4 : 2;
  auto count = [&](__m512i c, __m512i code) { return _mm512_popcnt_epi64(_mm512_xor_si512(c, code)); };
  // The loads reach column x_min + 15 of row y_min + 1, or y_min + 2 with the codes below (codes
  // past a row's end are never picked).
  const LaneWindows windows = WindowsOf(t, valid, sw, sh, kRight ? 14 : 15, kBelow ? 3 : 2);
  const __m512i column = windows.column;
  // Lanes on the window's second row take it as their own and the third as the one below (no
  // branch: which lanes do is as good as random from one plane to the next).
  for (int h = 0; h < 2; ++h) {
    const __mmask8 lanes = static_cast<__mmask8>(valid >> (8 * h));
    if (lanes == 0) {
      for (int k = 0; k < kCodes; ++k) d[h][k] = _mm512_setzero_si512();
      continue;
    }
    if (static_cast<__mmask8>(windows.fast >> (8 * h)) == 0xFF) {
      const __m256i half_column = h == 0 ? _mm512_castsi512_si256(column) : _mm512_extracti64x4_epi64(column, 1);
      const __m512i at = _mm512_cvtepi32_epi64(half_column);
      const __m512i right = _mm512_add_epi64(at, _mm512_set1_epi64(1));
      const uint64_t* r = src + windows.starts[h];
      const __mmask8 on_second = static_cast<__mmask8>(windows.second >> (8 * h));
      const __m512i a0 = _mm512_loadu_si512(r), a1 = _mm512_loadu_si512(r + 8);
      const __m512i b0 = _mm512_loadu_si512(r + sw), b1 = _mm512_loadu_si512(r + sw + 8);
      const __m512i second_row = _mm512_permutex2var_epi64(b0, at, b1);
      int k = 0;
      d[h][k++] = count(_mm512_mask_mov_epi64(_mm512_permutex2var_epi64(a0, at, a1), on_second, second_row), codes[h]);
      const __m512i second_row_right = kRight ? _mm512_permutex2var_epi64(b0, right, b1) : second_row;
      if (kRight) {
        d[h][k++] = count(_mm512_mask_mov_epi64(_mm512_permutex2var_epi64(a0, right, a1), on_second, second_row_right), codes[h]);
      }
      if (kBelow) {
        const __m512i c0 = _mm512_loadu_si512(r + 2 * static_cast<size_t>(sw)), c1 = _mm512_loadu_si512(r + 2 * static_cast<size_t>(sw) + 8);
        d[h][k++] = count(_mm512_mask_mov_epi64(second_row, on_second, _mm512_permutex2var_epi64(c0, at, c1)), codes[h]);
        if (kRight) {
          d[h][k++] = count(_mm512_mask_mov_epi64(second_row_right, on_second, _mm512_permutex2var_epi64(c0, right, c1)), codes[h]);
        }
      }
      continue;
    }
    const __m512i all = LaneIndex(t, sw);
    const __m256i index = h == 0 ? _mm512_castsi512_si256(all) : _mm512_extracti64x4_epi64(all, 1);
    const int offsets[4] = {0, kRight ? 1 : sw, sw, sw + 1};
    for (int k = 0; k < kCodes; ++k) {
      const __m256i at = _mm256_add_epi32(index, _mm256_set1_epi32(offsets[k]));
      d[h][k] = count(_mm512_mask_i32gather_epi64(_mm512_setzero_si512(), lanes, at, src, 8), codes[h]);
    }
  }
}

// BilinearCost with one weight 0, `w` the other (the same integers: with wy = 0,
// (256 top + 2^11) >> 12 = (top + 8) >> 4; with wx = 0, top = 256 d00 and bottom = 256 d10).
inline __m256i LinearCost(__m512i d0, __m512i d1, __m512i w, __mmask16 valid) {
  return CostUnits(Lerp(d0, d1, w), kWeightShift, valid);
}

// The low halves of the 64-bit lanes of `low` and `high` as 16 x int32 (lanes 0-7 from `low`).
inline __m512i Join(__m512i low, __m512i high) {
  const __m512i even = _mm512_set_epi32(30, 28, 26, 24, 22, 20, 18, 16, 14, 12, 10, 8, 6, 4, 2, 0);
  return _mm512_permutex2var_epi32(low, even, high);
}

// BestKCostsAcrossPixels' kAxisMode: a TapAxis (as int) that every neighbour has, or this.
constexpr int kMixedAxes = 3;

// A neighbour as BestKCostsAcrossPixels reads it: its codes, and its homographies, either an
// affine family or rows of n planes.
struct LaneNeighbour {
  const uint64_t* codes = nullptr;
  int width = 0, height = 0;
  const AffineFamily* family = nullptr;
  const float* hom = nullptr;
  TapAxis axis = TapAxis::kBoth;
  float max_u = 0, max_v = 0;  // TapLimits(axis, width, height)
};

// Best-k census costs of 16 consecutive reference pixels x0..x0+15 of row y (the first `count` of
// them exist) for planes p0..p1-1, vectorised over the pixels (a lane per pixel): out[p * 16 + j]
// for pixel x0 + j is the mean of the k lowest of the nn neighbours' costs (nn <= 16; k_shift:
// log2 k when k is a power of two, else -1). The
// projections take the same float steps as ComputeAffineTaps / ComputeTaps, each cost is
// CensusCosts' integer formula, and the k lowest and their mean are the same integers as
// BestKMean's, lane by lane: the results are identical to the other builds'. The neighbours'
// costs of a plane never leave the registers. K: k fixed at compile time (1-3), so that the k
// lowest stay in registers; K == 0: k = runtime_k. kAxisMode: the neighbours' TapAxis when they
// all share one (as usual: the branches on it fold), else kMixedAxes.
template <int K, int kAxisMode>
void BestKCostsAcrossPixels(const uint64_t* ref_codes, int count, const LaneNeighbour* neighbours, int nn, int runtime_k,
                            int k_shift, int n, int p0, int p1, int x0, int y, uint16_t* out) {
  const int k = K > 0 ? K : runtime_k;
  const __mmask16 exist = static_cast<__mmask16>((1u << count) - 1);
  const __m512i codes[2] = {_mm512_maskz_loadu_epi64(static_cast<__mmask8>(exist), ref_codes),
                            _mm512_maskz_loadu_epi64(static_cast<__mmask8>(exist >> 8), ref_codes + 8)};
  const __m512i lanes = _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
  const __m512 half = _mm512_set1_ps(0.5f);
  const __m512 xc = _mm512_add_ps(_mm512_cvtepi32_ps(_mm512_add_epi32(_mm512_set1_epi32(x0), lanes)), half);
  const __m512 yc = _mm512_set1_ps(static_cast<float>(y) + 0.5f);
  // (m[e] xc + m[e+1] yc) + m[e+2], per lane, as the scalar expressions group it.
  auto image = [&](const float* m, int e) {
    return _mm512_add_ps(_mm512_add_ps(_mm512_mul_ps(_mm512_set1_ps(m[e]), xc), _mm512_mul_ps(_mm512_set1_ps(m[e + 1]), yc)),
                         _mm512_set1_ps(m[e + 2]));
  };
  // Per affine neighbour and pixel lane: the image under H_0 and its change per plane.
  struct Affine {
    __m512 u0, du, v0, dv, z0, dz;
  } affine[16];
  for (int i = 0; i < nn; ++i) {
    const AffineFamily* f = neighbours[i].family;
    if (f == nullptr) continue;
    affine[i] = {image(f->base, 0), image(f->step, 0), image(f->base, 3), image(f->step, 3), image(f->base, 6), image(f->step, 6)};
  }
  const __m512 k_float = _mm512_set1_ps(static_cast<float>(k));
  // Every neighbour's taps of plane p, into `taps`.
  auto plane_taps = [&](int p, LaneTaps* taps) {
    const __m512 pf = _mm512_set1_ps(static_cast<float>(p));
    for (int i = 0; i < nn; ++i) {
      const LaneNeighbour& g = neighbours[i];
      __m512 z, u, v;
      if (g.family != nullptr) {
        const Affine& a = affine[i];
        z = _mm512_add_ps(a.z0, _mm512_mul_ps(pf, a.dz));
        u = _mm512_sub_ps(_mm512_div_ps(_mm512_add_ps(a.u0, _mm512_mul_ps(pf, a.du)), z), half);
        v = _mm512_sub_ps(_mm512_div_ps(_mm512_add_ps(a.v0, _mm512_mul_ps(pf, a.dv)), z), half);
      } else {
        float m[9];
        for (int e = 0; e < 9; ++e) m[e] = g.hom[static_cast<size_t>(e) * n + p];
        z = image(m, 6);
        u = _mm512_sub_ps(_mm512_div_ps(image(m, 0), z), half);
        v = _mm512_sub_ps(_mm512_div_ps(image(m, 3), z), half);
      }
      taps[i] = TapsOf(z, u, v, g.max_u, g.max_v, kAxisMode == kMixedAxes ? g.axis : static_cast<TapAxis>(kAxisMode));
    }
  };
  // The planes in a software pipeline: the taps of plane p + 1 are computed before plane p's codes
  // are fetched. One neighbour's work for a plane is a chain of about 80 cycles' latency
  // (divisions, conversions, the window's test, loads, permutes, popcounts, the weighting) that the
  // core, on its own, overlapped with little more than the next neighbour's; so ordered, the taps'
  // chains of the next plane run beside the fetches of this one.
  LaneTaps pipeline[2][16];
  if (p0 < p1) plane_taps(p0, pipeline[0]);
  for (int p = p0; p < p1; ++p) {
    const LaneTaps* taps = pipeline[(p - p0) & 1];
    if (p + 1 < p1) plane_taps(p + 1, pipeline[(p + 1 - p0) & 1]);
    __m256i best[16];
    for (int q = 0; q < k; ++q) best[q] = _mm256_set1_epi16(-1);
    __m256i total = _mm256_setzero_si256();
    for (int i = 0; i < nn; ++i) {
      const LaneNeighbour& g = neighbours[i];
      const LaneTaps& t = taps[i];
      const __mmask16 valid = t.inside & exist;
      __m512i d[2][4];
      const TapAxis axis = kAxisMode == kMixedAxes ? g.axis : static_cast<TapAxis>(kAxisMode);
      if (axis == TapAxis::kRows) {
        Distances<TapAxis::kRows>(codes, t, valid, g.codes, g.width, g.height, d);
      } else if (axis == TapAxis::kColumns) {
        Distances<TapAxis::kColumns>(codes, t, valid, g.codes, g.width, g.height, d);
      } else {
        Distances<TapAxis::kBoth>(codes, t, valid, g.codes, g.width, g.height, d);
      }
      __m256i cost = axis != TapAxis::kBoth
                         ? LinearCost(Join(d[0][0], d[1][0]), Join(d[0][1], d[1][1]), axis == TapAxis::kRows ? t.wx : t.wy, valid)
                         : BilinearCost(Join(d[0][0], d[1][0]), Join(d[0][1], d[1][1]), Join(d[0][2], d[1][2]),
                                               Join(d[0][3], d[1][3]), t.wx, t.wy, valid);
      if (k == nn) {
        total = _mm256_add_epi16(total, cost);  // at most 16 costs of 1024: no overflow
        continue;
      }
      for (int q = 0; q < k; ++q) {  // insertion: best[] stays sorted, the larger value moves on
        const __m256i lower = _mm256_min_epu16(best[q], cost);
        cost = _mm256_max_epu16(best[q], cost);
        best[q] = lower;
      }
    }
    if (k != nn) {
      for (int q = 0; q < k; ++q) total = _mm256_add_epi16(total, best[q]);
    }
    __m256i mean;
    if (k_shift >= 0) {
      mean = _mm256_srli_epi16(total, k_shift);
    } else {  // a float quotient of integers below 2^24 truncates to the integer quotient
      const __m512 quotient = _mm512_div_ps(_mm512_cvtepi32_ps(_mm512_cvtepu16_epi32(total)), k_float);
      mean = _mm512_cvtepi32_epi16(_mm512_cvttps_epi32(quotient));
    }
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + static_cast<size_t>(p) * 16), mean);
  }
}
#endif

// Census cost of every plane: Hamming distances between the reference code and the four codes
// around the correspondence, interpolated bilinearly (a cost curve smooth in the plane index, for
// sub-pixel accuracy), 16 units per bit: ((h00 (1-ax) + h01 ax)(1-ay) + (h10 (1-ax) + h11 ax) ay)
// in fixed point, for planes p0..p1-1 (multiples of 16). Along one axis (TapAxis) one weight is 0
// and the formula is the linear one: the codes of weight 0 are read (they exist) and cancel.
void CensusCosts(uint64_t code, const uint64_t* src, int sw, const Taps& taps, int p0, int p1, uint16_t* out) {
#if IBMR_SWEEP_AVX512
  const __m512i code_v = _mm512_set1_epi64(static_cast<long long>(code));
  const __m512i zero = _mm512_setzero_si512();
  // Hamming distances of 16 lanes at index + offset, as 16 x int32.
  auto distances = [&](__m512i index, __mmask16 valid, int offset) {
    const __m512i at = _mm512_add_epi32(index, _mm512_set1_epi32(offset));
    const __m512i lo = _mm512_mask_i32gather_epi64(zero, static_cast<__mmask8>(valid), _mm512_castsi512_si256(at), src, 8);
    const __m512i hi = _mm512_mask_i32gather_epi64(zero, static_cast<__mmask8>(valid >> 8),
                                                   _mm512_extracti64x4_epi64(at, 1), src, 8);
    const __m256i dlo = _mm512_cvtepi64_epi32(_mm512_popcnt_epi64(_mm512_xor_si512(lo, code_v)));
    const __m256i dhi = _mm512_cvtepi64_epi32(_mm512_popcnt_epi64(_mm512_xor_si512(hi, code_v)));
    return _mm512_inserti64x4(_mm512_castsi256_si512(dlo), dhi, 1);
  };
  for (int p = p0; p < p1; p += 16) {
    const __m512i index = _mm512_loadu_si512(taps.index.data() + p);
    const __mmask16 valid = _mm512_cmpge_epi32_mask(index, zero);
    const __m512i wx = _mm512_loadu_si512(taps.wx.data() + p), wy = _mm512_loadu_si512(taps.wy.data() + p);
    const __m512i d00 = distances(index, valid, 0), d01 = distances(index, valid, 1);
    const __m512i d10 = distances(index, valid, sw), d11 = distances(index, valid, sw + 1);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(out + p), BilinearCost(d00, d01, d10, d11, wx, wy, valid));
  }
#else
  for (int p = p0; p < p1; ++p) {
    const int32_t index = taps.index[p];
    if (index < 0) {
      out[p] = kOutsideCost;
      continue;
    }
    const uint64_t* r0 = src + index;
    const int32_t d00 = __builtin_popcountll(code ^ r0[0]);
    const int32_t d01 = __builtin_popcountll(code ^ r0[1]), d10 = __builtin_popcountll(code ^ r0[sw]),
                  d11 = __builtin_popcountll(code ^ r0[sw + 1]);
    const int32_t top = (d00 << kWeightShift) + (d01 - d00) * taps.wx[p];
    const int32_t bottom = (d10 << kWeightShift) + (d11 - d10) * taps.wx[p];
    const int32_t sum = (top << kWeightShift) + (bottom - top) * taps.wy[p];
    out[p] = static_cast<uint16_t>((sum + (1 << (2 * kWeightShift - 5))) >> (2 * kWeightShift - 4));
  }
#endif
}

// The mean of the k smallest of nn costs, entry by entry: neighbour i's costs at costs + i * stride
// (overwritten), entries [begin, end), into out[begin, end). `best` holds k * stride entries.
// k == nn is the plain mean; otherwise an insertion network keeps the k smallest (it vectorises
// over the entries).
void BestKMean(uint16_t* __restrict costs, size_t stride, int nn, int k, int k_shift, size_t begin, size_t end,
               uint16_t* __restrict best, uint16_t* __restrict out) {
  if (nn == 1) {
    std::copy(costs + begin, costs + end, out + begin);
    return;
  }
  if (k == nn) {
    for (size_t e = begin; e < end; ++e) {
      uint32_t sum = 0;
      for (int i = 0; i < nn; ++i) sum += costs[i * stride + e];
      out[e] = static_cast<uint16_t>(sum / nn);
    }
    return;
  }
  for (int q = 0; q < k; ++q) std::fill(best + q * stride + begin, best + q * stride + end, static_cast<uint16_t>(0xFFFF));
  for (int i = 0; i < nn; ++i) {
    uint16_t* c = costs + i * stride;  // the value being inserted
    for (int q = 0; q < k; ++q) {
      uint16_t* b = best + q * stride;
      for (size_t e = begin; e < end; ++e) {
        const uint16_t lo = std::min(b[e], c[e]);
        c[e] = std::max(b[e], c[e]);
        b[e] = lo;
      }
    }
  }
  for (size_t e = begin; e < end; ++e) {
    uint32_t sum = 0;
    for (int q = 0; q < k; ++q) sum += best[q * stride + e];
    out[e] = static_cast<uint16_t>(k_shift >= 0 ? sum >> k_shift : sum / k);
  }
}

// One pixel's costs `c` limited to its plane range first..last: the planes outside it take the mean
// of its costs in range. An empty range (the pixel is not matched: returns false) makes the curve
// flat, kOutsideCost on the padding planes too: a semi-global path then carries the pixel's curve
// unchanged (PlaneSweep's crop relies on it).
inline bool LimitToRange(int first, int last, int np, int stride, uint16_t* c) {
  last = std::min(last, np - 1);
  if (first > last) {
    std::fill(c, c + stride, kOutsideCost);
    return false;
  }
  if (first == 0 && last == np - 1) return true;  // every plane in range: nothing to fill
  uint32_t sum = 0;
  for (int p = first; p <= last; ++p) sum += c[p];
  const uint16_t mean = static_cast<uint16_t>(sum / (last - first + 1));
  std::fill(c, c + first, mean);
  std::fill(c + last + 1, c + np, mean);
  return true;
}

// The axis a neighbour's census cost is interpolated along (CensusSampling::kAlongEpipolar): the
// one its correspondences move along more, from the first plane to the last, for the reference
// pixel at the centre of the neighbour's image (the views of a sweep share a size in practice; a
// fixed pixel, so that every part of a view chooses alike). Scalar double steps in a fixed order:
// every build chooses the same.
TapAxis InterpolationAxis(const std::vector<Eigen::Matrix3d>& homographies, int sw, int sh, CensusSampling sampling) {
  if (sampling == CensusSampling::kBilinear || homographies.size() < 2) return TapAxis::kBoth;
  const double x = 0.5 * sw, y = 0.5 * sh;
  auto image = [&](const Eigen::Matrix3d& m, double* u, double* v) {
    const double z = m(2, 0) * x + m(2, 1) * y + m(2, 2);
    *u = (m(0, 0) * x + m(0, 1) * y + m(0, 2)) / z;
    *v = (m(1, 0) * x + m(1, 1) * y + m(1, 2)) / z;
  };
  double u0, v0, u1, v1;
  image(homographies.front(), &u0, &v0);
  image(homographies.back(), &u1, &v1);
  if (!std::isfinite(u0) || !std::isfinite(u1) || !std::isfinite(v0) || !std::isfinite(v1)) return TapAxis::kBoth;
  return std::abs(u1 - u0) >= std::abs(v1 - v0) ? TapAxis::kRows : TapAxis::kColumns;
}

// Census costs of all neighbours, combined by best-k: the mean of the k smallest costs per plane.
// With `ranges`, only the blocks of 16 planes that meet a pixel's range are evaluated, and each
// pixel is then limited to its range (LimitToRange, as ApplyRanges would, while its costs are in
// the first-level cache; `unmatched` marks the empty ones). Returns the evaluations done (counted
// per pixel over its own blocks) and the threads' CPU time spent on them.
VolumeWork BuildCensusVolume(const std::vector<uint64_t>& ref, const std::vector<const std::vector<uint64_t>*>& src,
                             const std::vector<Neighbour>& neighbours, int k, CensusSampling sampling, const PlaneRanges* ranges,
                             cv::Point origin, CostVolume* v) {
  const int w = v->width, h = v->height, np = v->planes, n = v->stride;
  const int nn = static_cast<int>(neighbours.size());
  // Homographies as float rows of n planes (padding planes zero); integer shifts detected for
  // rectified pairs.
  std::vector<std::vector<float>> hom(nn, std::vector<float>(9 * static_cast<size_t>(n), 0.f));
  // Otherwise, homographies affine in the plane index are detected (fronto-parallel sweeps).
  std::vector<std::vector<int>> shift(nn);
  std::vector<char> disparity_order(nn, 0), affine(nn, 0);
  std::vector<AffineFamily> family(nn);
  std::vector<TapAxis> axis(nn);
  for (int i = 0; i < nn; ++i) {
    axis[i] = InterpolationAxis(neighbours[i].homographies, neighbours[i].gray.cols, neighbours[i].gray.rows, sampling);
    bool all_shifts = true, in_order = true;
    for (int p = 0; p < np; ++p) {
      const Eigen::Matrix3d& m = neighbours[i].homographies[p];
      for (int e = 0; e < 9; ++e) hom[i][static_cast<size_t>(e) * n + p] = static_cast<float>(m(e / 3, e % 3));
      int dx = 0, dy = 0;
      all_shifts &= IsIntegerTranslation(m, &dx, &dy) && dy == 0;
      in_order &= dx == -p;
      shift[i].push_back(dx);
    }
    if (!all_shifts) shift[i].clear();
    disparity_order[i] = all_shifts && in_order;
    affine[i] = !all_shifts && FindAffineFamily(neighbours[i].homographies, &family[i]);
  }
  const int k_shift = (k & (k - 1)) == 0 ? __builtin_ctz(k) : -1;  // a power-of-two k divides by a shift
  // The AVX-512 build evaluates warped neighbours a lane per pixel (BestKCostsAcrossPixels), 16
  // pixels of a row for one plane at a time: their codes are fetched by contiguous loads where the
  // other builds gather them plane by plane. Rectified pairs (shifts) keep the plane-major kernel.
  bool across_pixels = IBMR_SWEEP_AVX512 != 0 && nn <= 16;
  for (int i = 0; i < nn; ++i) across_pixels &= shift[i].empty();
#if IBMR_SWEEP_AVX512
  // The kernel for k and the neighbours' interpolation axis (one for all, as usual, or mixed).
  int axis_mode = nn > 0 ? static_cast<int>(axis[0]) : 0;
  for (int i = 1; i < nn; ++i) axis_mode = axis[i] == axis[0] ? axis_mode : kMixedAxes;
  auto kernel_for_axes = [axis_mode](auto k_constant) {
    constexpr int kK = decltype(k_constant)::value;
    return axis_mode == 0   ? &BestKCostsAcrossPixels<kK, 0>
           : axis_mode == 1 ? &BestKCostsAcrossPixels<kK, 1>
           : axis_mode == 2 ? &BestKCostsAcrossPixels<kK, 2>
                            : &BestKCostsAcrossPixels<kK, kMixedAxes>;
  };
  auto* const lane_kernel = k == 1   ? kernel_for_axes(std::integral_constant<int, 1>())
                            : k == 2 ? kernel_for_axes(std::integral_constant<int, 2>())
                            : k == 3 ? kernel_for_axes(std::integral_constant<int, 3>())
                                     : kernel_for_axes(std::integral_constant<int, 0>());
  std::vector<LaneNeighbour> lane_neighbours(across_pixels ? nn : 0);
  for (size_t i = 0; i < lane_neighbours.size(); ++i) {
    lane_neighbours[i] = {src[i]->data(), neighbours[i].gray.cols, neighbours[i].gray.rows, affine[i] ? &family[i] : nullptr,
                          hom[i].data(), axis[i]};
    TapLimits(axis[i], lane_neighbours[i].width, lane_neighbours[i].height, &lane_neighbours[i].max_u, &lane_neighbours[i].max_v);
  }
#endif
  if (ranges != nullptr) v->unmatched.assign(static_cast<size_t>(w) * h, 0);
  tbb::enumerable_thread_specific<int64_t> evaluations(0);
  TaskSeconds seconds;
  // Pixels in chunks of kChunk along a row. The plane-major kernel takes each neighbour in turn
  // over the chunk: the codes one neighbour's correspondences read for a chunk stay in the
  // first-level cache (pixel by pixel with every neighbour inside, the four neighbours' paths
  // together overflowed it). The lane kernel takes the chunk's 16 pixels at once.
  // The rows come in tiles of 4-8 (simple_partitioner, grain 8), swept chunk by chunk down the
  // tile's rows before the next chunk. The codes a chunk reads over all its planes form a strip
  // along the epipolar lines, and the chunk below reads nearly the same strip. Where the lines run
  // along the neighbour's columns (templeSparseRing: the strip spans ~100 rows of the neighbour, a
  // few cache lines on each), the four neighbours' strips exceed the first-level cache but stay in
  // the second-level one between the tile's rows. Row by row across the whole image, they were
  // fetched from the third-level cache again for every row: 16% more time for the evaluations
  // (830 -> 967 M/s over 4 alternated pairs), no change where the lines run along the rows.
  constexpr int kChunk = 16;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& rows) {
    const TaskSeconds::Scope timed(&seconds);
    // Per neighbour, n planes of kChunk pixels, [j][i][p]; across pixels, only the combined costs,
    // [p][j] in `lane_mean`.
    std::vector<uint16_t> chunk_costs(across_pixels ? 0 : static_cast<size_t>(kChunk) * nn * n, kMaxCost);
    std::vector<uint16_t> best(across_pixels ? 0 : static_cast<size_t>(k) * n);
    std::vector<uint16_t> lane_mean(across_pixels ? static_cast<size_t>(n) * kChunk : 0);
    std::array<int, kChunk> chunk_p0{}, chunk_p1{};
    std::array<bool, kChunk> chunk_live{};
    Taps taps;
    if (!across_pixels) taps.Resize(n);
    int64_t& done = evaluations.local();
    for (int x0 = 0; x0 < w; x0 += kChunk) {
      for (int y = rows.begin(); y < rows.end(); ++y) {
        const int count = std::min(kChunk, w - x0);
        // The chunk's costs, into the volume.
        [&] {
          int union_p0 = n, union_p1 = 0;  // the blocks any live pixel of the chunk needs
          for (int j = 0; j < count; ++j) {
            const size_t pixel = static_cast<size_t>(y) * w + x0 + j;
            int p0 = 0, p1 = n;  // blocks of 16 planes evaluated
            chunk_live[j] = true;
            if (ranges != nullptr) {
              const int first = ranges->first[pixel], last = ranges->last[pixel];
              if (ranges->Empty(pixel, np)) {
                chunk_live[j] = false;
                continue;
              }
              p0 = first & ~15;
              p1 = std::min(n, (last + 16) & ~15);
            }
            chunk_p0[j] = p0;
            chunk_p1[j] = p1;
            union_p0 = std::min(union_p0, p0);
            union_p1 = std::max(union_p1, p1);
            done += static_cast<int64_t>(std::min(p1, np) - p0) * nn;
          }
          if (union_p0 >= union_p1) return;  // no live pixel
#if IBMR_SWEEP_AVX512
          if (across_pixels) {
            const int p_end = std::min(union_p1, np);
            lane_kernel(ref.data() + static_cast<size_t>(y) * w + x0, count, lane_neighbours.data(), nn, k, k_shift, n, union_p0,
                        p_end, x0 + origin.x, y + origin.y, lane_mean.data());
            for (int j = 0; j < count; ++j) {
              if (!chunk_live[j]) continue;
              uint16_t* out = v->At(x0 + j, y);
              const uint16_t* mean = lane_mean.data() + j;
              for (int p = chunk_p0[j], end = std::min(chunk_p1[j], np); p < end; ++p) out[p] = mean[static_cast<size_t>(p) * kChunk];
            }
            return;
          }
#endif
          for (int i = 0; i < nn; ++i) {
            const int sw = neighbours[i].gray.cols, sh = neighbours[i].gray.rows;
            const bool shifts = !shift[i].empty();
            for (int j = 0; j < count; ++j) {
              if (!chunk_live[j]) continue;
              const int x = x0 + j, p0 = chunk_p0[j], p1 = chunk_p1[j];
              const uint64_t code = ref[static_cast<size_t>(y) * w + x];
              uint16_t* c = chunk_costs.data() + (static_cast<size_t>(j) * nn + i) * n;
              if (shifts) {
                ShiftCensusCosts(code, src[i]->data(), shift[i].data(), disparity_order[i], p0, std::min(p1, np), x + origin.x,
                                 y + origin.y, sw, sh, c);
              } else {
                if (affine[i]) {
                  ComputeAffineTaps(family[i], p0, p1, (x + origin.x) + 0.5f, (y + origin.y) + 0.5f, sw, sh, axis[i], &taps);
                } else {
                  ComputeTaps(hom[i].data(), n, p0, p1, (x + origin.x) + 0.5f, (y + origin.y) + 0.5f, sw, sh, axis[i], &taps);
                }
                CensusCosts(code, src[i]->data(), sw, taps, p0, p1, c);
              }
            }
          }
          for (int j = 0; j < count; ++j) {
            if (!chunk_live[j]) continue;
            BestKMean(chunk_costs.data() + static_cast<size_t>(j) * nn * n, n, nn, k, k_shift, chunk_p0[j],
                      std::min(chunk_p1[j], np), best.data(), v->At(x0 + j, y));
          }
        }();
        if (ranges == nullptr) continue;
        for (int j = 0; j < count; ++j) {
          const size_t pixel = static_cast<size_t>(y) * w + x0 + j;
          // A pixel left out of the volume is unmatched, its curve `flat` (LeaveOutFarUnmatched).
          v->unmatched[pixel] = !v->Stored(pixel) || !LimitToRange(ranges->first[pixel], ranges->last[pixel], np, n, v->At(x0 + j, y));
        }
      }
    }
  }, tbb::simple_partitioner());
  return {evaluations.combine(std::plus<int64_t>()), seconds.Total()};
}

// Planes outside each pixel's range take the mean of its in-range costs; an unmatched pixel
// (empty range) gets a flat curve and is marked in `unmatched`.
void ApplyRanges(const PlaneRanges& ranges, CostVolume* v) {
  const int w = v->width;
  v->unmatched.assign(static_cast<size_t>(w) * v->height, 0);
  tbb::parallel_for(0, v->height, [&](int y) {
    for (int x = 0; x < w; ++x) {
      const size_t pixel = static_cast<size_t>(y) * w + x;
      v->unmatched[pixel] = !LimitToRange(ranges.first[pixel], ranges.last[pixel], v->planes, v->stride, v->At(x, y));
    }
  });
}

}  // namespace

// The census's row loops, on separate buffers (restrict): the loops store bytes, which may alias
// anything, so written inline over a lambda's captures the compiler reloaded the width at every
// pixel and ran them one byte at a time (the census was 40% of a two-view match).
inline void CensusFirstBit(uint8_t* __restrict bits, const uint8_t* __restrict q, const uint8_t* __restrict c, int w) {
#pragma GCC ivdep
  for (int x = 0; x < w; ++x) bits[x] = static_cast<uint8_t>(q[x] < c[x]);
}
inline void CensusNextBit(uint8_t* __restrict bits, const uint8_t* __restrict q, const uint8_t* __restrict c, int w) {
#pragma GCC ivdep
  for (int x = 0; x < w; ++x) bits[x] = static_cast<uint8_t>((bits[x] << 1) | (q[x] < c[x]));
}
inline void CensusFlush(uint64_t* __restrict out, const uint8_t* __restrict bits, int shift, int w) {
#pragma GCC ivdep
  for (int x = 0; x < w; ++x) out[x] = (out[x] << shift) | bits[x];
}

std::vector<uint64_t> CensusTransform(const cv::Mat& gray, int rx, int ry) {
  const int w = gray.cols, h = gray.rows;
  std::vector<uint64_t> codes(static_cast<size_t>(w) * h, 0);
  // The window's rows with clamped borders, one after another (2 ry + 1 rows of w + 2 rx).
  const int pw = w + 2 * rx;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& rows) {
    std::vector<uint8_t> padded(static_cast<size_t>(2 * ry + 1) * pw);
    std::vector<uint8_t> bits(w);
    for (int y = rows.begin(); y < rows.end(); ++y) {
      const uint8_t* c = gray.ptr<uint8_t>(y);
      uint64_t* out = codes.data() + static_cast<size_t>(y) * w;
      for (int dy = -ry; dy <= ry; ++dy) {
        const uint8_t* r = gray.ptr<uint8_t>(std::clamp(y + dy, 0, h - 1));
        uint8_t* p = padded.data() + static_cast<size_t>(dy + ry) * pw;
        std::fill(p, p + rx, r[0]);
        std::copy(r, r + w, p + rx);
        std::fill(p + rx + w, p + pw, r[w - 1]);
      }
      // One window offset at a time over the whole row, in groups of 8: each offset's bit goes
      // into a byte per pixel (the loop over x runs on 8-bit lanes), and each full group shifts
      // into the 64-bit codes once. The bits land in the same order as one shift per offset.
      // (The first offset of a group assigns its bit, so `bits` needs no clearing.)
      int in_group = 0;
      for (int dy = -ry; dy <= ry; ++dy) {
        for (int dx = -rx; dx <= rx; ++dx) {
          if (dx == 0 && dy == 0) continue;
          const uint8_t* q = padded.data() + static_cast<size_t>(dy + ry) * pw + rx + dx;
          if (in_group == 0) {
            CensusFirstBit(bits.data(), q, c, w);
          } else {
            CensusNextBit(bits.data(), q, c, w);
          }
          if (++in_group == 8) {
            CensusFlush(out, bits.data(), in_group, w);
            in_group = 0;
          }
        }
      }
      if (in_group > 0) CensusFlush(out, bits.data(), in_group, w);
    }
  });
  return codes;
}

namespace {

// Whether the box filter of radius r (BoxFilterVolume's fixed-point mean, over every clipped
// window's area) maps a window of kOutsideCost curves to kOutsideCost: then an unmatched pixel with
// no matched one in its window keeps the flat curve LimitToRange gave it.
bool FlatCurveSurvivesTheBox(int r) {
  if (r <= 0) return true;
  for (int ny = 1; ny <= 2 * r + 1; ++ny) {
    for (int nx = 1; nx <= 2 * r + 1; ++nx) {
      const uint32_t area = static_cast<uint32_t>(ny * nx);
      if (area == 1) continue;  // copied
      if ((uint64_t{area} * kOutsideCost * BoxReciprocal(area)) >> 16 != kOutsideCost) return false;
    }
  }
  return true;
}

// Leaves out of the volume the unmatched pixels (empty plane range) that no matched pixel reaches
// through the box filter of radius r (none within r pixels in x and y): their filtered curve is
// flat kOutsideCost, which `flat` holds once for all of them (the semi-global paths cross them
// reading it). Sets the volume's slots (the stored pixels in row-major order) and returns how many
// are stored. On templeSparseRing the part a view sweeps (the bounding box of its matched pixels)
// holds large unmatched areas around the object: those pages are never touched.
size_t LeaveOutFarUnmatched(const PlaneRanges& ranges, int r, CostVolume* v) {
  const int w = v->width, h = v->height;
  cv::Mat reached(h, w, CV_8U);
  for (int y = 0; y < h; ++y) {
    uint8_t* row = reached.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      row[x] = ranges.Empty(static_cast<size_t>(y) * w + x, v->planes) ? 0 : 255;
    }
  }
  if (r > 0) cv::dilate(reached, reached, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 1, 2 * r + 1)));
  v->slots.resize(static_cast<size_t>(w) * h);
  uint32_t next = 0;
  for (int y = 0; y < h; ++y) {
    const uint8_t* row = reached.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) v->slots[static_cast<size_t>(y) * w + x] = row[x] != 0 ? next++ : CostVolume::kNotStored;
  }
  v->flat.assign(v->stride, kOutsideCost);
  return next;
}

}  // namespace

VolumeWork BuildCostVolume(const cv::Mat& ref, const std::vector<Neighbour>& neighbours, const EngineOptions& o,
                           CostVolume* volume, const PlaneRanges* ranges, const std::vector<uint64_t>* reference_census,
                           cv::Point origin) {
  const int w = ref.cols, h = ref.rows;
  const int planes = static_cast<int>(neighbours.front().homographies.size());
  const int nn = static_cast<int>(neighbours.size());
  volume->width = w;
  volume->height = h;
  volume->planes = planes;
  volume->stride = RoundUp16(planes);
  volume->unmatched.clear();  // every pixel, unless the plane ranges leave some out
  size_t stored = static_cast<size_t>(w) * h;
  if (o.cost == Cost::kCensus && ranges != nullptr && FlatCurveSurvivesTheBox(o.window_radius)) {
    stored = LeaveOutFarUnmatched(*ranges, o.window_radius, volume);
  } else {
    volume->slots.clear();
    volume->flat.clear();
  }
  volume->data.resize(stored * volume->stride);
  if (volume->stride > planes) {
    tbb::parallel_for(0, h, [&](int y) {
      for (int x = 0; x < w; ++x) {
        if (volume->Stored(static_cast<size_t>(y) * w + x)) std::fill(volume->At(x, y) + planes, volume->At(x, y) + volume->stride, kMaxCost);
      }
    });
  }

  std::vector<uint64_t> ref_census;  // when not given
  std::vector<std::vector<uint64_t>> own_census(nn);
  std::vector<const std::vector<uint64_t>*> src_census(nn);
  cv::Mat ref_mean, ref_var;
  const size_t pixels = static_cast<size_t>(w) * h;
  if (o.cost == Cost::kCensus) {
    if (reference_census == nullptr || reference_census->size() != pixels) {
      ref_census = CensusTransform(ref, o.census_radius_x, o.census_radius_y);
      reference_census = &ref_census;
    }
    for (int i = 0; i < nn; ++i) {
      const std::vector<uint64_t>* given = neighbours[i].census.get();
      if (given != nullptr && given->size() == static_cast<size_t>(neighbours[i].gray.cols) * neighbours[i].gray.rows) {
        src_census[i] = given;
      } else {
        own_census[i] = CensusTransform(neighbours[i].gray, o.census_radius_x, o.census_radius_y);
        src_census[i] = &own_census[i];
      }
    }
  } else if (o.cost == Cost::kZncc) {
    cv::Mat f;
    ref.convertTo(f, CV_32F);
    const cv::Size k(2 * o.window_radius + 1, 2 * o.window_radius + 1);
    cv::boxFilter(f, ref_mean, CV_32F, k, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
    cv::boxFilter(f.mul(f), ref_var, CV_32F, k, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
    ref_var -= ref_mean.mul(ref_mean);
  }
  const int k = std::min(o.best_k, nn);
  if (o.cost == Cost::kCensus) {
    VolumeWork work = BuildCensusVolume(*reference_census, src_census, neighbours, k, o.census_sampling, ranges, origin, volume);
    work.box_filter_seconds = BoxFilterVolume(volume, o.window_radius);
    return work;
  }
  tbb::enumerable_thread_specific<PlaneScratch> scratch;
  TaskSeconds seconds;
  tbb::parallel_for(tbb::blocked_range<int>(0, planes, 1), [&](const tbb::blocked_range<int>& range) {
    const TaskSeconds::Scope timed(&seconds);
    PlaneScratch& s = scratch.local();
    s.slices.resize(nn);
    for (int p = range.begin(); p < range.end(); ++p) {
      for (int i = 0; i < nn; ++i) {
        s.slices[i].resize(static_cast<size_t>(w) * h);
        uint16_t* slice = s.slices[i].data();
        const Eigen::Matrix3d& hom = neighbours[i].homographies[p];
        if (o.cost == Cost::kSad) {
          SadSlice(ref, origin, neighbours[i].gray, hom, &s, slice);
          BoxMean(slice, w, h, o.window_radius, &s.row_sums);
        } else {
          ZnccSlice(ref, origin, ref_mean, ref_var, neighbours[i].gray, hom, o.window_radius, &s, slice);
        }
      }
      // Best-k combination over neighbours, written into the volume's plane p.
      const size_t n = static_cast<size_t>(w) * h;
      uint16_t* dst = volume->data.data() + p;
      const int stride = volume->stride;
      if (nn == 1) {
        const uint16_t* a = s.slices[0].data();
        for (size_t i = 0; i < n; ++i) dst[i * stride] = a[i];
      } else {
        uint16_t values[64];
        for (size_t i = 0; i < n; ++i) {
          for (int j = 0; j < nn; ++j) values[j] = s.slices[j][i];
          std::partial_sort(values, values + k, values + nn);
          uint32_t sum = 0;
          for (int j = 0; j < k; ++j) sum += values[j];
          dst[i * stride] = static_cast<uint16_t>(sum / k);
        }
      }
    }
  });
  if (ranges != nullptr) ApplyRanges(*ranges, volume);  // evaluated everywhere, then limited
  return {static_cast<int64_t>(planes) * w * h * nn, seconds.Total()};
}

void Aggregate(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, bool one_buffer, Aggregated* out) {
  Aggregated& result = *out;
  result.width = v.width;
  result.height = v.height;
  result.planes = v.planes;
  result.stride = v.stride;
  result.unmatched = v.unmatched;
  if (!o.semi_global) {
    if (v.slots.empty()) {
      result.a = v.data;
    } else {  // pixel-indexed, as WinnerTakeAll reads it
      result.a.resize(static_cast<size_t>(v.width) * v.height * v.stride);
      for (int y = 0; y < v.height; ++y) {
        for (int x = 0; x < v.width; ++x) {
          std::copy(v.At(x, y), v.At(x, y) + v.stride, result.a.data() + (static_cast<size_t>(y) * v.width + x) * v.stride);
        }
      }
    }
    result.b.clear();
    return;
  }
  if (one_buffer) {
    SgmPass(v, gray, o, +1, false, false, &result.a);
    SgmPass(v, gray, o, -1, true, false, &result.a);
    LargeBuffer<uint16_t>().swap(result.b);  // pages a concurrent call may have left
    return;
  }
  tbb::parallel_invoke([&] { SgmPass(v, gray, o, +1, false, false, &result.a); },
                      [&] { SgmPass(v, gray, o, -1, false, false, &result.b); });
}

Winners WinnerTakeAll(const Aggregated& ag, const CostVolume* data, const CertaintyOptions& certainty, bool right_winners) {
  const int w = ag.width, h = ag.height, np = ag.planes, stride = ag.stride;
  Winners out;
  out.plane = cv::Mat(h, w, CV_32F, cv::Scalar(-1));
  out.confidence = cv::Mat(h, w, CV_32F, cv::Scalar(0));
  out.margin = cv::Mat(h, w, CV_32F, cv::Scalar(0));
  if (right_winners) out.right = cv::Mat(h, w, CV_32S, cv::Scalar(-1));
  // 0xFFFF at the padding planes, to OR into their sums.
  std::vector<uint16_t> padding(stride, 0);
  std::fill(padding.begin() + np, padding.end(), static_cast<uint16_t>(0xFFFF));
  tbb::parallel_for(0, h, [&](int y) {
    std::vector<uint16_t> s(stride);
    // Right-view winners of this row, stored right to left: left pixel x at disparity d is right
    // pixel x - d, entry w - 1 - x + d, so a left pixel's disparities update a contiguous run.
    std::vector<uint32_t> right_cost(right_winners ? w : 0, 0xFFFFFFFFu);
    std::vector<int32_t> right_disparity(right_winners ? w : 0, -1);
    float* plane = out.plane.ptr<float>(y);
    float* conf = out.confidence.ptr<float>(y);
    float* margin = out.margin.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const size_t pixel = static_cast<size_t>(y) * w + x;
      if (!ag.Matched(pixel)) continue;  // no winner, certainty 0
      const uint16_t* a = ag.a.data() + pixel * stride;
      // The sum (padding planes at 0xFFFF) and its minimum, a vector at a time.
      UnsignedLanes low = UnsignedLanes{} + static_cast<uint16_t>(0xFFFF);
      for (int d = 0; d < stride; d += kLaneCount) {
        UnsignedLanes sum = reinterpret_cast<UnsignedLanes>(LoadLanes<Lanes>(a + d));
        if (!ag.b.empty()) sum += reinterpret_cast<UnsignedLanes>(LoadLanes<Lanes>(ag.b.data() + pixel * stride + d));
        if (d + kLaneCount > np) sum |= reinterpret_cast<UnsignedLanes>(LoadLanes<Lanes>(padding.data() + d));
        StoreLanes(s.data() + d, reinterpret_cast<Lanes>(sum));
        low = low < sum ? low : sum;
      }
      if (right_winners) {
        // Left pixels come in increasing x, so a right pixel sees its disparities in increasing
        // order: a strict < keeps the smallest among equal costs.
        uint32_t* cost = right_cost.data() + (w - 1 - x);
        int32_t* disparity = right_disparity.data() + (w - 1 - x);
        const int count = std::min(np, x + 1);
        for (int d = 0; d < count; ++d) {
          const uint32_t value = s[d];
          const bool better = value < cost[d];
          cost[d] = better ? value : cost[d];
          disparity[d] = better ? d : disparity[d];
        }
      }
      WinnerOf(s.data(), LowestUnsignedLane(low), np, data == nullptr ? nullptr : data->At(x, y), certainty, plane + x,
               conf + x, margin + x);
    }
    if (right_winners) {
      int* right = out.right.ptr<int>(y);
      for (int x = 0; x < w; ++x) right[x] = right_disparity[w - 1 - x];
    }
  });
  return out;
}

Winners AggregateAndPick(const CostVolume& v, const cv::Mat& gray, const EngineOptions& o, const CertaintyOptions& certainty,
                         LargeBuffer<uint16_t>* sums) {
  Winners out;
  out.plane = cv::Mat(v.height, v.width, CV_32F, cv::Scalar(-1));
  out.confidence = cv::Mat(v.height, v.width, CV_32F, cv::Scalar(0));
  out.margin = cv::Mat(v.height, v.width, CV_32F, cv::Scalar(0));
  const PickTarget pick{out.plane.ptr<float>(), out.confidence.ptr<float>(), out.margin.ptr<float>(), certainty};
  if (!o.semi_global) {  // the (box-filtered) costs are the sums: picked from the volume itself
    sums->clear();       // not used (its capacity stays in the pool)
    tbb::parallel_for(0, v.height, [&](int y) {
      std::vector<uint16_t> s(v.stride);
      for (int x = 0; x < v.width; ++x) {
        const size_t pixel = static_cast<size_t>(y) * v.width + x;
        if (!v.Matched(pixel)) continue;
        std::copy(v.At(x, y), v.At(x, y) + v.stride, s.begin());
        pick.Pick(s.data(), v.planes, v.stride, v.At(x, y), pixel);
      }
    });
    return out;
  }
  SgmPass(v, gray, o, +1, false, true, sums);  // the matched pixels' sums only (SumSlots)
  SgmPass(v, gray, o, -1, true, true, sums, &pick);
  return out;
}

}  // namespace IBMR_SWEEP_ISA
}  // namespace sweep
}  // namespace ibmr

#if IBMR_SWEEP_AVX512 || IBMR_SWEEP_AVX2
#pragma GCC pop_options
#endif
