// A scratch folder for a test: under the system's temp directory, named by the caller and the
// process, emptied when made and removed with its contents when the test program exits (set
// IBMR_KEEP_TEST_DIRS to keep them for a look after a failure). Each ctest entry is its own
// process, so repeated suites do not fill /tmp.
#pragma once

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

namespace ibmr_testing {

inline std::filesystem::path ScratchDir(const std::string& name) {
  struct RemovedAtExit {
    std::vector<std::filesystem::path> dirs;
    ~RemovedAtExit() {
      if (std::getenv("IBMR_KEEP_TEST_DIRS")) return;
      std::error_code ignored;
      for (const auto& dir : dirs) std::filesystem::remove_all(dir, ignored);
    }
  };
  static RemovedAtExit made;
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  made.dirs.push_back(dir);
  return dir;
}

}  // namespace ibmr_testing
