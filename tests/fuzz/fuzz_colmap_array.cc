// libFuzzer harness: COLMAP dense arrays (depth, normal and confidence maps, .bin).
#include <exception>

#include "pipeline/core/colmap_array_io.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ibmr::fuzz::WriteInput("input.bin", data, size);
  try {
    const ibmr::FloatMap map = ibmr::ReadColmapArray(path);
    (void)ibmr::ReadColmapArrayMatching(path, map, map.channels);
  } catch (const std::exception&) {
  }
  return 0;
}
