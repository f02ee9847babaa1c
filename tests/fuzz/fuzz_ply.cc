// libFuzzer harness: PLY meshes and point clouds (ascii and binary; ply_io.h), as render, surfels
// and the mesh-accuracy command read them from users. Rejections (exceptions) are fine; crashes,
// sanitizer reports and hangs are not.
#include <exception>

#include "pipeline/core/ply_io.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ibmr::fuzz::WriteInput("input.ply", data, size);
  try {
    const ibmr::TriangleMesh mesh = ibmr::ReadMeshPly(path);
    (void)mesh.Validate();
  } catch (const std::exception&) {
  }
  try {
    (void)ibmr::ReadPointCloudPly(path);
  } catch (const std::exception&) {
  }
  return 0;
}
