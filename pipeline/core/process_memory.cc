// Memory readings from /proc (see process_memory.h).
#include "pipeline/core/process_memory.h"

#include <malloc.h>

#include <algorithm>
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

}  // namespace

void ConfigureHeap() {
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
