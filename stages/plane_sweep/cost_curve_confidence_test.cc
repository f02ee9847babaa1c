// The cost-curve confidence measures on constructed curves: a single sharp minimum is confident
// by both, two equal minima (repetitive texture) are caught by the peak ratio but not by the
// margin, a flat curve (no texture) by both; the sweep's options reject a bad peak_ratio_scale
// naming the key.
#include "stages/plane_sweep/cost_curve_confidence.h"

#include <gtest/gtest.h>

#include <vector>

#include "stages/plane_sweep/plane_sweep.h"

namespace ibmr {
namespace {

constexpr int kPlanes = 64;

// A smooth curve at `high` with V-shaped dips of depth `high - low` and half width 4 at `minima`.
std::vector<uint16_t> Curve(const std::vector<int>& minima, uint16_t low, uint16_t high) {
  std::vector<uint16_t> c(kPlanes, high);
  for (int m : minima) {
    for (int d = 0; d < kPlanes; ++d) {
      const int distance = std::abs(d - m);
      if (distance < 4) c[d] = std::min<uint16_t>(c[d], static_cast<uint16_t>(low + (high - low) * distance / 4));
    }
  }
  return c;
}

TEST(CostCurveConfidence, SingleSharpMinimumIsConfidentByBoth) {
  const std::vector<uint16_t> c = Curve({20}, 100, 600);
  EXPECT_GT(sweep::MarginConfidence(c.data(), kPlanes, 20, 3.0), 0.9f);
  // The plateau at 600 is the best competitor: 1 - 100/600, times 2: 1.67, saturated near 1.
  EXPECT_GT(sweep::PeakRatioConfidence(c.data(), kPlanes, 20, 2.0), 0.9f);
  // A second, shallower dip: the ratio 1 - 100/500 = 0.8, scaled by 0.5: 0.4 (linear below 1/2).
  const std::vector<uint16_t> two = [] {
    std::vector<uint16_t> c = Curve({20}, 100, 600);
    c[45] = 500;
    return c;
  }();
  EXPECT_NEAR(sweep::PeakRatioConfidence(two.data(), kPlanes, 20, 0.5), 0.4f, 1e-6);
  // Above 1/2 the mapping keeps ordering instead of clipping: a deeper competitor scores lower.
  EXPECT_LT(sweep::PeakRatioConfidence(two.data(), kPlanes, 20, 2.0), sweep::PeakRatioConfidence(c.data(), kPlanes, 20, 2.0));
  EXPECT_LT(sweep::PeakRatioConfidence(c.data(), kPlanes, 20, 2.0), 1.f);
}

TEST(CostCurveConfidence, TwoEqualMinimaAreCaughtByThePeakRatioOnly) {
  const std::vector<uint16_t> c = Curve({15, 45}, 100, 600);
  // The margin sees a deep minimum either way: it cannot tell which of the two is right.
  EXPECT_GT(sweep::MarginConfidence(c.data(), kPlanes, 15, 3.0), 0.9f);
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(c.data(), kPlanes, 15, 2.0), 0.f);
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(c.data(), kPlanes, 45, 2.0), 0.f);
  sweep::CertaintyOptions both;
  both.peak_ratio_scale = 2.0;
  EXPECT_FLOAT_EQ(sweep::CurveConfidence(c.data(), c.data(), kPlanes, 15, both), 0.f);
  // The margin factor alone (what the sweep's confidence_threshold compares): a match exists.
  float margin = -1;
  EXPECT_FLOAT_EQ(sweep::CurveConfidence(c.data(), c.data(), kPlanes, 15, both, &margin), 0.f);
  EXPECT_FLOAT_EQ(margin, sweep::MarginConfidence(c.data(), kPlanes, 15, both.margin_scale));
  EXPECT_GT(margin, 0.9f);
  // Off: the certainty is the margin alone.
  EXPECT_GT(sweep::CurveConfidence(c.data(), c.data(), kPlanes, 15, sweep::CertaintyOptions{}), 0.9f);
  // A dip within the winner's own basin (two planes off) is not a competitor.
  std::vector<uint16_t> basin = Curve({20}, 100, 600);
  basin[22] = 100;
  basin[21] = 150;
  const std::vector<uint16_t> single = Curve({20}, 100, 600);
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(basin.data(), kPlanes, 20, 2.0),
                  sweep::PeakRatioConfidence(single.data(), kPlanes, 20, 2.0));
}

TEST(CostCurveConfidence, FlatCurveHasNoConfidence) {
  const std::vector<uint16_t> c(kPlanes, 400);
  EXPECT_FLOAT_EQ(sweep::MarginConfidence(c.data(), kPlanes, 10, 3.0), 0.f);
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(c.data(), kPlanes, 10, 2.0), 0.f);
  sweep::CertaintyOptions both;
  both.peak_ratio_scale = 2.0;
  EXPECT_FLOAT_EQ(sweep::CurveConfidence(c.data(), c.data(), kPlanes, 10, both), 0.f);
}

TEST(CostCurveConfidence, WinnerAPlaneOffItsDataMinimumKeepsItsPeak) {
  // The winner at 21, the curve's minimum at 20: c1 is the minimum's cost.
  const std::vector<uint16_t> c = Curve({20}, 100, 600);
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(c.data(), kPlanes, 21, 2.0), sweep::PeakRatioConfidence(c.data(), kPlanes, 20, 2.0));
  // A single basin without any other local minimum: 1.
  std::vector<uint16_t> v(kPlanes);
  for (int d = 0; d < kPlanes; ++d) v[d] = static_cast<uint16_t>(100 + 10 * std::abs(d - 20));
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(v.data(), kPlanes, 20, 2.0), 1.f);
  // A winner far from every minimum is beaten by one: 0.
  EXPECT_FLOAT_EQ(sweep::PeakRatioConfidence(c.data(), kPlanes, 50, 2.0), 0.f);
}

TEST(CostCurveConfidence, OptionsNameTheKey) {
  PlaneSweepOptions o;
  std::string error;
  EXPECT_TRUE(o.Check(&error)) << error;
  o.peak_ratio_scale = -1;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_NE(error.find("peak_ratio_scale"), std::string::npos) << error;
  o.peak_ratio_scale = 0;  // off
  EXPECT_TRUE(o.Check(&error)) << error;
}

}  // namespace
}  // namespace ibmr
