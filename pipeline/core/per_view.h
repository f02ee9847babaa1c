// Runs per-view work in parallel with TBB, skipping views already done in this run's checkpoint,
// reporting progress, and marking each view done, with its piece of the metrics, once its outputs
// are written. In a shard run it computes only the shard's views and then ends the stage.
#pragma once

#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "pipeline/core/stage_api.h"

namespace ibmr {

struct PerViewSummary {
  size_t computed = 0;  // views processed in this call
  size_t resumed = 0;   // views skipped because an earlier run (or a shard) had finished them
  // Every view's piece, computed or resumed, by name: aggregate from here (in name order, so that
  // the totals do not depend on which thread or shard finished first).
  std::map<std::string, nlohmann::json> pieces;
};

// Thrown by ForEachView in a shard run once the shard's views are done: what the stage does
// after its per-view loop (aggregating, stage-wide outputs) belongs to the merge, so the stage
// stops there. The runner treats it as the shard's success.
struct ShardFinished {
  size_t computed = 0;
  size_t resumed = 0;
};

// Calls `work(view)` for every view not yet done; `work` writes its outputs atomically and
// returns the view's piece (null when the stage keeps none). Exceptions from `work` propagate
// after the running views finish, with the view's name added.
PerViewSummary ForEachView(StageContext& context, const std::string& phase, const std::vector<std::string>& views,
                           const std::function<nlohmann::json(const std::string& view)>& work);

}  // namespace ibmr
