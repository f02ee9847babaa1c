// libFuzzer harness: nerfstudio / instant-ngp / Blender transforms.json (import format transforms).
#include <exception>
#include <string>

#include "pipeline/core/nerf_formats.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> names;
  try {
    const ibmr::SparseModel model = ibmr::ParseTransformsJson(
        text, "fuzz.json", [](const std::string&) { return std::pair<int, int>(64, 48); }, &names);
    (void)ibmr::WriteTransformsJson(model, "images/");
  } catch (const std::exception&) {
  }
  return 0;
}
