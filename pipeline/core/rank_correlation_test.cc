// Spearman's rho: +1 and -1 for monotone relations whatever their shape, about 0 for independent
// values, ties ranked by their mean (the textbook example), NaN where it is undefined.
#include "pipeline/core/rank_correlation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

namespace ibmr {
namespace {

TEST(SpearmanCorrelation, MonotoneRelationsAreOneOrMinusOne) {
  std::vector<double> x, up, down;
  for (int i = 0; i < 50; ++i) {
    x.push_back(i * 0.1);
    up.push_back(std::exp(i * 0.1));
    down.push_back(-i * i);
  }
  EXPECT_NEAR(SpearmanCorrelation(x, up), 1.0, 1e-12);
  EXPECT_NEAR(SpearmanCorrelation(x, down), -1.0, 1e-12);
}

TEST(SpearmanCorrelation, IndependentValuesAreNearZeroAndTiesGetMeanRanks) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<double> a, b;
  for (int i = 0; i < 20000; ++i) {
    a.push_back(u(rng));
    b.push_back(u(rng));
  }
  EXPECT_NEAR(SpearmanCorrelation(a, b), 0.0, 0.03);
  // Ties: ranks of {1, 2, 2, 3} are {0, 1.5, 1.5, 3}; of {1, 3, 2, 4} {0, 2, 1, 3}: rho = 0.9487.
  EXPECT_NEAR(SpearmanCorrelation({1, 2, 2, 3}, {1, 3, 2, 4}), 0.9486833, 1e-6);
}

TEST(SpearmanCorrelation, UndefinedCasesAreNaN) {
  EXPECT_TRUE(std::isnan(SpearmanCorrelation({1, 2}, {1, 2})));
  EXPECT_TRUE(std::isnan(SpearmanCorrelation({1, 1, 1}, {1, 2, 3})));
  EXPECT_TRUE(std::isnan(SpearmanCorrelation({1, 2, 3}, {1, 2})));
  const double inf = std::numeric_limits<double>::infinity(), nan = std::nan("");
  EXPECT_NEAR(SpearmanCorrelation({1, nan, 2, 3, inf}, {1, 5, 2, 3, 4}), 1.0, 1e-12);  // non-finite pairs left out
}

}  // namespace
}  // namespace ibmr
