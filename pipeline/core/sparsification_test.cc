// Sparsification: a confidence that orders samples as their errors do reaches the optimal area
// (ratio 1), a reversed one does worst, a constant one gives the flat curve at the mean error
// whatever the samples' order, and the ratio is undefined without enough samples or error.
#include "pipeline/core/sparsification.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace ibmr {
namespace {

std::vector<double> Errors(int n) {
  std::mt19937 rng(5);
  std::exponential_distribution<double> e(1.0);
  std::vector<double> error(n);
  for (double& x : error) x = e(rng);
  return error;
}

TEST(Sparsification, ConfidenceOrderedLikeTheErrorIsOptimal) {
  const std::vector<double> error = Errors(1000);
  std::vector<double> confidence;
  for (double e : error) confidence.push_back(std::exp(-e));  // any decreasing function
  const Sparsification s = SparsificationCurves(confidence, error);
  EXPECT_NEAR(s.AucRatio(), 1.0, 1e-12);
  // The optimal curve falls as samples are removed.
  for (size_t i = 1; i < s.optimal.size(); ++i) EXPECT_LE(s.optimal[i], s.optimal[i - 1] + 1e-12);
  EXPECT_NEAR(s.optimal[0], s.by_confidence[0], 1e-12);  // nothing removed: the mean error
}

TEST(Sparsification, ReversedConfidenceIsWorseThanConstant) {
  const std::vector<double> error = Errors(1000);
  std::vector<double> reversed(error.begin(), error.end()), constant(error.size(), 0.5);
  const double worst = SparsificationAucRatio(reversed, error);
  const double flat = SparsificationAucRatio(constant, error);
  EXPECT_GT(worst, flat);
  EXPECT_GT(flat, 1.5);
  // A constant confidence keeps the mean error at every fraction (ties removed together).
  const Sparsification s = SparsificationCurves(constant, error);
  for (double kept : s.by_confidence) EXPECT_NEAR(kept, s.by_confidence[0], 1e-9);
}

TEST(Sparsification, TiesDoNotFavourTheSamplesOrder) {
  // Errors sorted ascending with a constant confidence: a tie-breaking by position would look optimal.
  std::vector<double> error(100), confidence(100, 1.0);
  for (int i = 0; i < 100; ++i) error[i] = i;
  EXPECT_GT(SparsificationAucRatio(confidence, error), 1.5);
}

TEST(Sparsification, UndefinedWithoutSamplesOrError) {
  EXPECT_TRUE(std::isnan(SparsificationAucRatio({1, 2, 3}, {0.1, 0.2, 0.3})));
  EXPECT_TRUE(std::isnan(SparsificationAucRatio(std::vector<double>(50, 1), std::vector<double>(50, 0))));
  EXPECT_TRUE(std::isnan(SparsificationAucRatio({1, 2}, {1})));
  // Non-finite pairs are left out.
  std::vector<double> error = Errors(100), confidence(100);
  for (int i = 0; i < 100; ++i) confidence[i] = -error[i];
  confidence[3] = std::nan("");
  EXPECT_NEAR(SparsificationAucRatio(confidence, error), 1.0, 1e-12);
}

}  // namespace
}  // namespace ibmr
