// libFuzzer harness: Middlebury multi-view _par.txt files (import). Every image is 640x480.
#include <exception>
#include <string>

#include "stages/import/import.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    (void)ibmr::ParseMiddleburyPar(text, "fuzz_par.txt", [](const std::string&) { return std::pair<int, int>(640, 480); });
  } catch (const std::exception&) {
  }
  return 0;
}
