// The engine's functions as built for one instruction set (sweep_kernels.cc, compiled once per
// set into its own namespace); sweep_engine.cc chooses among them at run time. Internal to the
// plane_sweep stage: callers use the functions of sweep_engine.h.
#pragma once

#include "stages/plane_sweep/sweep_engine.h"

#define IBMR_SWEEP_KERNEL_DECLARATIONS                                                                         \
  VolumeWork BuildCostVolume(const cv::Mat& reference_gray, const std::vector<Neighbour>& neighbours,           \
                             const EngineOptions& options, CostVolume* volume, const PlaneRanges* ranges,       \
                             const std::vector<uint64_t>* reference_census, cv::Point origin);                 \
  void Aggregate(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options,         \
                 bool one_buffer, Aggregated* out);                                                           \
  Winners WinnerTakeAll(const Aggregated& aggregated, const CostVolume* data_cost,                               \
                        const CertaintyOptions& certainty,                                                     \
                        bool right_winners);                                                                   \
  Winners AggregateAndPick(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options,  \
                           const CertaintyOptions& certainty, LargeBuffer<uint16_t>* sums);                   \
  std::vector<uint64_t> CensusTransform(const cv::Mat& gray, int radius_x, int radius_y);

namespace ibmr {
namespace sweep {
namespace portable {
IBMR_SWEEP_KERNEL_DECLARATIONS
}  // namespace portable
namespace avx2 {
IBMR_SWEEP_KERNEL_DECLARATIONS
}  // namespace avx2
namespace avx512 {
IBMR_SWEEP_KERNEL_DECLARATIONS
}  // namespace avx512
}  // namespace sweep
}  // namespace ibmr

#undef IBMR_SWEEP_KERNEL_DECLARATIONS
