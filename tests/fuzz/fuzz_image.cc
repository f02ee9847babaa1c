// libFuzzer harness: image decoding as the stages do it (ReadImageColor, ReadImageUnchanged: any
// format OpenCV's imread detects from the bytes).
#include <exception>

#include "pipeline/core/image_io.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ibmr::fuzz::WriteInput("input.img", data, size);
  try {
    (void)ibmr::ReadImageColor(path);
  } catch (const std::exception&) {
  }
  try {
    (void)ibmr::ReadImageUnchanged(path);
  } catch (const std::exception&) {
  }
  return 0;
}
