// libFuzzer harness: LLFF poses_bounds.npy (import format llff), for three images at downscale 2.
#include <exception>
#include <string>

#include "pipeline/core/nerf_formats.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  try {
    (void)ibmr::ParsePosesBounds(bytes, "fuzz.npy", {"a.png", "b.png", "c.png"}, 2, nullptr);
  } catch (const std::exception&) {
  }
  return 0;
}
