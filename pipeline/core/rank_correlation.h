// Spearman's rank correlation: how well one quantity orders samples the way another does. The
// stability matrix asks whether a method's confidence falls where its error rises, sample by
// sample (depth pixels, fused points, particles): a good confidence measure has a strongly
// negative correlation with the error. Ranks, not values, so any monotone confidence scale works.
#pragma once

#include <vector>

namespace ibmr {

// Spearman's rho of (a[i], b[i]): the Pearson correlation of their ranks, tied values getting the
// mean of their ranks; pairs with a non-finite value are left out. NaN when fewer than 3 pairs
// remain or either side is constant.
double SpearmanCorrelation(const std::vector<double>& a, const std::vector<double>& b);

}  // namespace ibmr
