// libFuzzer harness: the carve stage's hull/octree.bin (the project's own format, read back by
// carve's consumers).
#include <exception>
#include <string>

#include "stages/carve/carve.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  try {
    const ibmr::Octree octree = ibmr::DeserializeOctree(bytes);
    (void)ibmr::SerializeOctree(octree);
  } catch (const std::exception&) {
  }
  return 0;
}
