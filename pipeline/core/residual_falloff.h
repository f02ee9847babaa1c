// A confidence factor from residuals measured against a local fit, scaled by their own median:
// the surface factors of multi_depth (a pixel's depth against the plane through its window) and
// fuse (a point against the plane through its nearest points) share it.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

namespace ibmr {

// Per residual r: floor + (1 - floor) exp(-(r / sigma)^2 / 2), sigma = scale * max(least, the upper
// median of the judged residuals). A negative residual means "not judged": its factor is 1. All 1
// when none is judged.
inline std::vector<float> ResidualFalloff(const std::vector<double>& residuals, double scale, double least, double floor) {
  std::vector<float> factors(residuals.size(), 1.f);
  std::vector<double> judged;
  judged.reserve(residuals.size());
  for (double r : residuals) {
    if (r >= 0) judged.push_back(r);
  }
  if (judged.empty()) return factors;
  std::nth_element(judged.begin(), judged.begin() + judged.size() / 2, judged.end());
  const double sigma = scale * std::max(least, judged[judged.size() / 2]);
  for (size_t i = 0; i < residuals.size(); ++i) {
    if (residuals[i] < 0) continue;
    const double t = residuals[i] / sigma;
    factors[i] = static_cast<float>(floor + (1 - floor) * std::exp(-0.5 * t * t));
  }
  return factors;
}

}  // namespace ibmr
