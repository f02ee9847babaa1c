// The instruction sets of the vectorised kernels (see cpu_isa.h).
#include "pipeline/core/cpu_isa.h"

#include <cstdlib>
#include <cstring>
#include <initializer_list>

namespace ibmr {

const char* IsaName(Isa isa) {
  switch (isa) {
    case Isa::kAvx2:
      return "avx2";
    case Isa::kAvx512:
      return "avx512";
    default:
      return "portable";
  }
}

Isa InitialIsa(bool (*supported)(Isa)) {
  if (const char* forced = std::getenv("IBMR_ISA")) {
    for (Isa isa : {Isa::kPortable, Isa::kAvx2, Isa::kAvx512}) {
      if (std::strcmp(forced, IsaName(isa)) == 0 && supported(isa)) return isa;
    }
  }
  for (Isa isa : {Isa::kAvx512, Isa::kAvx2}) {
    if (supported(isa)) return isa;
  }
  return Isa::kPortable;
}

}  // namespace ibmr
