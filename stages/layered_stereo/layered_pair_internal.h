// Small helpers shared by the files of the two-view layered method (layered_pair.h;
// disparity_planes.cc, layer_costs.cc, layer_labels.cc, layered_pair.cc): the steepest plane that
// plane fitting and the layer costs accept, a float minimum the compiler vectorises and a rounding
// without the library call. Internal to the layered_stereo stage; follows no seed-paper section.
#pragma once

#include <algorithm>

namespace ibmr {
namespace layered_internal {

// Steeper planes are not surfaces a stereo pair resolves (disparity gradient limit): rejected.
constexpr double kMaxGradient = 1.0;

// std::min by value: the compiler turns it into a vector min in loops (std::min returns a
// reference, whose select it does not if-convert).
inline float Min(float a, float b) { return b < a ? b : a; }

// std::lround without the library call (the baseline instruction set has no rounding instruction),
// saturated far beyond any image coordinate.
inline int RoundToInt(float v) {
  v = std::clamp(v, -1e9f, 1e9f);
  return static_cast<int>(v + (v >= 0.f ? 0.5f : -0.5f));
}

}  // namespace layered_internal
}  // namespace ibmr
