// CPU time and peak memory of this process (see resource_usage.h).
#include "pipeline/runner/resource_usage.h"

#include <sys/resource.h>

#include <fstream>
#include <string>

namespace ibmr {

double CpuSeconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  auto seconds = [](const timeval& t) { return t.tv_sec + t.tv_usec * 1e-6; };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

void ResetPeakMemory() {
  std::ofstream clear("/proc/self/clear_refs");
  if (clear) clear << "5";
}

double PeakMemoryMb() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;  // kB
  }
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}

double ChildPeakMemoryMb() {
  rusage usage{};
  getrusage(RUSAGE_CHILDREN, &usage);
  return usage.ru_maxrss / 1024.0;  // kB
}

}  // namespace ibmr
