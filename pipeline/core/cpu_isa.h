// The instruction sets the project's vectorised kernels are built for (plane_sweep's sweep
// kernels, the splat rasterizer's tile loops): each such file is compiled once per set and the
// process picks one at run time. Each module says which sets its build has and the CPU runs (its
// own feature list: the AVX-512 sweep kernels need VPOPCNTDQ, the splat tiles do not); this file
// holds what they share: the names, and the choice a process starts with.
#pragma once

namespace ibmr {

enum class Isa { kPortable, kAvx2, kAvx512 };

// "portable", "avx2", "avx512".
const char* IsaName(Isa isa);

// The set a process starts on: the one IBMR_ISA names (portable, avx2 or avx512) when `supported`
// says the CPU runs it (to compare the builds as whole processes), else the fastest supported.
Isa InitialIsa(bool (*supported)(Isa));

}  // namespace ibmr
