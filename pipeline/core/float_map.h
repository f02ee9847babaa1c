// Dense per-pixel float arrays: depth maps (1 channel, z along the optical axis, not distance
// along the ray; <= 0 or non-finite means "no estimate"), confidence maps, normal maps (3 channels,
// camera frame). Storage is channel-planar like COLMAP's .bin arrays: all of channel 0 row-major
// from the top row, then channel 1, and so on.
#pragma once

#include <cstddef>
#include <vector>

namespace ibmr {

struct FloatMap {
  int width = 0;
  int height = 0;
  int channels = 1;
  std::vector<float> data;

  FloatMap() = default;
  FloatMap(int w, int h, int c = 1, float fill = 0.f)
      : width(w), height(h), channels(c), data(static_cast<size_t>(w) * h * c, fill) {}

  bool Empty() const { return data.empty(); }
  size_t Index(int x, int y, int c = 0) const {
    return (static_cast<size_t>(c) * height + y) * width + x;
  }
  float& At(int x, int y, int c = 0) { return data[Index(x, y, c)]; }
  float At(int x, int y, int c = 0) const { return data[Index(x, y, c)]; }
  float* Channel(int c) { return data.data() + static_cast<size_t>(c) * width * height; }
  const float* Channel(int c) const { return data.data() + static_cast<size_t>(c) * width * height; }
};

using DepthMap = FloatMap;  // 1 channel, z depth

inline bool IsValidDepth(float z) { return z > 0.f && z < 1e30f; }

// A confidence map's value as the stages weigh it: clamped to [0, 1], and 0 where it is not a
// number (std::clamp passes NaN through, and NaN then passes every `< threshold` test).
inline float UsableConfidence(float c) { return c > 0.f ? (c < 1.f ? c : 1.f) : 0.f; }

}  // namespace ibmr
