// One record per stage run, records/<stage>.json: what ran (inputs with content hashes,
// parameters, code version, holdout set), how it went (status, error), what it cost (wall and
// CPU seconds, peak memory in MB) and the stage's own metrics. The runner compares a stored
// record's cache key with the current one to decide what is stale. Written atomically.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/core/json_file.h"  // ReadJsonOr

namespace ibmr {

struct StageRecord {
  std::string stage;
  std::string version;
  std::string status;  // "running", "ok", "failed" or "skipped" (the run's plan: Stage::Serves)
  std::string skipped_because;  // status "skipped": the one-line reason
  std::string key;     // cache key: hash of version, result parameters, holdout set, input hashes
  nlohmann::json params = nlohmann::json::object();
  nlohmann::json inputs = nlohmann::json::object();  // path -> content hash
  nlohmann::json outputs = nlohmann::json::array();
  nlohmann::json heldout = nlohmann::json::array();
  nlohmann::json metrics = nlohmann::json::object();
  std::string error;
  std::string started;  // ISO 8601, local time
  double wall_seconds = 0;
  double cpu_seconds = 0;
  double peak_memory_mb = 0;
  // Resident memory of the process when the stage started (what earlier stages left, plus the
  // program); the peak above includes it.
  double start_memory_mb = 0;
  // Peak of the largest program the stage ran (COLMAP), when it was larger than any before it in
  // this process; 0: none.
  double child_peak_memory_mb = 0;
  // Per-view stages: the memory budget the views in flight were fitted to (--memory-limit, or
  // what was available when the stage started), the stage's estimate of one view, and the views
  // run at once. 0: not a per-view stage (no estimate).
  double memory_budget_mb = 0;
  double view_memory_mb = 0;
  int views_in_flight = 0;
  size_t views_resumed = 0;  // per-view work found done by an interrupted run or by shards (how it ran,
                             // not what it made: the metrics count every view either way)
  // The warnings the stage logged while it ran (the first 20) and how many (stage_warnings.h):
  // a later stage's failure quotes them as the likely cause.
  std::vector<std::string> warnings;
  size_t warning_count = 0;
  std::string reused_from;  // another workspace whose outputs of the same key were linked in (ibmr sweep);
                            // the costs above are those of the run that computed them

  nlohmann::json ToJson() const;
  static StageRecord FromJson(const nlohmann::json& json);
};

// `json` as text (`indent` as nlohmann's dump), with bytes that are not UTF-8 replaced by U+FFFD:
// file names and workspace paths in another encoding are legal on Linux, and a plain dump()
// throws an opaque "incomplete UTF-8 string" naming no file. Every JSON the runner writes goes
// through here.
std::string DumpJson(const nlohmann::json& json, int indent = -1);

// nullopt when the record is absent or unreadable (treated as "never ran").
std::optional<StageRecord> ReadRecord(const std::string& path);
void WriteRecord(const std::string& path, const StageRecord& record);


}  // namespace ibmr
