// COLMAP's dense array format (dense/stereo/depth_maps/*.bin, normal_maps/*.bin): an ASCII
// header "WIDTH&HEIGHT&CHANNELS&" followed by float32 little-endian values, channel-planar (all
// of channel 0 row-major from the top row, then channel 1, ...). `colmap stereo_fusion` reads it.
#pragma once

#include <string>

#include "pipeline/core/float_map.h"

namespace ibmr {

FloatMap ReadColmapArray(const std::string& path);               // throws IoError
void WriteColmapArray(const std::string& path, const FloatMap& map);  // atomic

// A map that goes with `depth` (a normal or confidence map): empty when `path` does not exist;
// throws InputError naming the file when it is not depth.width x depth.height x `channels`.
FloatMap ReadColmapArrayMatching(const std::string& path, const FloatMap& depth, int channels);

}  // namespace ibmr
