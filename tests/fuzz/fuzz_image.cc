// libFuzzer harness: image decoding as the stages do it (ReadImageColor, ReadImageUnchanged: any
// format OpenCV's imread detects from the bytes).
//
// Debian's OpenCV and its codec libraries carry no coverage instrumentation, so libFuzzer sees only
// image_io.cc and would keep almost no input. What each read gives back (the type, channel count
// and size class of the image, or the error) is therefore handed to libFuzzer as extra features
// (its __libfuzzer_extra_counters section): an input that decodes to something new is kept.
#include <cstdint>
#include <exception>
#include <functional>
#include <string>

#include "pipeline/core/image_io.h"
#include "tests/fuzz/fuzz_input_file.h"

namespace {

__attribute__((used, section("__libfuzzer_extra_counters"))) uint8_t outcomes[4096];

int SizeClass(int n) { return n <= 0 ? 0 : 32 - __builtin_clz(static_cast<unsigned>(n)); }

void Note(int read, const cv::Mat& image) {
  const size_t h = std::hash<std::string>()(std::to_string(read) + ":" + std::to_string(image.type()) + ":" +
                                            std::to_string(SizeClass(image.cols)) + ":" + std::to_string(SizeClass(image.rows)));
  outcomes[h % sizeof(outcomes)] = 1;
}

void Note(int read, const std::exception& error) {
  outcomes[std::hash<std::string>()(std::to_string(read) + error.what()) % sizeof(outcomes)] = 1;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ibmr::fuzz::WriteInput("input.img", data, size);
  try {
    Note(0, ibmr::ReadImageColor(path));
  } catch (const std::exception& e) {
    Note(0, e);
  }
  try {
    Note(1, ibmr::ReadImageUnchanged(path));
  } catch (const std::exception& e) {
    Note(1, e);
  }
  return 0;
}
