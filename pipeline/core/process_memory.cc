// Memory readings from /proc (see process_memory.h).
#include "pipeline/core/process_memory.h"

#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <string>

namespace ibmr {

namespace {

// The value of a "Name:   1234 kB" line of a /proc file in MB; 0 when absent.
double KilobyteLineMb(const char* file, const std::string& name) {
  std::ifstream in(file);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(name, 0) == 0) return std::stod(line.substr(name.size())) / 1024.0;
  }
  return 0;
}

// Set in the environment of the second start: "1:" and the user's GLIBC_TUNABLES, or "0:" when
// the user had none.
constexpr const char* kRestartMarker = "IBMR_HEAP_RESTARTED";
constexpr const char* kTunable = "glibc.malloc.hugetlb";

// Whether the kernel gives transparent huge pages to memory that asks ("always" or "madvise").
bool TransparentHugePagesOnRequest() {
  std::ifstream in("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string modes;
  std::getline(in, modes);
  return modes.find("[always]") != std::string::npos || modes.find("[madvise]") != std::string::npos;
}

// See ConfigureHeap.
void RunAgainWithHugePageHeap(char** argv) {
#if defined(__linux__) && defined(__GLIBC__)
  if (const char* marker = std::getenv(kRestartMarker)) {
    // The second start: glibc has read the tunable; give the user's environment back.
    const std::string previous = marker;
    if (previous.rfind("1:", 0) == 0) {
      setenv("GLIBC_TUNABLES", previous.substr(2).c_str(), 1);
    } else {
      unsetenv("GLIBC_TUNABLES");
    }
    unsetenv(kRestartMarker);
    return;
  }
  const char* wanted = std::getenv("IBMR_HUGE_PAGES");
  if (argv == nullptr || argv[0] == nullptr || (wanted != nullptr && std::string(wanted) == "0")) return;
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  const std::string user = tunables ? tunables : "";
  if (user.find(kTunable) != std::string::npos || !TransparentHugePagesOnRequest()) return;
  const std::string marker = (tunables ? "1:" : "0:") + user;
  const std::string with_huge_pages = user + (user.empty() ? "" : ":") + kTunable + "=1";
  if (setenv(kRestartMarker, marker.c_str(), 1) != 0 || setenv("GLIBC_TUNABLES", with_huge_pages.c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
  // Still here: the exec failed (no /proc, say); go on with the heap as it is.
  if (tunables) {
    setenv("GLIBC_TUNABLES", user.c_str(), 1);
  } else {
    unsetenv("GLIBC_TUNABLES");
  }
  unsetenv(kRestartMarker);
#else
  (void)argv;
#endif
}

}  // namespace

void ConfigureHeap(char** argv) {
  RunAgainWithHugePageHeap(argv);
  mallopt(M_MMAP_THRESHOLD, 1 << 20);
  mallopt(M_TOP_PAD, 64 << 20);
}

double ResidentMemoryMb() { return KilobyteLineMb("/proc/self/status", "VmRSS:"); }

double AvailableMemoryMb() { return KilobyteLineMb("/proc/meminfo", "MemAvailable:"); }

double RemainingMemoryMb(double process_limit_mb) {
  if (process_limit_mb > 0) return std::max(0.0, process_limit_mb - ResidentMemoryMb());
  return AvailableMemoryMb();
}

}  // namespace ibmr
