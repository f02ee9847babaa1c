// Memory readings of this process and of the machine (Linux /proc), for fitting per-view work to
// a memory budget. Both return 0 when the reading is not available.
#pragma once

namespace ibmr {

// Resident memory of this process now (VmRSS), MB.
double ResidentMemoryMb();
// Memory the system can give without swapping (MemAvailable), MB.
double AvailableMemoryMb();
// Memory left for more work: `process_limit_mb` minus what this process holds when a limit is
// given (> 0), else what the system has available. Never negative.
double RemainingMemoryMb(double process_limit_mb);

}  // namespace ibmr
