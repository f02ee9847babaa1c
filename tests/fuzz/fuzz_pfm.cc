// libFuzzer harness: PFM float maps (Middlebury disparities, ground-truth depth).
#include <exception>

#include "pipeline/core/image_io.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ibmr::fuzz::WriteInput("input.pfm", data, size);
  try {
    (void)ibmr::ReadPfm(path);
  } catch (const std::exception&) {
  }
  return 0;
}
