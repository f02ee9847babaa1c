// The splat rasterizer's per-tile loops, forward and backward (see splat_tiles.h for the layout and
// splat_rasterizer.h for the method).
//
// Compiled once per instruction set (pipeline/core/CMakeLists.txt) into
// ibmr::splat_tiles::IBMR_SPLAT_ISA. The `#pragma GCC target` below (not -march on the command line)
// keeps the AVX code inside this file's own functions: inline and template code from headers
// (Eigen, OpenCV, std) stays compiled for the baseline, so the linker cannot hand an AVX-512 copy
// of it to the portable path.
//
// Every per-pixel step is written as a loop over the 16 pixels of a tile row, on arrays of floats
// and 32-bit integers only (one vector width throughout), with selects instead of branches, so that
// GCC vectorises it (-fopt-info-vec-optimized shows each row loop vectorised). What GCC 12 needs for
// that, each found with -fopt-info-vec-missed: -fno-trapping-math (CMakeLists.txt); comparisons
// combined with &, not &&; no select between comparisons (the tests are on raw, not on alpha =
// min(0.99, raw)); updates in place that are not conditional stores; the backward row loop's count
// of pixels taken. The results are the scalar definition's up to float rounding (the order of a
// few additions and multiplications, FMA contraction in the AVX builds, sums over pixels added per
// lane first) and ExpNonPositive's error.
#include "pipeline/core/splat_tiles.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "pipeline/core/splat_rasterizer.h"

#if IBMR_SPLAT_AVX512
#pragma GCC push_options
#pragma GCC target("avx2,fma,avx512f,avx512dq,avx512bw,avx512vl")
#elif IBMR_SPLAT_AVX2
#pragma GCC push_options
#pragma GCC target("avx2,fma")
#endif

#ifndef IBMR_SPLAT_ISA
#error "compile with -DIBMR_SPLAT_ISA=portable, avx2 or avx512 (see pipeline/core/CMakeLists.txt)"
#endif

namespace ibmr {
namespace splat_tiles {
namespace IBMR_SPLAT_ISA {
namespace {

constexpr int kRow = kSplatTile;                    // lanes: the pixels of one tile row
constexpr int kTilePixels = kSplatTile * kSplatTile;
constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 1e-4f;
// Stands for "this falloff is not evaluated" in the exponent comparisons (ExpNonPositive of its
// negative is 0): above any squared radius that passes a cut-off (at most extent_sigmas^2).
constexpr float kNotEvaluated = 1e38f;

// What every splat of a view shares.
struct ViewConstants {
  float cutoff = 0;          // squared radius (sigmas) past which the object-space falloff is not drawn
  float half_cutoff = 0;     // the same for the screen-space floor's exponent
  float inv_two_sigma2 = 0;  // 1 / (2 lowpass_sigma^2)
  // alpha = min(0.99, raw) is drawn where alpha >= min_alpha and alpha > 0: where raw >= min_raw
  // and raw > 0. (Tested on raw: GCC 12 cannot vectorise the selects between comparisons it makes
  // of the tests on alpha.)
  float min_raw = 0;
};

ViewConstants Constants(const SplatRasterOptions& options) {
  ViewConstants c;
  c.cutoff = SplatCutoffSquared(options);
  c.half_cutoff = 0.5f * c.cutoff;
  c.inv_two_sigma2 = 1.0f / (2.0f * options.lowpass_sigma * options.lowpass_sigma);
  c.min_raw = options.min_alpha <= kMaxAlpha ? options.min_alpha : std::numeric_limits<float>::infinity();
  return c;
}

// One splat as the row loops read it (its SplatTileRecord), with the tile rows and columns its
// footprint's box covers.
struct SplatInTile {
  float a00, a01, a02, a10, a11, a12, a20, a21, a22;
  float cx, cy, opacity;
  float red, green, blue;  // clamped at 0
  float view_depth;
  int bx0, bx1, by0, by1;  // tile-local, inclusive
};

SplatInTile Load(const SplatFrame& frame, uint32_t i, int px0, int py0, int w, int hgt) {
  SplatInTile s;
  const SplatTileRecord& r = frame.tile_record[i];
  s.a00 = r.inverse[0], s.a01 = r.inverse[1], s.a02 = r.inverse[2];
  s.a10 = r.inverse[3], s.a11 = r.inverse[4], s.a12 = r.inverse[5];
  s.a20 = r.inverse[6], s.a21 = r.inverse[7], s.a22 = r.inverse[8];
  s.cx = r.centre_x, s.cy = r.centre_y;
  s.opacity = r.opacity;
  s.red = r.colour[0], s.green = r.colour[1], s.blue = r.colour[2];
  s.view_depth = r.view_depth;
  const Eigen::Vector4i& box = frame.box[i];
  s.bx0 = std::max(box[0] - px0, 0), s.bx1 = std::min(box[2] - px0, w - 1);
  s.by0 = std::max(box[1] - py0, 0), s.by1 = std::min(box[3] - py0, hgt - 1);
  return s;
}

// Splats this many places ahead in a tile's list are fetched into the cache while the current one
// is drawn: each one is a miss otherwise (the lists are in depth order, the splats' memory in
// index order), and the misses, not the arithmetic, took most of the time.
constexpr int kPrefetchAhead = 8;

// The forward pass's counts of pixels still taking splats (per row and per tile) are redone every
// kRecountEvery splats, not after every row (a horizontal sum per row cost a quarter of the row
// loop): a row or the tile is left up to that many splats late, its pixels masked by their own
// flags meanwhile.
constexpr uint32_t kRecountEvery = 4;

// Where the backward pass keeps splat i's sums over tile `tile`: its entries, one per tile of its
// box in row-major order (SplatFrame::entry_start).
inline uint32_t EntryOf(const SplatFrame& frame, uint32_t i, int tile) {
  const Eigen::Vector4i& box = frame.box[i];
  const int bx0 = box[0] / kSplatTile, bx1 = box[2] / kSplatTile, by0 = box[1] / kSplatTile;
  const int tx = tile % frame.tiles_x, ty = tile / frame.tiles_x;
  return frame.entry_start[i] + static_cast<uint32_t>((ty - by0) * (bx1 - bx0 + 1) + (tx - bx0));
}

inline void Prefetch(const SplatFrame& frame, uint32_t i) {
  __builtin_prefetch(&frame.tile_record[i]);
  __builtin_prefetch(&frame.box[i]);
}

// The falloff of splat `s` at the 16 pixel centres (lane_x[l], y) of one row: G (0 where neither
// the disc nor the floor reaches), whether the disc's own value is the larger (object), and the
// disc coordinates u, v with 1 / w2 where it is. As splat_rasterizer.h defines it: G = max(exp(-(u^2
// + v^2) / 2) [w2 > 0, u^2 + v^2 < cutoff], exp(-|x - c|^2 / (2 sigma^2)) [that exponent < cutoff /
// 2]); the larger exponential is the one with the smaller exponent, so one exp a pixel.
struct RowFalloff {
  alignas(64) float g[kRow], u[kRow], v[kRow], inv_w2[kRow];
  alignas(64) int32_t object[kRow];
};

inline void EvaluateRow(const SplatInTile& s, const ViewConstants& view, const float* __restrict lane_x, float y,
                        RowFalloff* __restrict out) {
  const float b0 = s.a01 * y + s.a02, b1 = s.a11 * y + s.a12, b2 = s.a21 * y + s.a22;
  const float dy = y - s.cy, dy2 = dy * dy;
  for (int l = 0; l < kRow; ++l) {
    const float x = lane_x[l];
    const float w0 = s.a00 * x + b0, w1 = s.a10 * x + b1, w2 = s.a20 * x + b2;
    const float inv_w2 = 1.0f / w2;
    const float u = w0 * inv_w2, v = w1 * inv_w2;
    const float r2 = u * u + v * v;
    // Not evaluated behind the plane's horizon (w2 <= 0; u, v may be inf or NaN there: NaN fails
    // the comparison) nor past the cut-off. (Bitwise & on the comparisons, not &&: no branch.)
    const float disc_exponent = ((w2 > 0.0f) & (r2 < view.cutoff)) ? 0.5f * r2 : kNotEvaluated;
    const float dx = x - s.cx;
    const float d2 = (dx * dx + dy2) * view.inv_two_sigma2;
    const float floor_exponent = d2 < view.half_cutoff ? d2 : kNotEvaluated;
    const float exponent = std::min(disc_exponent, floor_exponent);
    out->g[l] = ExpNonPositive(-exponent);  // 0 where neither is evaluated
    // Where neither is evaluated this says "object" too, but g is 0 there and no pass uses it.
    out->object[l] = disc_exponent <= floor_exponent ? 1 : 0;
    out->u[l] = u;
    out->v[l] = v;
    out->inv_w2[l] = inv_w2;
  }
}

// Pixel geometry of a tile: lane l of row ly is pixel (px0 + l, py0 + ly), centred at + 0.5.
struct TileGeometry {
  int px0, py0, w, hgt;
  alignas(64) float lane_x[kRow];
  alignas(64) int32_t lane[kRow];
};

TileGeometry Geometry(const SplatFrame& frame, int tile) {
  TileGeometry g;
  g.px0 = (tile % frame.tiles_x) * kSplatTile;
  g.py0 = (tile / frame.tiles_x) * kSplatTile;
  g.w = std::min(kSplatTile, frame.width - g.px0);
  g.hgt = std::min(kSplatTile, frame.height - g.py0);
  for (int l = 0; l < kRow; ++l) {
    g.lane_x[l] = static_cast<float>(g.px0 + l) + 0.5f;
    g.lane[l] = l;
  }
  return g;
}

}  // namespace

void ForwardTile(SplatFrame& frame, int tile) {
  const ViewConstants view = Constants(frame.options);
  const TileGeometry geometry = Geometry(frame, tile);
  // The tile's pixels, row-major, lane = column. live: 1 while the pixel takes more splats (0
  // outside the image, or once a splat would have taken its transmittance below the cut-off).
  alignas(64) float transmit[kTilePixels], red[kTilePixels], green[kTilePixels], blue[kTilePixels];
  alignas(64) float depth[kTilePixels];
  alignas(64) int32_t live[kTilePixels], walked[kTilePixels];
  int row_live[kSplatTile];
  int live_total = 0;
  for (int ly = 0; ly < kSplatTile; ++ly) {
    row_live[ly] = 0;
    for (int l = 0; l < kRow; ++l) {
      const int p = ly * kRow + l;
      const bool inside = l < geometry.w && ly < geometry.hgt;
      transmit[p] = 1.0f;
      red[p] = green[p] = blue[p] = depth[p] = 0.0f;
      walked[p] = 0;
      live[p] = inside ? 1 : 0;
      row_live[ly] += inside;
    }
    live_total += row_live[ly];
  }
  RowFalloff falloff;
  const uint32_t start = frame.tile_start[tile], end = frame.tile_start[tile + 1];
  for (uint32_t j = start; j < end && live_total > 0; ++j) {
    if (j + kPrefetchAhead < end) Prefetch(frame, frame.tile_splats[j + kPrefetchAhead]);
    if ((j - start) % kRecountEvery == kRecountEvery - 1) {
      live_total = 0;
      for (int ly = 0; ly < kSplatTile; ++ly) {
        int count = 0;
        for (int l = 0; l < kRow; ++l) count += live[ly * kRow + l];
        row_live[ly] = count;
        live_total += count;
      }
      if (live_total == 0) break;
    }
    const SplatInTile s = Load(frame, frame.tile_splats[j], geometry.px0, geometry.py0, geometry.w, geometry.hgt);
    const int32_t index = static_cast<int32_t>(j - start + 1);
    for (int ly = s.by0; ly <= s.by1; ++ly) {
      if (row_live[ly] == 0) continue;
      const float y = static_cast<float>(geometry.py0 + ly) + 0.5f;
      EvaluateRow(s, view, geometry.lane_x, y, &falloff);
      float* __restrict row_transmit = transmit + ly * kRow;
      float* __restrict row_red = red + ly * kRow;
      float* __restrict row_green = green + ly * kRow;
      float* __restrict row_blue = blue + ly * kRow;
      float* __restrict row_depth = depth + ly * kRow;
      int32_t* __restrict row_live_lanes = live + ly * kRow;
      int32_t* __restrict row_walked = walked + ly * kRow;
      for (int l = 0; l < kRow; ++l) {
        const float raw = s.opacity * falloff.g[l];
        const float alpha = std::min(kMaxAlpha, raw);
        const bool in_box = (geometry.lane[l] >= s.bx0) & (geometry.lane[l] <= s.bx1);
        const bool taken = (row_live_lanes[l] != 0) & in_box & (raw >= view.min_raw) & (raw > 0.0f);
        const float t = row_transmit[l];
        const float next = t * (1.0f - alpha);
        // A splat that would take the transmittance below the cut-off ends the pixel unapplied.
        const bool ends = taken & (next < kMinTransmittance);
        const bool applied = taken & !ends;
        const float weight = applied ? alpha * t : 0.0f;
        row_red[l] += s.red * weight;
        row_green[l] += s.green * weight;
        row_blue[l] += s.blue * weight;
        // The updates in place are written as arithmetic that is exact where nothing changes (a
        // factor 1, an added 0, a max with a smaller index), not as selects GCC turns into
        // conditional stores, which the baseline instruction set cannot vectorise.
        const float hit_depth = falloff.object[l] != 0 ? falloff.inv_w2[l] : s.view_depth;
        const float depth_before = row_depth[l];
        row_depth[l] = depth_before + ((applied & (depth_before == 0.0f) & (raw >= 0.5f)) ? hit_depth : 0.0f);
        row_transmit[l] = t * (applied ? 1.0f - alpha : 1.0f);
        row_walked[l] = std::max(row_walked[l], applied ? index : 0);
        row_live_lanes[l] = std::min(row_live_lanes[l], ends ? 0 : 1);
      }
    }
  }
  const Eigen::Vector3f& background = frame.options.background;
  for (int ly = 0; ly < geometry.hgt; ++ly) {
    const int y = geometry.py0 + ly;
    cv::Vec3f* image = frame.image.ptr<cv::Vec3f>(y) + geometry.px0;
    float* transmittance = frame.transmittance.ptr<float>(y) + geometry.px0;
    float* depth_out = frame.depth.ptr<float>(y) + geometry.px0;
    uint32_t* last = frame.last.data() + static_cast<size_t>(y) * frame.width + geometry.px0;
    for (int l = 0; l < geometry.w; ++l) {
      const int p = ly * kRow + l;
      image[l] = cv::Vec3f(red[p] + transmit[p] * background[0], green[p] + transmit[p] * background[1],
                           blue[p] + transmit[p] * background[2]);
      transmittance[l] = transmit[p];
      depth_out[l] = depth[p];
      last[l] = static_cast<uint32_t>(walked[p]);
    }
  }
}

void BackwardTile(const SplatFrame& frame, const cv::Mat& d_image, int tile, ScreenGradientSums* entries) {
  const ViewConstants view = Constants(frame.options);
  const float inv_sigma2 = 2.0f * view.inv_two_sigma2;
  const TileGeometry geometry = Geometry(frame, tile);
  // The tile's pixels as the forward pass left them; walking back, transmit is recovered splat by
  // splat and behind is the colour of what lies behind the current splat (the background first).
  alignas(64) float transmit[kTilePixels], behind_red[kTilePixels], behind_green[kTilePixels], behind_blue[kTilePixels];
  alignas(64) float d_red[kTilePixels], d_green[kTilePixels], d_blue[kTilePixels];
  alignas(64) int32_t walked[kTilePixels];
  int32_t row_most[kSplatTile];  // the most splats any pixel of the row walked
  int32_t most = 0;
  const Eigen::Vector3f& background = frame.options.background;
  for (int ly = 0; ly < kSplatTile; ++ly) {
    row_most[ly] = 0;
    const int y = geometry.py0 + ly;
    for (int l = 0; l < kRow; ++l) {
      const int p = ly * kRow + l;
      const bool inside = l < geometry.w && ly < geometry.hgt;
      const int x = geometry.px0 + l;
      walked[p] = inside ? static_cast<int32_t>(frame.last[static_cast<size_t>(y) * frame.width + x]) : 0;
      transmit[p] = inside ? frame.transmittance.at<float>(y, x) : 1.0f;
      behind_red[p] = background[0], behind_green[p] = background[1], behind_blue[p] = background[2];
      const cv::Vec3f d = inside ? d_image.at<cv::Vec3f>(y, x) : cv::Vec3f(0, 0, 0);
      d_red[p] = d[0], d_green[p] = d[1], d_blue[p] = d[2];
      row_most[ly] = std::max(row_most[ly], walked[p]);
    }
    most = std::max(most, row_most[ly]);
  }
  RowFalloff falloff;
  // Per-lane sums over the splat's rows, added across lanes once per splat. The x factors of
  // d/d M^-1's first column and of the centre's x are applied then (x is fixed per lane).
  enum Sum { kW0, kW0y, kW1, kW1y, kW2, kW2y, kFloor, kFloorY, kRed, kGreen, kBlue, kOpacity, kSums };
  alignas(64) float lane_sums[kSums][kRow];
  const uint32_t start = frame.tile_start[tile];
  for (int32_t jj = most; jj-- > 0;) {
    if (jj >= kPrefetchAhead) {
      const uint32_t ahead = frame.tile_splats[start + jj - kPrefetchAhead];
      Prefetch(frame, ahead);
      __builtin_prefetch(&entries[EntryOf(frame, ahead, tile)], 1);
    }
    const uint32_t i = frame.tile_splats[start + jj];
    const SplatInTile s = Load(frame, i, geometry.px0, geometry.py0, geometry.w, geometry.hgt);
    for (int q = 0; q < kSums; ++q) {
      for (int l = 0; l < kRow; ++l) lane_sums[q][l] = 0.0f;
    }
    int touched = 0;
    for (int ly = s.by0; ly <= s.by1; ++ly) {
      if (jj >= row_most[ly]) continue;
      const float y = static_cast<float>(geometry.py0 + ly) + 0.5f;
      const float dy = y - s.cy;
      EvaluateRow(s, view, geometry.lane_x, y, &falloff);
      float* __restrict row_transmit = transmit + ly * kRow;
      float* __restrict row_behind_red = behind_red + ly * kRow;
      float* __restrict row_behind_green = behind_green + ly * kRow;
      float* __restrict row_behind_blue = behind_blue + ly * kRow;
      const float* __restrict row_d_red = d_red + ly * kRow;
      const float* __restrict row_d_green = d_green + ly * kRow;
      const float* __restrict row_d_blue = d_blue + ly * kRow;
      const int32_t* __restrict row_walked = walked + ly * kRow;
      // (Counting the pixels taken also keeps GCC 12's loop form vectorisable: without it the
      // loop is left with an exit block it does not if-convert.)
      int taken_count = 0;
      for (int l = 0; l < kRow; ++l) {
        const float g = falloff.g[l];
        const float raw = s.opacity * g;
        const float alpha = std::min(kMaxAlpha, raw);
        const bool in_box = (geometry.lane[l] >= s.bx0) & (geometry.lane[l] <= s.bx1);
        const bool taken = (jj < row_walked[l]) & in_box & (raw >= view.min_raw) & (raw > 0.0f);
        // The transmittance in front of this splat (alpha <= 0.99: no division by zero), exact where
        // the pixel is not taken (a factor 1, an added 0), as in the forward pass.
        const float t = row_transmit[l] / (taken ? 1.0f - alpha : 1.0f);
        row_transmit[l] = t;
        const float weight = taken ? alpha * t : 0.0f;
        lane_sums[kRed][l] += weight * row_d_red[l];
        lane_sums[kGreen][l] += weight * row_d_green[l];
        lane_sums[kBlue][l] += weight * row_d_blue[l];
        const float d_alpha = ((s.red - row_behind_red[l]) * row_d_red[l] + (s.green - row_behind_green[l]) * row_d_green[l] +
                               (s.blue - row_behind_blue[l]) * row_d_blue[l]) *
                              t;
        const float keep = taken ? 1.0f - alpha : 1.0f, cover = taken ? alpha : 0.0f;
        row_behind_red[l] = s.red * cover + row_behind_red[l] * keep;
        row_behind_green[l] = s.green * cover + row_behind_green[l] * keep;
        row_behind_blue[l] = s.blue * cover + row_behind_blue[l] * keep;
        // Clamped at the alpha cap: no gradient to the opacity or the footprint.
        const bool graded = taken & (raw < kMaxAlpha);
        lane_sums[kOpacity][l] += (graded ? d_alpha : 0.0f) * g;
        const float d_g = d_alpha * s.opacity;
        const bool object = graded & (falloff.object[l] != 0);
        const bool floor = graded & (falloff.object[l] == 0);
        // Through the disc: g = exp(-(u^2 + v^2) / 2), (u, v) = (w0, w1) / w2, w = M^-1 (x, y, 1).
        const float u = falloff.u[l], v = falloff.v[l], inv_w2 = falloff.inv_w2[l];
        const float du = -u * g * d_g, dv = -v * g * d_g;
        const float dw0 = object ? du * inv_w2 : 0.0f;
        const float dw1 = object ? dv * inv_w2 : 0.0f;
        const float dw2 = object ? -(du * u + dv * v) * inv_w2 : 0.0f;
        lane_sums[kW0][l] += dw0;
        lane_sums[kW0y][l] += dw0 * y;
        lane_sums[kW1][l] += dw1;
        lane_sums[kW1y][l] += dw1 * y;
        lane_sums[kW2][l] += dw2;
        lane_sums[kW2y][l] += dw2 * y;
        // Through the screen-space floor: d/d centre of exp(-|x - c|^2 / (2 sigma^2)).
        const float scale = floor ? d_g * g * inv_sigma2 : 0.0f;
        lane_sums[kFloor][l] += scale;
        lane_sums[kFloorY][l] += scale * dy;
        taken_count += taken ? 1 : 0;
      }
      touched += taken_count;
    }
    // A splat no pixel took adds nothing: its sums' cache line is left alone.
    if (touched == 0) {
      entries[EntryOf(frame, i, tile)] = ScreenGradientSums{};  // no pixel of this tile took it
      continue;
    }
    // Summed over lanes as a tree of vector additions (a scalar loop of 15 x 16 additions a splat
    // would cost as much as the rows).
    alignas(64) float lane_g[kScreenGradients][kRow];
    for (int l = 0; l < kRow; ++l) {
      const float x = geometry.lane_x[l];
      lane_g[0][l] = lane_sums[kW0][l] * x, lane_g[1][l] = lane_sums[kW0y][l], lane_g[2][l] = lane_sums[kW0][l];
      lane_g[3][l] = lane_sums[kW1][l] * x, lane_g[4][l] = lane_sums[kW1y][l], lane_g[5][l] = lane_sums[kW1][l];
      lane_g[6][l] = lane_sums[kW2][l] * x, lane_g[7][l] = lane_sums[kW2y][l], lane_g[8][l] = lane_sums[kW2][l];
      lane_g[9][l] = lane_sums[kFloor][l] * (x - s.cx), lane_g[10][l] = lane_sums[kFloorY][l];
      lane_g[11][l] = lane_sums[kRed][l], lane_g[12][l] = lane_sums[kGreen][l], lane_g[13][l] = lane_sums[kBlue][l];
      lane_g[14][l] = lane_sums[kOpacity][l];
    }
    for (int width = kRow / 2; width >= 1; width /= 2) {
      for (int q = 0; q < kScreenGradients; ++q) {
        for (int l = 0; l < width; ++l) lane_g[q][l] += lane_g[q][l + width];
      }
    }
    ScreenGradientSums& entry = entries[EntryOf(frame, i, tile)];
    for (int q = 0; q < kScreenGradients; ++q) entry.value[q] = lane_g[q][0];
  }
  // The splats behind every pixel's last: not reached from this tile.
  for (uint32_t j = start + static_cast<uint32_t>(most); j < frame.tile_start[tile + 1]; ++j) {
    entries[EntryOf(frame, frame.tile_splats[j], tile)] = ScreenGradientSums{};
  }
}

}  // namespace IBMR_SPLAT_ISA
}  // namespace splat_tiles
}  // namespace ibmr

#if IBMR_SPLAT_AVX512 || IBMR_SPLAT_AVX2
#pragma GCC pop_options
#endif
