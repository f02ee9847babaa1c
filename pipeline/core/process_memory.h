// Memory readings of this process and of the machine (Linux /proc), for fitting per-view work to
// a memory budget. Both return 0 when the reading is not available.
#pragma once

namespace ibmr {

// The heap settings of the programs that run stages (ibmr, the benchmarks), before any thread
// starts. Large buffers (a view's maps, a cost volume band, a render target: 1 MB and more) get
// their own mappings and go back to the system when freed: glibc otherwise raises that threshold
// to the largest block freed so far (up to 32 MB), after which such buffers stay resident after
// being freed (the full-size castle's render peaked 800 MB higher after other stages ran in the
// same process than alone). Smaller blocks come from the heaps, which keep 64 MB spare when they
// shrink instead of glibc's 128 kB: per-view work allocates and frees tens of MB a view, and on
// a virtual machine every page the heap got back from the system again cost a page fault (half
// of multi_depth's time on templeRing: 6.1 -> 3.2 s; plane_sweep 12.7 -> 9.1 s, fuse 5.1 -> 3.9 s;
// fuse's peak 245 -> 317 MB). The runner's malloc_trim after each stage releases the spare.
void ConfigureHeap();

// Resident memory of this process now (VmRSS), MB.
double ResidentMemoryMb();
// Memory the system can give without swapping (MemAvailable), MB.
double AvailableMemoryMb();
// Memory left for more work: `process_limit_mb` minus what this process holds when a limit is
// given (> 0), else what the system has available. Never negative.
double RemainingMemoryMb(double process_limit_mb);

}  // namespace ibmr
