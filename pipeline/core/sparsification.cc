// Sparsification curves and their area relative to the optimal one (see sparsification.h).
#include "pipeline/core/sparsification.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace ibmr {

namespace {

// Mean error of the first `keep` samples of `order` (best first), where `key[order[i]]` groups ties:
// a group that straddles the cut contributes its mean error per kept sample. `prefix[i]` is the
// error sum of order[0..i), `group_end[i]` the end of the tie group holding position i,
// `group_start[i]` its start.
double KeptMean(size_t keep, const std::vector<double>& prefix, const std::vector<size_t>& group_start,
                const std::vector<size_t>& group_end) {
  if (keep == 0) return 0;
  const size_t last = keep - 1;
  const size_t start = group_start[last], end = group_end[last];
  const double group_mean = (prefix[end] - prefix[start]) / static_cast<double>(end - start);
  const double sum = prefix[start] + group_mean * static_cast<double>(keep - start);
  return sum / static_cast<double>(keep);
}

// The curve of samples ranked by `key` (descending: kept first), ties grouped.
std::vector<double> Curve(const std::vector<double>& key, const std::vector<double>& error) {
  const size_t n = key.size();
  std::vector<size_t> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return key[a] > key[b]; });
  std::vector<double> prefix(n + 1, 0);
  for (size_t i = 0; i < n; ++i) prefix[i + 1] = prefix[i] + error[order[i]];
  std::vector<size_t> group_start(n), group_end(n);
  for (size_t start = 0; start < n;) {
    size_t end = start + 1;
    while (end < n && key[order[end]] == key[order[start]]) ++end;
    for (size_t k = start; k < end; ++k) group_start[k] = start, group_end[k] = end;
    start = end;
  }
  std::vector<double> curve(kSparsificationSteps);
  for (int step = 0; step < kSparsificationSteps; ++step) {
    const size_t removed = static_cast<size_t>(std::llround(static_cast<double>(n) * step / kSparsificationSteps));
    curve[step] = KeptMean(n - removed, prefix, group_start, group_end);
  }
  return curve;
}

double Mean(const std::vector<double>& v) {
  return v.empty() ? 0.0 : std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
}

}  // namespace

double Sparsification::AucRatio() const {
  if (by_confidence.empty() || !(optimal_auc > 0)) return std::numeric_limits<double>::quiet_NaN();
  return auc / optimal_auc;
}

Sparsification SparsificationCurves(const std::vector<double>& all_confidence, const std::vector<double>& all_error) {
  Sparsification result;
  if (all_confidence.size() != all_error.size()) return result;
  std::vector<double> confidence, error, negated_error;
  for (size_t i = 0; i < all_confidence.size(); ++i) {
    if (!std::isfinite(all_confidence[i]) || !std::isfinite(all_error[i])) continue;
    confidence.push_back(all_confidence[i]);
    error.push_back(all_error[i]);
    negated_error.push_back(-all_error[i]);  // the optimal ranking keeps the smallest errors first
  }
  if (confidence.size() < static_cast<size_t>(kSparsificationSteps)) return result;
  result.by_confidence = Curve(confidence, error);
  result.optimal = Curve(negated_error, error);
  result.auc = Mean(result.by_confidence);
  result.optimal_auc = Mean(result.optimal);
  return result;
}

double SparsificationAucRatio(const std::vector<double>& confidence, const std::vector<double>& error) {
  return SparsificationCurves(confidence, error).AucRatio();
}

}  // namespace ibmr
