// libFuzzer harness: stage records (records/<stage>.json), which decide what is stale on resume.
#include <exception>

#include "pipeline/runner/record.h"
#include "tests/fuzz/fuzz_input_file.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = ibmr::fuzz::WriteInput("record.json", data, size);
  try {
    (void)ibmr::ReadRecord(path);
  } catch (const std::exception&) {
  }
  return 0;
}
