// Memory readings from /proc (see process_memory.h).
#include "pipeline/core/process_memory.h"

#include <malloc.h>
#include <sys/auxv.h>
#include <unistd.h>
#if defined(__GLIBC__)
#include <gnu/libc-version.h>
#endif

#include <algorithm>
#include <cstdio>
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

// Set in the environment of the second start: the pid (an exec keeps it), which tells the second
// start from a program that merely inherited the variable.
constexpr const char* kRestartMarker = "IBMR_HEAP_RESTARTED";
constexpr const char* kTunable = "glibc.malloc.hugetlb";

#if defined(__linux__) && defined(__GLIBC__)
// Whether the kernel gives transparent huge pages only to memory that asks (madvise mode): in
// "always" mode every large block gets them anyway, in "never" (or without THP) none does.
bool HugePagesOnlyOnRequest() {
  std::ifstream in("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string modes;
  std::getline(in, modes);
  return modes.find("[madvise]") != std::string::npos;
}

// glibc 2.35 introduced the tunable; older ones ignore it.
bool GlibcHasHugePageTunable() {
  int major = 0, minor = 0;
  return std::sscanf(gnu_get_libc_version(), "%d.%d", &major, &minor) == 2 && (major > 2 || (major == 2 && minor >= 35));
}
#endif

// See ConfigureHeap. True in the second start.
bool RunAgainWithHugePageHeap(char** argv) {
#if defined(__linux__) && defined(__GLIBC__)
  const std::string pid = std::to_string(::getpid());
  if (const char* marker = std::getenv(kRestartMarker)) {
    const bool ours = pid == marker;
    unsetenv(kRestartMarker);
    // The second start: glibc has read the tunable, which stays in the environment for the
    // programs this one runs (COLMAP's feature extraction gains as much; a child ibmr needs no
    // second start).
    if (ours) return true;
  }
  const char* wanted = std::getenv("IBMR_HUGE_PAGES");
  if (argv == nullptr || argv[0] == nullptr || (wanted != nullptr && std::string(wanted) == "0")) return false;
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  const std::string user = tunables ? tunables : "";
  if (user.find(kTunable) != std::string::npos || !HugePagesOnlyOnRequest() || !GlibcHasHugePageTunable()) return false;
  // Started through the dynamic loader (`ld-linux.so ibmr ...`: no interpreter of its own) or
  // under valgrind (which would not follow): the program is not ours to start again.
  const char* preload = std::getenv("LD_PRELOAD");
  if (getauxval(AT_BASE) == 0 || (preload != nullptr && std::string(preload).find("vgpreload") != std::string::npos)) return false;
  // The program's own path, not /proc/self/exe: the kernel names a process after the file it
  // runs (`ps`, `pidof ibmr`).
  char path[4096];
  const ssize_t length = readlink("/proc/self/exe", path, sizeof(path) - 1);
  if (length <= 0) return false;
  path[length] = '\0';
  const std::string with_huge_pages = user + (user.empty() ? "" : ":") + kTunable + "=1";
  if (setenv(kRestartMarker, pid.c_str(), 1) == 0 && setenv("GLIBC_TUNABLES", with_huge_pages.c_str(), 1) == 0) {
    execv(path, argv);
  }
  // Still here: the exec failed; go on with the heap and the environment as they were.
  if (tunables != nullptr) {
    setenv("GLIBC_TUNABLES", user.c_str(), 1);
  } else {
    unsetenv("GLIBC_TUNABLES");
  }
  unsetenv(kRestartMarker);
  return false;
#else
  (void)argv;
  return false;
#endif
}

}  // namespace

bool ConfigureHeap(char** argv) {
  const bool restarted = RunAgainWithHugePageHeap(argv);
  mallopt(M_MMAP_THRESHOLD, 2 << 20);
  mallopt(M_TOP_PAD, 64 << 20);
  return restarted;
}

void ReleaseFreeHeap() {
#if defined(__GLIBC__)
  malloc_trim(0);
#endif
}

double ResidentMemoryMb() { return KilobyteLineMb("/proc/self/status", "VmRSS:"); }

double AvailableMemoryMb() { return KilobyteLineMb("/proc/meminfo", "MemAvailable:"); }

double RemainingMemoryMb(double process_limit_mb) {
  if (process_limit_mb > 0) return std::max(0.0, process_limit_mb - ResidentMemoryMb());
  return AvailableMemoryMb();
}

}  // namespace ibmr
