// libFuzzer harness: a COLMAP text model (cameras.txt, images.txt, points3D.txt), as import and
// every stage read sparse/. The input holds the three files separated by lines "%%".
#include <exception>
#include <filesystem>

#include "pipeline/core/colmap_text_io.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const std::string folder = ibmr::fuzz::ScratchDir() + "/model";
  std::filesystem::create_directories(folder);
  const char* const names[] = {"model/cameras.txt", "model/images.txt", "model/points3D.txt"};
  size_t start = 0;
  for (int i = 0; i < 3; ++i) {
    size_t end = text.find("\n%%\n", start);
    if (end == std::string::npos || i == 2) end = text.size();
    const std::string part = start <= text.size() ? text.substr(start, end - start) : std::string();
    ibmr::fuzz::WriteInput(names[i], reinterpret_cast<const uint8_t*>(part.data()), part.size());
    start = end + 4;
  }
  try {
    (void)ibmr::ReadSparseModelText(folder);
  } catch (const std::exception&) {
  }
  return 0;
}
