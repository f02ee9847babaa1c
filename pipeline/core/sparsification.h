// Sparsification curves of a confidence measure (Hu & Mordohai, "A quantitative evaluation of
// confidence measures for stereo vision", PAMI 2012, section 3: the error of the kept samples as
// the least confident are removed, and its area; Ilg et al. ECCV 2018 plot the same with the mean
// error). The optimal curve removes the samples by their true error, largest first, so its area
// is the least any confidence can reach; the area relative to it (>= 1) says how far a confidence
// is from ordering the samples as their errors do: 1 is perfect, a confidence that knows nothing
// (random, or constant) scores the mean error over the optimal area. Used beside Spearman's rho in
// the stability matrix (depth pixels, fused points, particles).
#pragma once

#include <vector>

namespace ibmr {

// Number of removal fractions a curve is sampled at: 0, 1/k, ..., (k-1)/k of the samples removed.
inline constexpr int kSparsificationSteps = 20;

struct Sparsification {
  std::vector<double> by_confidence;  // mean error of the kept samples at each removal fraction
  std::vector<double> optimal;        // the same, removing by true error (largest first)
  double auc = 0;                     // mean of by_confidence (the area over removal fractions [0, 1))
  double optimal_auc = 0;             // mean of optimal
  // auc / optimal_auc (>= 1; NaN when the optimal area is 0 or there are fewer than
  // kSparsificationSteps samples).
  double AucRatio() const;
};

// The curves of (confidence[i], error[i]), errors >= 0; pairs with a non-finite value are left
// out. Samples of equal confidence are removed together: where a removal fraction splits a group
// of ties, the kept part of the group counts with the group's mean error (a constant confidence
// gives the flat curve at the mean error, not one favoured by the samples' order).
Sparsification SparsificationCurves(const std::vector<double>& confidence, const std::vector<double>& error);

// SparsificationCurves(confidence, error).AucRatio().
double SparsificationAucRatio(const std::vector<double>& confidence, const std::vector<double>& error);

}  // namespace ibmr
