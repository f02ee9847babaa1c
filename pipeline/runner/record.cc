// Reading and writing stage records (see record.h).
#include "pipeline/runner/record.h"

#include <filesystem>

#include "pipeline/core/atomic_file.h"

namespace ibmr {

nlohmann::json StageRecord::ToJson() const {
  nlohmann::json json = {{"stage", stage},       {"version", version},     {"status", status},
          {"key", key},           {"params", params},       {"inputs", inputs},
          {"outputs", outputs},   {"heldout", heldout},     {"metrics", metrics},
          {"error", error},       {"started", started},     {"wall_seconds", wall_seconds},
          {"cpu_seconds", cpu_seconds}, {"peak_memory_mb", peak_memory_mb}};
  if (start_memory_mb > 0) json["start_memory_mb"] = start_memory_mb;
  if (views_resumed > 0) json["views_resumed"] = views_resumed;
  if (child_peak_memory_mb > 0) json["child_peak_memory_mb"] = child_peak_memory_mb;
  if (view_memory_mb > 0) {
    json["memory_budget_mb"] = memory_budget_mb;
    json["view_memory_mb"] = view_memory_mb;
    json["views_in_flight"] = views_in_flight;
  }
  if (!reused_from.empty()) json["reused_from"] = reused_from;
  if (!skipped_because.empty()) json["skipped_because"] = skipped_because;
  if (warning_count > 0) {
    json["warnings"] = warnings;
    json["warning_count"] = warning_count;
  }
  return json;
}

StageRecord StageRecord::FromJson(const nlohmann::json& j) {
  StageRecord r;
  r.stage = j.value("stage", "");
  r.version = j.value("version", "");
  r.status = j.value("status", "");
  r.key = j.value("key", "");
  r.params = j.value("params", nlohmann::json::object());
  r.inputs = j.value("inputs", nlohmann::json::object());
  r.outputs = j.value("outputs", nlohmann::json::array());
  r.heldout = j.value("heldout", nlohmann::json::array());
  r.metrics = j.value("metrics", nlohmann::json::object());
  r.error = j.value("error", "");
  r.started = j.value("started", "");
  r.wall_seconds = j.value("wall_seconds", 0.0);
  r.cpu_seconds = j.value("cpu_seconds", 0.0);
  r.peak_memory_mb = j.value("peak_memory_mb", 0.0);
  r.start_memory_mb = j.value("start_memory_mb", 0.0);
  r.views_resumed = j.value("views_resumed", size_t{0});
  r.child_peak_memory_mb = j.value("child_peak_memory_mb", 0.0);
  r.memory_budget_mb = j.value("memory_budget_mb", 0.0);
  r.view_memory_mb = j.value("view_memory_mb", 0.0);
  r.views_in_flight = j.value("views_in_flight", 0);
  r.warnings = j.value("warnings", std::vector<std::string>());
  r.warning_count = j.value("warning_count", size_t{0});
  r.reused_from = j.value("reused_from", "");
  r.skipped_because = j.value("skipped_because", "");
  return r;
}

std::optional<StageRecord> ReadRecord(const std::string& path) {
  if (!std::filesystem::exists(path)) return std::nullopt;
  try {
    return StageRecord::FromJson(nlohmann::json::parse(ReadFile(path)));
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

std::string DumpJson(const nlohmann::json& json, int indent) {
  return json.dump(indent, ' ', false, nlohmann::json::error_handler_t::replace);
}

void WriteRecord(const std::string& path, const StageRecord& record) {
  WriteFileAtomic(path, DumpJson(record.ToJson(), 2) + "\n");
}

}  // namespace ibmr
