// libFuzzer harness: YAML configs with their validation against every built-in stage's
// parameters (LoadConfig: unknown keys, types, ranges, variables), and one --set override.
#include <exception>

#include "pipeline/runner/builtin_stages.h"
#include "pipeline/runner/config.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const ibmr::StageRegistry* registry = [] {
    auto* r = new ibmr::StageRegistry();
    ibmr::RegisterBuiltinStages(r);
    return r;
  }();
  const std::string path = ibmr::fuzz::WriteInput("config.yaml", data, size);
  try {
    ibmr::Config config = ibmr::LoadConfig(path, *registry);
    ibmr::ApplyOverride("render.k=3", *registry, &config);
  } catch (const std::exception&) {
  }
  return 0;
}
