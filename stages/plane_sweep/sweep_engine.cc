// The engine's buffer pool and the run-time choice of its build (see sweep_engine.h; the loops
// are in sweep_kernels.cc).
#include "stages/plane_sweep/sweep_engine.h"

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <mutex>

#include "stages/plane_sweep/sweep_kernels.h"

namespace ibmr {
namespace sweep {

namespace {

std::mutex& PoolMutex() {
  static std::mutex mutex;
  return mutex;
}
std::vector<std::unique_ptr<Buffers>>& Pool() {
  static std::vector<std::unique_ptr<Buffers>> pool;
  return pool;
}

// IBMR_ISA=portable in the environment starts the process on the portable build (to compare the
// two as whole processes).
std::atomic<Isa>& Active() {
  static std::atomic<Isa> active{[] {
    const char* forced = std::getenv("IBMR_ISA");
    return forced != nullptr && std::strcmp(forced, "portable") == 0 ? Isa::kPortable : BestIsa();
  }()};
  return active;
}

}  // namespace

Isa BestIsa() {
#if IBMR_SWEEP_HAVE_AVX512
  static const bool avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                             __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
                             __builtin_cpu_supports("avx512vpopcntdq");
  if (avx512) return Isa::kAvx512;
#endif
  return Isa::kPortable;
}

Isa ActiveIsa() { return Active().load(); }

bool SetIsa(Isa isa) {
  if (isa == Isa::kAvx512 && BestIsa() != Isa::kAvx512) return false;
  Active().store(isa);
  return true;
}

const char* IsaName(Isa isa) { return isa == Isa::kAvx512 ? "avx512" : "portable"; }

#if IBMR_SWEEP_HAVE_AVX512
#define IBMR_SWEEP_DISPATCH(call) return ActiveIsa() == Isa::kAvx512 ? avx512::call : portable::call
#else
#define IBMR_SWEEP_DISPATCH(call) return portable::call
#endif

int64_t BuildCostVolume(const cv::Mat& reference_gray, const std::vector<Neighbour>& neighbours,
                        const EngineOptions& options, CostVolume* volume, const PlaneRanges* ranges) {
  IBMR_SWEEP_DISPATCH(BuildCostVolume(reference_gray, neighbours, options, volume, ranges));
}

void Aggregate(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options,
               Aggregated* out) {
  IBMR_SWEEP_DISPATCH(Aggregate(volume, reference_gray, options, out));
}

Winners WinnerTakeAll(const Aggregated& aggregated, const CostVolume* data_cost, double confidence_scale,
                      bool right_winners) {
  IBMR_SWEEP_DISPATCH(WinnerTakeAll(aggregated, data_cost, confidence_scale, right_winners));
}

std::vector<uint64_t> CensusTransform(const cv::Mat& gray, int radius_x, int radius_y) {
  IBMR_SWEEP_DISPATCH(CensusTransform(gray, radius_x, radius_y));
}

#undef IBMR_SWEEP_DISPATCH

BufferLease::BufferLease() {
  std::lock_guard<std::mutex> lock(PoolMutex());
  if (Pool().empty()) {
    buffers_ = std::make_unique<Buffers>();
  } else {
    buffers_ = std::move(Pool().back());
    Pool().pop_back();
  }
}

BufferLease::~BufferLease() {
  std::lock_guard<std::mutex> lock(PoolMutex());
  Pool().push_back(std::move(buffers_));
}

void ReleaseBufferPool() {
  std::lock_guard<std::mutex> lock(PoolMutex());
  Pool().clear();
}

}  // namespace sweep
}  // namespace ibmr
