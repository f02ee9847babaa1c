// Confidence of a stereo match from its matching-cost curve (one cost per plane at a pixel; 0 is a
// perfect match, about 1000 the worst, sweep_engine.h), after Hu & Mordohai, "A quantitative
// evaluation of confidence measures for stereo vision" (PAMI 2012), section 2:
//  * the margin (their "matching score" family, as the certainty of seed 000 lines 5300-5525): how
//    far the winner's cost lies below the curve's mean; 0 on a flat curve (untextured surfaces) and
//    where the winner matches no better than a random plane (occlusion);
//  * the peak ratio (their PKR, section 2.3: the second-smallest local minimum c2m over the
//    minimum c1): 1 - c1 / c2m, 0 where another plane, away from the winner, matches about as well
//    (repetitive texture, where a wrong match is as cheap as the right one), 1 where no other
//    local minimum competes.
// Both are pure functions of the curve; the sweep's certainty (WinnerOf in sweep_kernels.cc) is
// their product, so either failure lowers it. Header-only and inline: evaluated once per pixel in
// the winner search.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace ibmr {
namespace sweep {

// Scales of the certainty's factors (PlaneSweepOptions carries them).
struct CertaintyOptions {
  double margin_scale = 3.0;      // margin factor = Saturate(scale * (mean - winner) / mean); > 0
  double peak_ratio_scale = 0.0;  // peak factor = Saturate(scale * (1 - c1 / c2m)); 0: off
};

// A measure's value x (scaled) mapped to [0, 1): x up to 1/2 (0 below 0), then 1 - exp(1 - 2x) / 2,
// which continues it with the same slope and never reaches 1. Below 1/2 it is the clipped value the
// confidence threshold always compared with (the same depth maps at thresholds up to 1/2); above,
// it keeps ordering the pixels that clipping tied at 1 (the margin times 3 passes 1 at a margin of
// a third: most pixels of a textured scene), which hid the order of their errors from every use of
// the confidence downstream.
inline float Saturate(double x) {
  if (!(x > 0)) return 0.f;
  return static_cast<float>(x <= 0.5 ? x : 1.0 - 0.5 * std::exp(1.0 - 2.0 * x));
}

// Local minima closer than this to the winner (in planes) belong to its own basin, not a competitor.
constexpr int kPeakExclusionPlanes = 2;

// The margin factor of `curve` (np costs) at plane `best`: Saturate((mean - curve[best]) / mean
// times `scale`) (a mean below 1 counts as 1).
inline float MarginConfidence(const uint16_t* curve, int np, int best, double scale) {
  uint32_t total = 0;
  for (int d = 0; d < np; ++d) total += curve[d];
  const float mean = static_cast<float>(total) / static_cast<float>(np);
  const float margin = (mean - static_cast<float>(curve[best])) / std::max(1.f, mean);
  return Saturate(margin * scale);
}

// The peak-ratio factor of `curve` at plane `best`: c1 is the lowest cost within one plane of
// `best` (the winner of an aggregated curve may sit a plane off its data cost's minimum), c2m the
// lowest local minimum (a plane no costlier than both neighbours; the ends count against their one
// neighbour) more than kPeakExclusionPlanes from `best`. Saturate((1 - c1 / c2m) times `scale`)
// (0 when c2m <= c1); 1 when no such minimum exists (a single basin). A flat curve has a
// competitor at every plane: 0.
inline float PeakRatioConfidence(const uint16_t* curve, int np, int best, double scale) {
  uint16_t c1 = curve[best];
  if (best > 0) c1 = std::min(c1, curve[best - 1]);
  if (best + 1 < np) c1 = std::min(c1, curve[best + 1]);
  uint32_t c2 = 0xFFFFFFFFu;
  for (int d = 0; d < np; ++d) {
    if (d >= best - kPeakExclusionPlanes && d <= best + kPeakExclusionPlanes) continue;
    const uint16_t c = curve[d];
    if (c >= c2) continue;
    const bool below_left = d == 0 || c <= curve[d - 1];
    const bool below_right = d + 1 == np || c <= curve[d + 1];
    if (below_left && below_right) c2 = c;
  }
  if (c2 == 0xFFFFFFFFu) return 1.f;
  if (c2 <= c1) return 0.f;
  const double ratio = 1.0 - static_cast<double>(c1) / static_cast<double>(c2);
  return Saturate(ratio * scale);
}

// The certainty of the match at plane `best`, the minimum of the aggregated curve `aggregated`:
// the margin factor of the matching cost `data` times, when enabled, the peak-ratio factor of the
// aggregated curve (after the smoothness term a second minimum is an ambiguity the aggregation
// did not resolve; on the raw matching cost, which the aggregation overrules where it is noisy,
// most pixels of a noisy or repetitive scene have one). `margin`, when not null, receives the
// margin factor alone: whether there is a match at all (the sweep's confidence_threshold compares
// it), apart from whether it is ambiguous.
inline float CurveConfidence(const uint16_t* data, const uint16_t* aggregated, int np, int best,
                             const CertaintyOptions& options, float* margin = nullptr) {
  float confidence = MarginConfidence(data, np, best, options.margin_scale);
  if (margin != nullptr) *margin = confidence;
  if (options.peak_ratio_scale > 0 && confidence > 0) {
    confidence *= PeakRatioConfidence(aggregated, np, best, options.peak_ratio_scale);
  }
  return confidence;
}

}  // namespace sweep
}  // namespace ibmr
