// Shared by the libFuzzer harnesses: the readers under test take paths, so each input is written
// to a file in a per-process folder under /dev/shm (memory, not disk) first, removed at exit.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

namespace ibmr::fuzz {

inline std::string ScratchDir() {
  static const std::string dir = [] {
    const std::filesystem::path base = std::filesystem::exists("/dev/shm") ? "/dev/shm" : std::filesystem::temp_directory_path();
    const std::filesystem::path path = base / ("ibmr_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(path);
    // Removed when libFuzzer ends the run (it exits through exit()); a crash leaves it, with the input.
    static const std::string remove_at_exit = path.string();
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(remove_at_exit, ec);
    });
    return path.string();
  }();
  return dir;
}

// Writes `size` bytes to ScratchDir()/name and returns the path.
inline std::string WriteInput(const std::string& name, const uint8_t* data, size_t size) {
  const std::string path = ScratchDir() + "/" + name;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file) {
    if (size > 0) std::fwrite(data, 1, size, file);
    std::fclose(file);
  }
  return path;
}

}  // namespace ibmr::fuzz
