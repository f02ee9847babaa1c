// The engine's buffer pool and the run-time choice of its build (see sweep_engine.h; the loops
// are in sweep_kernels.cc).
#include "stages/plane_sweep/sweep_engine.h"

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <mutex>
#include <stdexcept>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

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

// IBMR_ISA=portable (or avx2) in the environment starts the process on that build where the CPU
// runs it (to compare the builds as whole processes; cpu_isa.h).
std::atomic<Isa>& Active() {
  static std::atomic<Isa> active{InitialIsa(IsaSupported)};
  return active;
}

}  // namespace

bool IsaSupported(Isa isa) {
  switch (isa) {
    case Isa::kPortable:
      return true;
#if IBMR_SWEEP_HAVE_AVX512
    case Isa::kAvx2: {
      // Every feature the build's `#pragma GCC target` enables (sweep_kernels.cc).
      static const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("bmi") &&
                               __builtin_cpu_supports("bmi2") && __builtin_cpu_supports("fma") &&
                               __builtin_cpu_supports("popcnt");
      return avx2;
    }
    case Isa::kAvx512: {
      static const bool avx512 = IsaSupported(Isa::kAvx2) && __builtin_cpu_supports("avx512cd") &&
                                 __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                                 __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
                                 __builtin_cpu_supports("avx512vpopcntdq");
      return avx512;
    }
#endif
    default:
      return false;
  }
}

Isa BestIsa() {
  if (IsaSupported(Isa::kAvx512)) return Isa::kAvx512;
  if (IsaSupported(Isa::kAvx2)) return Isa::kAvx2;
  return Isa::kPortable;
}

Isa ActiveIsa() { return Active().load(); }

bool SetIsa(Isa isa) {
  if (!IsaSupported(isa)) return false;
  Active().store(isa);
  return true;
}

#if IBMR_SWEEP_HAVE_AVX512
#define IBMR_SWEEP_DISPATCH(call)                                  \
  switch (ActiveIsa()) {                                           \
    case Isa::kAvx512:                                             \
      return avx512::call;                                         \
    case Isa::kAvx2:                                               \
      return avx2::call;                                           \
    default:                                                       \
      return portable::call;                                       \
  }
#else
#define IBMR_SWEEP_DISPATCH(call) return portable::call
#endif

double ThreadCpuSeconds() {
  timespec now{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

VolumeWork BuildCostVolume(const cv::Mat& reference_gray, const std::vector<Neighbour>& neighbours,
                           const EngineOptions& options, CostVolume* volume, const PlaneRanges* ranges,
                           const std::vector<uint64_t>* reference_census, cv::Point origin) {
  IBMR_SWEEP_DISPATCH(BuildCostVolume(reference_gray, neighbours, options, volume, ranges, reference_census, origin));
}

void Aggregate(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options,
               Aggregated* out, bool one_buffer) {
  IBMR_SWEEP_DISPATCH(Aggregate(volume, reference_gray, options, one_buffer, out));
}

Winners WinnerTakeAll(const Aggregated& aggregated, const CostVolume* data_cost, const CertaintyOptions& certainty,
                      bool right_winners) {
  IBMR_SWEEP_DISPATCH(WinnerTakeAll(aggregated, data_cost, certainty, right_winners));
}

Winners AggregateAndPick(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options,
                         const CertaintyOptions& certainty, LargeBuffer<uint16_t>* sums) {
  IBMR_SWEEP_DISPATCH(AggregateAndPick(volume, reference_gray, options, certainty, sums));
}

std::vector<uint64_t> CensusTransform(const cv::Mat& gray, int radius_x, int radius_y) {
  IBMR_SWEEP_DISPATCH(CensusTransform(gray, radius_x, radius_y));
}

#undef IBMR_SWEEP_DISPATCH

bool IsHalfTurned(const Eigen::Matrix3d& reference_rotation, const Eigen::Matrix3d& neighbour_rotation) {
  const Eigen::Matrix3d relative = neighbour_rotation * reference_rotation.transpose();
  return relative(0, 0) + relative(1, 1) < 0;
}

std::vector<uint64_t> ReverseCensusBits(const std::vector<uint64_t>& codes, int bits) {
  if (bits < 1 || bits > 64) throw std::invalid_argument("ReverseCensusBits: bits must be in [1, 64]");
  std::vector<uint64_t> reversed(codes.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, codes.size(), 1 << 14), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i) {
      uint64_t c = codes[i];
      // Swap halves, then quarters, ... down to single bits: the whole word reversed.
      c = (c >> 32) | (c << 32);
      c = ((c >> 16) & 0x0000FFFF0000FFFFull) | ((c & 0x0000FFFF0000FFFFull) << 16);
      c = ((c >> 8) & 0x00FF00FF00FF00FFull) | ((c & 0x00FF00FF00FF00FFull) << 8);
      c = ((c >> 4) & 0x0F0F0F0F0F0F0F0Full) | ((c & 0x0F0F0F0F0F0F0F0Full) << 4);
      c = ((c >> 2) & 0x3333333333333333ull) | ((c & 0x3333333333333333ull) << 2);
      c = ((c >> 1) & 0x5555555555555555ull) | ((c & 0x5555555555555555ull) << 1);
      reversed[i] = c >> (64 - bits);
    }
  });
  return reversed;
}

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
