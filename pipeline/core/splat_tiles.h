// The splat rasterizer's per-tile loops (splat_rasterizer.h), over a 16x16 tile's pixels as
// structure-of-arrays, one splat at a time, one tile row (16 lanes) per vectorised loop; and the
// exponential they evaluate the falloff with.
//
// splat_tiles.cc is compiled once per instruction set (pipeline/core/CMakeLists.txt), into
// namespace ibmr::splat_tiles::<isa>: `portable` (the build's baseline), and with GCC on x86-64
// `avx2` (AVX2 + FMA: 8 lanes) and `avx512` (AVX-512F/DQ/BW/VL: 16 lanes, a row per instruction).
// splat_rasterizer.cc calls the one ActiveIsa names. The row loops vectorise only as written (see
// splat_tiles.cc); after changing them, check with -fopt-info-vec-optimized.
#pragma once

#include <cstdint>
#include <cstring>
#include <opencv2/core.hpp>

#include "pipeline/core/cpu_isa.h"

namespace ibmr {

struct SplatFrame;

namespace splat_tiles {

// exp(x) for x <= 0, written to vectorise: Cody-Waite reduction x = n ln2 + r (|r| <= ln2 / 2,
// ln2 split in two so that n ln2 is exact to float precision), Cephes' expf polynomial for e^r
// (1 + r + r^2 P5(r), degree 7), and 2^n put straight into the exponent bits. Below -87 it is 0
// (exp(-87) = 1.6e-38 is near the smallest normal float; std::exp goes on through the denormals
// to -103.9: the only place the two differ by more than rounding). Relative error against double std::exp over [-87, 0]: at most
// 8.2e-8 measured (every float in [-20, 0] and 50M points over [-87, 0]), about 0.7 ulp;
// kExpMaxRelativeError is the bound splat_rasterizer_test holds it to.
inline constexpr float kExpMaxRelativeError = 1.2e-7f;

inline float ExpNonPositive(float x) {
  const bool underflows = x < -87.0f;
  x = underflows ? -87.0f : x;
  x = x > 0.0f ? 0.0f : x;
  // Round x / ln2 to the nearest integer by adding and subtracting 1.5 * 2^23 (exact in float
  // without -ffast-math; no SSE4.1 round instruction needed on the baseline).
  constexpr float kRound = 12582912.0f;
  const float n = (x * 1.44269504088896341f + kRound) - kRound;
  float r = x - n * 0.693359375f;
  r = r - n * -2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  const float e_r = p * (r * r) + r + 1.0f;
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float two_n;
  std::memcpy(&two_n, &bits, sizeof two_n);
  return underflows ? 0.0f : e_r * two_n;
}

using ::ibmr::Isa;  // pipeline/core/cpu_isa.h
using ::ibmr::IsaName;

// The instruction sets this build has tile loops for and this CPU runs; IBMR_ISA=portable (or
// avx2) in the environment starts on that one where the CPU runs it (to compare them).
bool IsaSupported(Isa isa);
Isa ActiveIsa();
bool SetIsa(Isa isa);  // false (and unchanged) where unsupported

// The gradient sums of one splat over one tile's pixels, which the backward pass writes per splat
// and tile of its box (SplatFrame::entry_start): d/d M^-1 row-major (9), d/d the projected centre (2), d/d colour (3), d/d
// opacity (1); one cache line an entry. Summed per splat afterwards in tile order, so that
// the gradients do not depend on which thread drew which tile (a fit gives the same bytes run
// after run, as sharded runs must).
inline constexpr int kScreenGradients = 15;
struct alignas(64) ScreenGradientSums {
  float value[16] = {};  // kScreenGradients used
};

#define IBMR_SPLAT_TILE_DECLARATIONS                                                                         \
  /* Composites tile `tile` of `frame` front to back into its image, transmittance, depth and last. */      \
  void ForwardTile(SplatFrame& frame, int tile);                                                           \
  /* Walks tile `tile`'s list back to front, writing each splat's entry for the tile (entry_start). */ \
  void BackwardTile(const SplatFrame& frame, const cv::Mat& d_image, int tile, ScreenGradientSums* entries);

namespace portable {
IBMR_SPLAT_TILE_DECLARATIONS
}  // namespace portable
namespace avx2 {
IBMR_SPLAT_TILE_DECLARATIONS
}  // namespace avx2
namespace avx512 {
IBMR_SPLAT_TILE_DECLARATIONS
}  // namespace avx512
#undef IBMR_SPLAT_TILE_DECLARATIONS

// The active build's.
void ForwardTile(SplatFrame& frame, int tile);
void BackwardTile(const SplatFrame& frame, const cv::Mat& d_image, int tile, ScreenGradientSums* entries);

}  // namespace splat_tiles
}  // namespace ibmr
