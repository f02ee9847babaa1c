// libFuzzer harness: Strecha .camera files (import).
#include <exception>
#include <string>

#include "stages/import/import.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  ibmr::Camera camera;
  ibmr::Rigid3d pose;
  try {
    ibmr::ParseStrechaCamera(text, "fuzz.camera", &camera, &pose);
  } catch (const std::exception&) {
  }
  return 0;
}
