// Spearman's rank correlation with mean ranks for ties (see rank_correlation.h).
#include "pipeline/core/rank_correlation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace ibmr {

namespace {

std::vector<double> Ranks(const std::vector<double>& values) {
  std::vector<size_t> order(values.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](size_t i, size_t j) { return values[i] < values[j]; });
  std::vector<double> ranks(values.size());
  for (size_t start = 0; start < order.size();) {
    size_t end = start + 1;
    while (end < order.size() && values[order[end]] == values[order[start]]) ++end;
    const double mean_rank = 0.5 * static_cast<double>(start + end - 1);
    for (size_t k = start; k < end; ++k) ranks[order[k]] = mean_rank;
    start = end;
  }
  return ranks;
}

}  // namespace

double SpearmanCorrelation(const std::vector<double>& all_a, const std::vector<double>& all_b) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  if (all_a.size() != all_b.size()) return nan;
  // Pairs with a non-finite side are left out (a NaN would break the sort's ordering).
  std::vector<double> a, b;
  a.reserve(all_a.size());
  b.reserve(all_b.size());
  for (size_t i = 0; i < all_a.size(); ++i) {
    if (!std::isfinite(all_a[i]) || !std::isfinite(all_b[i])) continue;
    a.push_back(all_a[i]);
    b.push_back(all_b[i]);
  }
  if (a.size() < 3) return nan;
  const std::vector<double> ra = Ranks(a), rb = Ranks(b);
  const double mean = 0.5 * static_cast<double>(a.size() - 1);
  double cov = 0, va = 0, vb = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    cov += (ra[i] - mean) * (rb[i] - mean);
    va += (ra[i] - mean) * (ra[i] - mean);
    vb += (rb[i] - mean) * (rb[i] - mean);
  }
  if (va == 0 || vb == 0) return nan;
  return cov / std::sqrt(va * vb);
}

}  // namespace ibmr
