// The median of a list of numbers, as the stages' records and the benchmarks report it.
#pragma once

#include <algorithm>
#include <vector>

namespace ibmr {

// The middle value, or the mean of the two middle values of an even count; 0 for an empty list.
// Takes its argument by value: the copy is sorted.
inline double Median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

}  // namespace ibmr
