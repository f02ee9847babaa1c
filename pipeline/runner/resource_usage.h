// Process resource readings for stage records: CPU seconds (all threads) and peak resident
// memory. Peak memory is per stage: ResetPeakMemory() clears the kernel's high-water mark
// (/proc/self/clear_refs, Linux >= 4.0) before a stage runs.
#pragma once

namespace ibmr {

double CpuSeconds();       // user + system time of this process so far
void ResetPeakMemory();    // best effort; the next PeakMemoryMb() is the peak since this call
double PeakMemoryMb();     // VmHWM in MB
// Peak resident memory of the largest child process waited for so far (COLMAP), MB.
double ChildPeakMemoryMb();

}  // namespace ibmr
