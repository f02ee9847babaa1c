// The polynomial arctangent stays within kAngleBound of std::atan2 over the upper half plane: a
// dense sweep of angles (both octant boundaries and the axes included) at several radii, and random
// pairs of very different magnitudes.
#include "stages/render/arc_tangent_bound.h"

#include <gtest/gtest.h>

#include <random>

namespace ibmr {
namespace {

TEST(ArcTangentBound, WithinTheBoundOverTheUpperHalfPlane) {
  double worst = 0;
  for (const double radius : {1e-300, 1e-8, 1.0, 3.7, 1e12}) {
    for (int i = 0; i <= 200000; ++i) {
      const double angle = M_PI * i / 200000;
      const double y = radius * std::sin(angle), x = radius * std::cos(angle);
      if (y < 0) continue;
      worst = std::max(worst, std::abs(ArcTangentBelowPi(y, x) - std::atan2(y, x)));
    }
  }
  std::mt19937_64 random(3);
  std::uniform_real_distribution<double> exponent(-30, 30), unit(-1, 1);
  for (int i = 0; i < 200000; ++i) {
    const double y = std::abs(unit(random)) * std::pow(10.0, exponent(random));
    const double x = unit(random) * std::pow(10.0, exponent(random));
    worst = std::max(worst, std::abs(ArcTangentBelowPi(y, x) - std::atan2(y, x)));
  }
  EXPECT_LT(worst, 1.2e-5);
  EXPECT_LT(worst, kAngleBound / 8);
  EXPECT_EQ(ArcTangentBelowPi(0, 0), 0.0);
  EXPECT_EQ(ArcTangentBelowPi(0, 5), 0.0);
  EXPECT_NEAR(ArcTangentBelowPi(0, -5), M_PI, 1e-15);
}

}  // namespace
}  // namespace ibmr
