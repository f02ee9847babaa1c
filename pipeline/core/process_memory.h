// Memory readings of this process and of the machine (Linux /proc), for fitting per-view work to
// a memory budget. Both return 0 when the reading is not available.
#pragma once

namespace ibmr {

// The heap settings of the programs that run stages (ibmr, the benchmarks): call first in main,
// before any thread starts, with main's argv.
//
// Huge pages: on Linux with glibc, the program runs itself again (execv of /proc/self/exe, the
// same process id and arguments) once, with GLIBC_TUNABLES=glibc.malloc.hugetlb=1 added to the
// environment, so that glibc's malloc asks for transparent huge pages (madvise) on the blocks it
// maps (2 MB and more) and on its heap's growth. A first touch then faults in one 2 MB page
// instead of 512 small ones; on a virtual machine, where each fault is dear, stages spend a fifth
// to a half of their time there otherwise. Sceaux castle, 9 views at 1600x1202, 2 cores:
// plane_sweep 13.4-14.9 -> 10.7-10.9 s, multi_depth 9.5-10.0 -> 6.9-7.1 s, fuse 5.6 -> 2.8 s,
// render 34.1-35.9 -> 23.3-23.7 s (peaks up to 15% higher). The tunable can only be set before
// the program starts (glibc reads it at load time), hence the second start. The process restores
// GLIBC_TUNABLES to what it was, so the programs it runs (COLMAP) see the user's environment.
// Nothing happens when the user's GLIBC_TUNABLES already names glibc.malloc.hugetlb, when the
// system has transparent huge pages "never" or none, when IBMR_HUGE_PAGES=0 (to measure without),
// or when the exec fails (the program then goes on as it is).
//
// Large buffers (a view's maps, a cost volume band, a render target: 1 MB and more) get
// their own mappings and go back to the system when freed: glibc otherwise raises that threshold
// to the largest block freed so far (up to 32 MB), after which such buffers stay resident after
// being freed (the full-size castle's render peaked 800 MB higher after other stages ran in the
// same process than alone). Smaller blocks come from the heaps, which keep 64 MB spare when they
// shrink instead of glibc's 128 kB: per-view work allocates and frees tens of MB a view, and on
// a virtual machine every page the heap got back from the system again cost a page fault (half
// of multi_depth's time on templeRing: 6.1 -> 3.2 s; plane_sweep 12.7 -> 9.1 s, fuse 5.1 -> 3.9 s;
// fuse's peak 245 -> 317 MB). The runner's malloc_trim after each stage releases the spare.
void ConfigureHeap(char** argv);

// Resident memory of this process now (VmRSS), MB.
double ResidentMemoryMb();
// Memory the system can give without swapping (MemAvailable), MB.
double AvailableMemoryMb();
// Memory left for more work: `process_limit_mb` minus what this process holds when a limit is
// given (> 0), else what the system has available. Never negative.
double RemainingMemoryMb(double process_limit_mb);

}  // namespace ibmr
