// Runs per-view work in parallel with TBB, skipping views already done in this run's
// checkpoint, reporting progress, and marking each view done once its outputs are written.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "pipeline/core/stage_api.h"

namespace ibmr {

struct PerViewSummary {
  size_t computed = 0;  // views processed in this call
  size_t resumed = 0;   // views skipped because an earlier, interrupted run had finished them
};

// Calls `work(view)` for every view not yet done; `work` must write its outputs atomically
// before returning. Exceptions from `work` propagate after the running views finish.
PerViewSummary ForEachView(StageContext& context, const std::string& phase, const std::vector<std::string>& views,
                           const std::function<void(const std::string& view)>& work);

}  // namespace ibmr
