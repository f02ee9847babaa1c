// Memory readings of this process and of the machine (Linux /proc), for fitting per-view work to
// a memory budget. Both return 0 when the reading is not available.
#pragma once

namespace ibmr {

// The heap settings of the programs that run stages (ibmr, the benchmarks): call first in main,
// before any thread starts, with main's argv.
//
// Huge pages: on Linux with glibc 2.35 or later and transparent huge pages in "madvise" mode (the
// default: only memory that asks gets them), the program runs itself again, once (execv of its
// own file, with the same arguments and process id), with glibc.malloc.hugetlb=1 added to
// GLIBC_TUNABLES, so that glibc's malloc asks for huge pages (madvise) on the blocks it maps (2 MB
// and more) and on its heap's growth. A first touch then faults in one 2 MB page instead of 512
// small ones; on a virtual machine, where each fault is dear, stages spent a fifth to a half of
// their time there. Sceaux castle, 9 views at 1600x1202, 2 cores, alternated: plane_sweep to
// score 157-161 -> 123-125 s, fuse 5.4-6.0 -> 2.3-2.4 s, render 30.2-30.9 -> 19.5-20.0 s, outputs
// identical, peaks -5 to +12%. The tunable is read when the program loads, hence the second
// start. It stays in the environment of the programs ibmr runs: COLMAP's feature extraction on
// the castle took 15.6-15.7 s with it, 23.3-25.1 s without (its SfM 56.3-56.5 s against
// 65.0-65.4 s). No second start when the user's GLIBC_TUNABLES names
// glibc.malloc.hugetlb already, when IBMR_HUGE_PAGES=0 (to measure without), when the program was
// started through the dynamic loader or under valgrind, or when the exec fails (the program then
// goes on as it is). Returns true in the second start.
//
// Large buffers (a view's maps, a cost volume band, a render target: 2 MB and more) get
// their own mappings and go back to the system when freed: glibc otherwise raises that threshold
// to the largest block freed so far (up to 32 MB), after which such buffers stay resident after
// being freed (the full-size castle's render peaked 800 MB higher after other stages ran in the
// same process than alone). Smaller blocks come from the heaps, which keep 64 MB spare when they
// shrink instead of glibc's 128 kB: per-view work allocates and frees tens of MB a view, and on
// a virtual machine every page the heap got back from the system again cost a page fault (half
// of multi_depth's time on templeRing: 6.1 -> 3.2 s; plane_sweep 12.7 -> 9.1 s, fuse 5.1 -> 3.9 s;
// fuse's peak 245 -> 317 MB). The runner's malloc_trim after each stage releases the spare.
// The threshold is the huge page's size: glibc asks huge pages only for mapped blocks that large,
// so that a smaller mapped block (layered_stereo's 800x600 float images, 1.9 MB) cost 469 faults
// of 4 kB each time; from the heap it is reused without any. Sceaux castle as above (1 MB -> 2 MB,
// alternated): plane_sweep to score 117-128 -> 108-113 s, layered_stereo 50.8-56.8 -> 40.4-42.5 s,
// peaks up to 10% higher (score 583-600 -> 639-668 MB).
bool ConfigureHeap(char** argv);

// Gives the heap's free memory back to the system (malloc_trim): the 64 MB spare ConfigureHeap
// keeps and what freed blocks left in between. The runner calls it after each stage, a stage
// between phases that free a large model (render between its models).
void ReleaseFreeHeap();

// Resident memory of this process now (VmRSS), MB.
double ResidentMemoryMb();
// Memory the system can give without swapping (MemAvailable), MB.
double AvailableMemoryMb();
// Memory left for more work: `process_limit_mb` minus what this process holds when a limit is
// given (> 0), else what the system has available. Never negative.
double RemainingMemoryMb(double process_limit_mb);

}  // namespace ibmr
