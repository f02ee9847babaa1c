// The stage graph, cache decisions and stage execution (see runner.h).
#include "pipeline/runner/runner.h"

#include <spdlog/fmt/ranges.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <memory>
#include <thread>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_info.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/content_hash.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/per_view.h"
#include "pipeline/runner/race.h"
#include "pipeline/runner/record.h"
#include "pipeline/runner/stage_warnings.h"
#include "pipeline/core/process_memory.h"
#include "pipeline/core/sparse_image_names.h"
#include "pipeline/runner/resource_usage.h"
#include "pipeline/runner/stage_lock.h"
#include "pipeline/runner/terminal_progress.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

std::string NowIso() {
  const std::time_t t = std::time(nullptr);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%S", std::localtime(&t));
  return buffer;
}

// Absolute, normalised form of a declared input/output (workspace-relative unless absolute).
std::string Resolve(const Workspace& workspace, const std::string& path) { return workspace.Resolve(path); }

// True when one path is the other or lies inside it.
bool Overlaps(const std::string& a, const std::string& b) { return PathWithin(a, b) || PathWithin(b, a); }

std::vector<std::string> SortedImageNames(const Workspace& workspace) {
  const SparseImageNames model = ReadSparseImageNamesCached(workspace.SparseDir());
  if (!model.readable && !model.error.empty()) {
    spdlog::warn("cannot read the image list for the holdout policy: {}", model.error);
  }
  return model.names;
}

// Throws ConfigError for a name of holdout.images that is not an image of the model: the view
// would be used for training while the log said it was held out. Names the config key and the
// nearest image name. Nothing to check before a model exists (`sorted_names` empty).
void CheckHeldoutNames(const Config& config, const std::vector<std::string>& sorted_names) {
  if (sorted_names.empty()) return;
  for (size_t i = 0; i < config.holdout.images.size(); ++i) {
    const std::string& name = config.holdout.images[i];
    if (std::find(sorted_names.begin(), sorted_names.end(), name) != sorted_names.end()) continue;
    const int line = i < config.holdout.image_lines.size() ? config.holdout.image_lines[i] : 0;
    throw ConfigError(config.path + (line > 0 ? ":" + std::to_string(line) : "") + ": key 'holdout.images': '" + name +
                      "' is not an image of the model (" + std::to_string(sorted_names.size()) +
                      " images); did you mean '" + Nearest(name, sorted_names) + "'? Give names as the model's images.txt has them");
  }
}

// Throws ConfigError for `holdout.split` when the capture has no image of that split (no
// splits.json: not a capture with splits), naming the key and what the capture holds.
void CheckHeldoutSplit(const Config& config, const std::vector<std::string>& sorted_names, const ImageSplits& splits) {
  if (config.holdout.split.empty() || sorted_names.empty()) return;
  std::map<std::string, int> counts;
  for (const std::string& name : sorted_names) {
    const auto it = splits.find(name);
    ++counts[it == splits.end() ? "none" : it->second];
  }
  if (counts.count(config.holdout.split)) return;
  std::string held;
  for (const auto& [split, count] : counts) held += (held.empty() ? "" : ", ") + split + " " + std::to_string(count);
  throw ConfigError(config.path + ":" + std::to_string(config.holdout.split_line) + ": key 'holdout.split': the capture has no image of the " +
                    config.holdout.split + " split (" + held + (splits.empty() ? "; no splits.json: import a capture with splits, such as NeRF's Blender layout with transforms_" + config.holdout.split + ".json" : "") +
                    "); use holdout.every or holdout.images instead");
}

}  // namespace

ViewCheckpoint Runner::CheckpointOf(const Stage& stage, const std::string& key) const {
  return ViewCheckpoint(Workspace(config_.workspace).RecordsDir() + "/" + stage.Name() + ".views", key);
}

std::string Runner::RecordPath(const std::string& stage) const {
  return Workspace(config_.workspace).RecordsDir() + "/" + stage + ".json";
}

std::string Runner::LockPath(const std::string& stage) const {
  return Workspace(config_.workspace).RecordsDir() + "/" + stage + ".lock";
}

Workspace Runner::WorkspaceBefore(const StageConfig& stage_config) const {
  return ModelWorkspace(static_cast<size_t>(&stage_config - config_.stages.data()));
}

Workspace Runner::WorkspaceAfter(size_t index) const { return ModelWorkspace(index + 1); }

Workspace Runner::ModelWorkspace(size_t stages) const {
  Workspace workspace(config_.workspace);
  // The model and images of the last of the first `stages` stages that writes them.
  for (size_t i = 0; i < stages && i < config_.stages.size(); ++i) {
    const Stage::ModelFolders folders = registry_.Find(config_.stages[i].name)->WritesModel();
    workspace.SetModelFolders(folders.sparse.empty() ? workspace.SparseRelative() : folders.sparse,
                              folders.images.empty() ? workspace.ImagesRelative() : folders.images);
  }
  return workspace;
}

std::optional<CaptureShape> Runner::CaptureOf(size_t index) const {
  return CaptureIn(WorkspaceBefore(config_.stages.at(index)));
}

std::optional<CaptureShape> Runner::CaptureIn(const Workspace& workspace) const {
  const std::string folder = Resolve(workspace, workspace.SparseRelative());
  if (const auto found = shapes_.find(folder); found != shapes_.end()) return found->second;
  std::optional<CaptureShape> shape;
  if (fs::exists(folder + "/images.txt")) {
    try {
      const SparseModel model = ReadSparseModelText(folder);
      if (!model.images.empty()) {
        shape = AnalyseCapture(model, CaptureHasAlpha(workspace));
        if (config_.plan.kind != "auto" && config_.plan.kind != shape->kind) {
          shape->set_by = "plan.kind (the analysis: " + shape->kind + ")";
          shape->kind = config_.plan.kind;
        }
        nlohmann::json json = shape->ToJson();
        json["model"] = workspace.SparseRelative();
        const std::string path = workspace.Path(kCaptureFile);
        // Looking (status, --dry-run) writes nothing.
        if (write_capture_ && ReadJsonOr(path, nlohmann::json()) != json) WriteFileAtomic(path, DumpJson(json, 2) + "\n");
        spdlog::info("capture: {} ({})", shape->Describe(), kCaptureFile);
      }
    } catch (const std::exception& e) {
      spdlog::warn("cannot analyse the capture's shape from {}: {}; every stage runs", folder, e.what());
      shape.reset();
    }
  }
  shapes_[folder] = shape;
  return shape;
}

std::string Runner::SkipReason(size_t index) const {
  const StageConfig& stage_config = config_.stages.at(index);
  const Stage& stage = *registry_.Find(stage_config.name);
  if (config_.plan.Forces(stage.Name())) return "";
  if (const auto race = race_skips_.find(index); race != race_skips_.end()) return race->second;
  const CaptureUse use = stage.Serves();
  if (!use.kinds.empty()) {
    const std::optional<CaptureShape> shape = CaptureOf(index);
    if (shape && !shape->kind.empty() && std::find(use.kinds.begin(), use.kinds.end(), shape->kind) == use.kinds.end()) {
      return stage.Name() + ": skipped, the capture is " + shape->Describe() + "; " + use.why + "; --with " +
             stage.Name() + " runs it";
    }
  }
  if (stage.SkippedWithItsInputs() && !skipped_outputs_.empty()) {
    const StageContext context = MakeContext(stage, stage_config);  // carries skipped_outputs_
    for (const std::string& input : stage.Inputs(context)) {
      if (const std::string* reason = context.SkippedBy(input)) {
        return stage.Name() + ": skipped, it needs '" + input + "', which a skipped stage makes (" + *reason + ")";
      }
    }
  }
  return "";
}

void Runner::Skip(size_t index, const StageContext& context, const std::string& key, const std::string& reason,
                  bool write_record) const {
  const Stage& stage = *registry_.Find(config_.stages.at(index).name);
  const std::vector<std::string> outputs = stage.Outputs(context);
  // For the stages after it, the reason up to its figures: "volume: skipped, the capture is general".
  const std::string short_reason = reason.substr(0, reason.find(" ("));
  for (const std::string& output : outputs) skipped_outputs_[Resolve(context.workspace, output)] = short_reason;
  if (!write_record) return;
  const auto record = ReadRecord(RecordPath(stage.Name()));
  if (record && record->status == "skipped" && record->key == key && record->skipped_because == reason) {
    spdlog::info("[{}] {} (as before)", stage.Name(), reason);
    return;
  }
  StageRecord skipped;
  skipped.stage = stage.Name();
  skipped.version = stage.Version();
  skipped.status = "skipped";
  skipped.skipped_because = reason;
  skipped.key = key;
  skipped.params = context.params.ResultJson(stage.Parameters());
  skipped.heldout = context.heldout_images;
  skipped.outputs = outputs;
  skipped.started = NowIso();
  WriteRecord(RecordPath(stage.Name()), skipped);
  spdlog::info("[{}] {}", stage.Name(), reason);
}

StageContext Runner::MakeContext(const Stage& stage, const StageConfig& stage_config) const {
  StageContext context;
  context.workspace = WorkspaceBefore(stage_config);
  context.skipped_outputs = skipped_outputs_;
  context.params = stage_config.params;
  context.config_dir = config_.dir;
  context.inputs = config_.inputs;
  context.role = stage.Role();
  if (context.role != HoldoutRole::kAllViews && config_.holdout.Active()) {
    const std::vector<std::string> names = SortedImageNames(context.workspace);
    CheckHeldoutNames(config_, names);
    const ImageSplits splits = config_.holdout.split.empty() ? ImageSplits() : ReadImageSplits(context.workspace);
    CheckHeldoutSplit(config_, names, splits);
    context.heldout_images = config_.holdout.Select(names, splits);
    if (context.role == HoldoutRole::kScoring) context.scored_heldout = config_.holdout.Scored(names, splits);
  }
  if (!race_losers_.empty() && !stage.DrawsModels(context).empty()) context.left_out_models = race_losers_;
  return context;
}

std::string Runner::CacheKey(const Stage& stage, const StageContext& context, nlohmann::json* input_hashes,
                             const nlohmann::json* params_override) const {
  *input_hashes = nlohmann::json::object();
  for (const std::string& input : stage.Inputs(context)) {
    const std::string path = Resolve(context.workspace, input);
    // What a skipped stage left from an earlier run is not read (StageContext::SkippedBy).
    (*input_hashes)[input] = context.SkippedBy(input) != nullptr ? std::string("skipped")
                                                                : HashPath(path, config_.workspace);  // a workspace in the photo folder
  }
  nlohmann::json key_source = {{"stage", stage.Name()},
                               {"version", stage.Version()},
                               {"params", params_override ? *params_override : context.params.ResultJson(stage.Parameters())},
                               {"heldout", context.heldout_images},
                               {"inputs", *input_hashes}};
  // Only where a subset is scored, so that every other stage's key stays as it was.
  if (!context.scored_heldout.empty()) key_source["scored"] = context.scored_heldout;
  if (!context.left_out_models.empty()) key_source["left_out_models"] = context.left_out_models;
  // Equal to a plain dump() for UTF-8 names, so that cache keys stay as they were.
  return HashBytes(DumpJson(key_source));
}

std::string Runner::MissingOutput(const Stage& stage, const StageContext& context) const {
  for (const std::string& output : stage.Outputs(context)) {
    if (!fs::exists(Resolve(context.workspace, output))) return "output '" + output + "' is missing";
  }
  return "";
}

bool Runner::Finished(const Stage& stage, const StageContext& context, const std::string& key) const {
  const auto record = ReadRecord(RecordPath(stage.Name()));
  return record && record->status == "ok" && KeyMatches(stage, context, key, *record) && MissingOutput(stage, context).empty();
}

// A parameter a stage gains in a later version changes every key (the key holds every parameter),
// though a run with it at its default computes what the record's run computed: every workspace
// would redo the stage and all after it. So the record's key also matches when the only
// parameters it lacks are at their defaults: the key is then recomputed over the record's
// parameters alone. (A changed default, or a new parameter set away from its default, still
// changes the key; a change of behaviour comes with a new Version().)
bool Runner::KeyMatches(const Stage& stage, const StageContext& context, const std::string& key,
                        const StageRecord& record) const {
  if (record.key == key) return true;
  if (record.version != stage.Version() || !record.params.is_object()) return false;
  const nlohmann::json params = context.params.ResultJson(stage.Parameters());
  const nlohmann::json defaults = DefaultParams(stage, config_.dir).ResultJson(stage.Parameters());
  nlohmann::json recorded_set = nlohmann::json::object();
  bool lacks_some = false;
  for (auto it = params.begin(); it != params.end(); ++it) {
    if (record.params.contains(it.key())) {
      recorded_set[it.key()] = it.value();
    } else if (defaults.contains(it.key()) && defaults[it.key()] == it.value()) {
      lacks_some = true;
    } else {
      return false;
    }
  }
  if (!lacks_some) return false;
  nlohmann::json inputs;
  return CacheKey(stage, context, &inputs, &recorded_set) == record.key;
}

std::string Runner::OwnStaleness(const Stage& stage, const StageContext& context, const std::string& key) const {
  const auto record = ReadRecord(RecordPath(stage.Name()));
  if (!record) return "never ran";
  if (record->status == "running") {
    const std::string holder = LockHolder(LockPath(stage.Name()));
    if (!holder.empty()) return "running now in another process (" + holder + ")";
    return "interrupted while running (will resume)";
  }
  if (record->status == "skipped") {
    return "the plan skipped it last time (" + record->skipped_because.substr(0, record->skipped_because.find(" (")) +
           "); now it runs";
  }
  if (record->status != "ok") return "last run failed: " + record->error;
  if (KeyMatches(stage, context, key, *record)) return MissingOutput(stage, context);
  if (record->version != stage.Version()) return "code version changed (" + record->version + " -> " + stage.Version() + ")";
  const nlohmann::json params = context.params.ResultJson(stage.Parameters());
  for (auto it = params.begin(); it != params.end(); ++it) {
    if (!record->params.contains(it.key()) || record->params[it.key()] != it.value()) {
      return "parameter '" + it.key() + "' changed (" +
             (record->params.contains(it.key()) ? DumpJson(record->params[it.key()]) : "unset") + " -> " +
             DumpJson(it.value()) + ")";
    }
  }
  if (record->heldout != nlohmann::json(context.heldout_images)) return "holdout set changed";
  nlohmann::json inputs;
  CacheKey(stage, context, &inputs);
  for (auto it = inputs.begin(); it != inputs.end(); ++it) {
    if (!record->inputs.contains(it.key()) || record->inputs[it.key()] != it.value()) {
      return "input '" + it.key() + "' changed";
    }
  }
  return "cache key changed";
}

std::vector<size_t> Runner::Upstream(size_t index) const {
  const Stage* stage = registry_.Find(config_.stages[index].name);
  const StageContext context = MakeContext(*stage, config_.stages[index]);
  std::vector<size_t> upstream;
  for (size_t j = 0; j < index; ++j) {
    const Stage* earlier = registry_.Find(config_.stages[j].name);
    const StageContext earlier_context = MakeContext(*earlier, config_.stages[j]);
    bool depends = false;
    for (const std::string& in : stage->Inputs(context)) {
      for (const std::string& out : earlier->Outputs(earlier_context)) {
        depends |= Overlaps(Resolve(context.workspace, in), Resolve(context.workspace, out));
      }
    }
    if (depends) upstream.push_back(j);
  }
  return upstream;
}

std::vector<std::string> Runner::DeclaredInputs(size_t index) const {
  const Stage& stage = *registry_.Find(config_.stages.at(index).name);
  return stage.Inputs(MakeContext(stage, config_.stages[index]));
}

std::vector<std::string> Runner::DeclaredOutputs(size_t index) const {
  const Stage& stage = *registry_.Find(config_.stages.at(index).name);
  return stage.Outputs(MakeContext(stage, config_.stages[index]));
}

std::string Runner::SharedOutputs() const {
  const Workspace workspace(config_.workspace);
  std::vector<std::vector<std::string>> outputs;
  for (size_t i = 0; i < config_.stages.size(); ++i) outputs.push_back(DeclaredOutputs(i));
  for (size_t i = 0; i < outputs.size(); ++i) {
    for (size_t j = i + 1; j < outputs.size(); ++j) {
      for (const std::string& a : outputs[i]) {
        for (const std::string& b : outputs[j]) {
          if (!Overlaps(Resolve(workspace, a), Resolve(workspace, b))) continue;
          return config_.path + ": stages '" + config_.stages[i].name + "' and '" + config_.stages[j].name +
                 "' both write " + (a.size() <= b.size() ? a : b) + " ('" + a + "' and '" + b +
                 "'); a file has one writer, so that the cache knows which stage made it: drop one of the stages "
                 "or point one at another folder";
        }
      }
    }
  }
  return "";
}

std::vector<StageStatus> Runner::Status() const {
  std::vector<StageStatus> statuses;
  skipped_outputs_.clear();
  shapes_.clear();
  write_capture_ = false;
  LoadRaceSkips();
  for (size_t i = 0; i < config_.stages.size(); ++i) {
    const Stage* stage = registry_.Find(config_.stages[i].name);
    const StageContext context = MakeContext(*stage, config_.stages[i]);
    nlohmann::json inputs;
    const std::string key = CacheKey(*stage, context, &inputs);
    if (const std::string skip = SkipReason(i); !skip.empty()) {
      Skip(i, context, key, skip, false);
      statuses.push_back({stage->Name(), true, skip.substr(skip.find(':') + 2), true});
      continue;
    }
    StageStatus status{stage->Name(), false, OwnStaleness(*stage, context, key)};
    if (status.reason.empty()) {
      for (size_t j : Upstream(i)) {
        if (!statuses[j].up_to_date) status.reason = "upstream stage '" + statuses[j].name + "' is stale";
      }
    }
    status.up_to_date = status.reason.empty();
    if (status.up_to_date) status.reason = "up to date";
    statuses.push_back(status);
  }
  return statuses;
}

namespace {

// Caps the views a per-view stage runs at once to what the memory budget holds (at least one),
// and notes the budget in the record.
void FitViewsToMemory(const Stage& stage, double memory_limit_mb, StageContext* context, StageRecord* record) {
  const double view_mb = stage.ViewMemoryMb(*context);
  if (view_mb <= 0) return;
  const double budget = memory_limit_mb > 0 ? memory_limit_mb : AvailableMemoryMb();
  if (budget <= 0) return;
  const double remaining = RemainingMemoryMb(memory_limit_mb);
  const int threads = tbb::this_task_arena::max_concurrency();
  const int fit = static_cast<int>(remaining / view_mb);
  context->max_views_in_flight = std::clamp(fit, 1, threads);
  context->view_memory_mb = view_mb;
  context->memory_limit_mb = memory_limit_mb;
  record->memory_budget_mb = budget;
  record->view_memory_mb = view_mb;
  record->views_in_flight = context->max_views_in_flight;
  if (fit < 1) {
    spdlog::warn("[{}] one view needs about {:.0f} MB, more than the {:.0f} MB left of the memory budget ({:.0f} MB); "
                 "running one view at a time (lower max_image_size or the stage's memory parameters, or raise "
                 "--memory-limit)",
                 stage.Name(), view_mb, remaining, budget);
  } else if (fit < threads) {
    spdlog::info("[{}] {} view(s) at a time: about {:.0f} MB each within the {:.0f} MB left of a budget of {:.0f} MB",
                 stage.Name(), context->max_views_in_flight, view_mb, remaining, budget);
  }
}

}  // namespace

bool Runner::Execute(const Stage& stage, StageContext& context, const std::string& key, const nlohmann::json& inputs,
                     const RunOptions& options) {
  TerminalProgress progress(stage.Name(), options.interactive);
  context.progress = &progress;
  context.checkpoint = CheckpointOf(stage, key);

  StageRecord record;
  record.stage = stage.Name();
  record.version = stage.Version();
  record.key = key;
  record.params = context.params.ResultJson(stage.Parameters());
  record.inputs = inputs;
  record.heldout = context.heldout_images;
  record.outputs = stage.Outputs(context);
  record.started = NowIso();
  record.status = "running";
  FitViewsToMemory(stage, options.memory_limit_mb, &context, &record);
  WriteRecord(RecordPath(stage.Name()), record);

  spdlog::info("[{}] running (version {}, params {})", stage.Name(), stage.Version(),
               DumpJson(context.params.ToJson()));
  if (!context.heldout_images.empty()) {
    spdlog::info("[{}] {} held-out views are kept out", stage.Name(), context.heldout_images.size());
  }
  size_t stale = 0;
  for (const std::string& output : record.outputs) stale += RemoveStaleTemporaries(context.workspace.Path(output));
  if (stale > 0) spdlog::info("[{}] removed {} temporary file(s) left by an interrupted run", stage.Name(), stale);
  ResetPeakMemory();
  record.start_memory_mb = ResidentMemoryMb();
  const double child_peak_before = ChildPeakMemoryMb();
  const double cpu_start = CpuSeconds();
  const auto wall_start = std::chrono::steady_clock::now();
  {
    const StageWarnings warnings;
    try {
      stage.Run(context);
      record.status = "ok";
    } catch (const ShardFinished&) {
      record.status = "failed";
      record.error = "internal: a whole-stage run ended as a shard";
    } catch (const std::exception& e) {
      record.status = "failed";
      record.error = e.what();
    }
    record.warnings = warnings.Messages();
    record.warning_count = warnings.Count();
  }
  // Give the heap the stage freed back to the system, so that the next stage's peak carries
  // less of it (Sceaux at 1600 px: score 577 -> 366 MB after render). Not all of it: the
  // full-size castle's render still peaks at 3235 MB after surfels, against 2408 MB alone.
  ReleaseFreeHeap();
  record.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  record.cpu_seconds = CpuSeconds() - cpu_start;
  record.peak_memory_mb = PeakMemoryMb();
  if (ChildPeakMemoryMb() > child_peak_before) record.child_peak_memory_mb = ChildPeakMemoryMb();
  record.metrics = context.metrics;
  if (record.view_memory_mb > 0) record.views_in_flight = context.max_views_in_flight;  // as lowered by the loops
  record.views_resumed = context.views_resumed;
  if (record.status == "ok") {
    WriteRecord(RecordPath(stage.Name()), record);
    context.checkpoint.Clear();
    spdlog::info("[{}] done in {:.2f}s wall, {:.2f}s CPU, peak {:.0f} MB (from {:.0f} MB at the start){}",
                 stage.Name(), record.wall_seconds, record.cpu_seconds, record.peak_memory_mb, record.start_memory_mb,
                 record.child_peak_memory_mb > 0
                     ? fmt::format(" (programs it ran: {:.0f} MB)", record.child_peak_memory_mb)
                     : std::string());
    return true;
  }
  // What the stages before it warned of (their records, cached or just run): the likely cause of
  // a failure on an empty input is upstream.
  std::vector<std::tuple<std::string, std::vector<std::string>, size_t>> upstream;
  for (const StageConfig& earlier : config_.stages) {
    if (earlier.name == stage.Name()) break;
    if (const std::optional<StageRecord> r = ReadRecord(RecordPath(earlier.name)); r && r->status == "ok") {
      upstream.emplace_back(earlier.name, r->warnings, r->warning_count);
    }
  }
  if (const std::string cause = UpstreamWarnings(upstream); !cause.empty()) record.error += " (earlier warnings: " + cause + ")";
  WriteRecord(RecordPath(stage.Name()), record);
  spdlog::error("[{}] failed: {}", stage.Name(), record.error);
  spdlog::error("[{}] outputs of earlier runs are kept; fix the problem and run again", stage.Name());
  return false;
}

namespace {

// Hard links keep a sweep's variants cheap: every write in a workspace is a temporary file renamed
// over the old name, so a linked file is replaced, never changed in place, and the workspace it
// came from keeps its own. Copies where links cannot be made (another file system).
void LinkOrCopy(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::remove_all(to, ec);
  fs::create_directories(to.parent_path());
  fs::copy(from, to, fs::copy_options::recursive | fs::copy_options::create_hard_links, ec);
  if (!ec) return;
  fs::remove_all(to, ec);
  fs::copy(from, to, fs::copy_options::recursive | fs::copy_options::overwrite_existing);
}

}  // namespace

bool Runner::Reuse(const Stage& stage, const StageContext& context, const std::string& key,
                   const std::vector<std::string>& from) const {
  const std::vector<std::string> outputs = stage.Outputs(context);
  for (const std::string& output : outputs) {
    if (fs::path(output).is_absolute()) return false;  // not the workspace's to share
  }
  for (const std::string& other : from) {
    const Workspace source(other);
    std::error_code ec;
    if (fs::equivalent(source.root(), context.workspace.root(), ec)) continue;
    const auto record = ReadRecord(source.RecordsDir() + "/" + stage.Name() + ".json");
    if (!record || record->status != "ok" || record->key != key) continue;
    bool complete = true;
    for (const std::string& output : outputs) complete = complete && fs::exists(Resolve(source, output));
    if (!complete) continue;
    for (const std::string& output : outputs) LinkOrCopy(Resolve(source, output), Resolve(context.workspace, output));
    StageRecord reused = *record;
    if (reused.reused_from.empty()) reused.reused_from = source.root();
    WriteRecord(RecordPath(stage.Name()), reused);
    spdlog::info("[{}] reused from {} (same cache key; it took {:.2f}s there)", stage.Name(), reused.reused_from,
                 reused.wall_seconds);
    return true;
  }
  return false;
}

std::string Runner::ShardableStagesText() const {
  std::string list;
  for (const StageConfig& s : config_.stages) {
    if (registry_.Find(s.name)->Shardable()) list += (list.empty() ? "" : ", ") + s.name;
  }
  return list.empty() ? "no stage of this config is per-view" : "shardable stages: " + list;
}

std::vector<std::string> Runner::ShardViews(const std::string& stage_name) const {
  const StageConfig* stage_config = config_.FindStage(stage_name);
  if (stage_config == nullptr) return {};
  const Stage& stage = *registry_.Find(stage_name);
  if (!stage.Shardable()) return {};
  return stage.ShardViews(MakeContext(stage, *stage_config));
}

bool Runner::SelectStages(const RunOptions& options, std::vector<size_t>* selected) const {
  auto index_of = [&](const std::string& name) -> int {
    for (size_t i = 0; i < config_.stages.size(); ++i) {
      if (config_.stages[i].name == name) return static_cast<int>(i);
    }
    return -1;
  };
  for (const std::string* name : {&options.only, &options.from, &options.to}) {
    if (!name->empty() && index_of(*name) < 0) {
      std::string list;
      for (const auto& s : config_.stages) list += (list.empty() ? "" : ", ") + s.name;
      spdlog::error("stage '{}' is not in {} (stages: {})", *name, config_.path, list);
      return false;
    }
  }
  if (!options.only.empty() && (!options.from.empty() || !options.to.empty())) {
    // Either would silently widen or narrow what --only asked for.
    spdlog::error("--only '{}' with --from/--to: use --only alone, or --from/--to", options.only);
    return false;
  }
  int first = 0;
  int last = static_cast<int>(config_.stages.size()) - 1;
  if (!options.only.empty()) first = last = index_of(options.only);
  if (!options.from.empty()) first = index_of(options.from);
  if (!options.to.empty()) last = index_of(options.to);

  selected->clear();
  for (int i = first; i <= last; ++i) selected->push_back(static_cast<size_t>(i));
  if (selected->empty()) {
    spdlog::error("no stage of {} is selected (--from '{}' comes after --to '{}')", config_.path, options.from,
                  options.to);
    return false;
  }
  return true;
}

double Runner::ViewMemoryMb(const std::string& stage_name) const {
  const StageConfig* stage_config = config_.FindStage(stage_name);
  if (stage_config == nullptr) return 0;
  const Stage& stage = *registry_.Find(stage_name);
  return stage.ViewMemoryMb(MakeContext(stage, *stage_config));
}

std::vector<std::string> Runner::UnfinishedViews(const std::string& stage_name) const {
  const StageConfig* stage_config = config_.FindStage(stage_name);
  if (stage_config == nullptr) return {};
  PlanUpTo(static_cast<size_t>(stage_config - config_.stages.data()));  // the key a run would compute
  const Stage& stage = *registry_.Find(stage_name);
  const StageContext context = MakeContext(stage, *stage_config);
  nlohmann::json inputs;
  const ViewCheckpoint checkpoint = CheckpointOf(stage, CacheKey(stage, context, &inputs));
  std::vector<std::string> unfinished;
  for (const std::string& view : ShardViews(stage_name)) {
    if (!checkpoint.Done(view)) unfinished.push_back(view);
  }
  return unfinished;
}

void Runner::PlanUpTo(size_t index) const {
  skipped_outputs_.clear();
  shapes_.clear();
  LoadRaceSkips();
  for (size_t j = 0; j < index && j < config_.stages.size(); ++j) {
    if (const std::string skip = SkipReason(j); !skip.empty()) {
      const Stage& stage = *registry_.Find(config_.stages[j].name);
      Skip(j, MakeContext(stage, config_.stages[j]), "", skip, false);
    }
  }
}

std::string Runner::Staleness(size_t index) const {
  PlanUpTo(index);
  if (!SkipReason(index).empty()) return "";  // the plan skips it: nothing to run
  const Stage& stage = *registry_.Find(config_.stages.at(index).name);
  const StageContext context = MakeContext(stage, config_.stages[index]);
  nlohmann::json inputs;
  return OwnStaleness(stage, context, CacheKey(stage, context, &inputs));
}

int Runner::RunShard(const RunOptions& options) {
  const StageConfig* stage_config = config_.FindStage(options.only);
  if (options.only.empty() || stage_config == nullptr) {
    spdlog::error("--views needs --only STAGE naming a stage of {}", config_.path);
    return 2;
  }
  const Stage& stage = *registry_.Find(options.only);
  if (!stage.Shardable()) {
    spdlog::error("[{}] has no per-view shards; run it without --views ({})", stage.Name(), ShardableStagesText());
    return 2;
  }
  const size_t index = static_cast<size_t>(stage_config - config_.stages.data());
  PlanUpTo(index);  // the stages the plan skips before it, as a whole run sees them
  if (const std::string skip = SkipReason(index); !skip.empty()) {
    spdlog::info("[{}] {}: the shard has nothing to do", stage.Name(), skip);
    return 0;
  }
  std::unique_ptr<tbb::global_control> threads;
  if (options.jobs > 0) {
    threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, options.jobs);
  }
  StageContext context = MakeContext(stage, *stage_config);
  nlohmann::json inputs;
  const std::string key = CacheKey(stage, context, &inputs);
  if (!options.force && OwnStaleness(stage, context, key).empty()) {
    spdlog::info("[{}] up to date: the shard has nothing to do", stage.Name());
    return 0;
  }
  if (options.dry_run) {
    spdlog::info("[{}] would compute views {}", stage.Name(), fmt::join(options.views, ", "));
    return 0;
  }
  fs::create_directories(context.workspace.RecordsDir());
  StageLock lock;  // shared: other shards may run beside this one, a whole run or a merge may not
  std::string holder;
  if (!lock.TryLock(LockPath(stage.Name()), false, &holder)) {
    spdlog::error("[{}] a whole run of the stage (or the merge of its shards) is running in another ibmr process "
                  "on workspace {} ({}); run the shard when it has finished",
                  stage.Name(), config_.workspace, holder);
    return 1;
  }
  if (!options.force && Finished(stage, context, key)) {  // a merge finished meanwhile
    spdlog::info("[{}] up to date: the shard has nothing to do", stage.Name());
    return 0;
  }
  // No record and no clean-up of temporaries here: other shards of the stage may be writing now.
  // Both belong to the merge.
  TerminalProgress progress(stage.Name() + " shard", options.interactive);
  context.progress = &progress;
  context.checkpoint = CheckpointOf(stage, key);
  context.shard_views.insert(options.views.begin(), options.views.end());
  StageRecord unused;  // a shard writes no record
  FitViewsToMemory(stage, options.memory_limit_mb, &context, &unused);
  const auto wall_start = std::chrono::steady_clock::now();
  try {
    stage.Run(context);
    spdlog::error("[{}] ended without reaching its per-view work; the shard did nothing", stage.Name());
    return 1;
  } catch (const ShardFinished& done) {
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
    spdlog::info("[{}] shard: {} view(s) computed, {} already done, in {:.2f}s, peak {:.0f} MB; run the stage "
                 "without --views to merge",
                 stage.Name(), done.computed, done.resumed, seconds, PeakMemoryMb());
    return 0;
  } catch (const std::exception& e) {
    spdlog::error("[{}] shard failed: {}", stage.Name(), e.what());
    return 1;
  }
}

void Runner::RunRaceAfter(size_t model_stage, const RunOptions& options) {
  const Workspace model = WorkspaceAfter(model_stage);
  std::set<std::string> heldout;
  if (config_.holdout.Active()) {
    const std::vector<std::string> names = SortedImageNames(model);
    heldout = config_.holdout.Select(names, config_.holdout.split.empty() ? ImageSplits() : ReadImageSplits(model));
  }
  const std::optional<CaptureShape> shape = CaptureIn(model);
  const RaceOutcome outcome =
      RunRace(config_, registry_, model_stage, model, heldout, shape ? shape->kind : "", options);
  nlohmann::json race = {{"scale", config_.plan.race.scale},
                         {"validation_every", config_.plan.race.validation_every},
                         {"margin_db", config_.plan.race.margin_db},
                         {"metric", config_.plan.race.metric},
                         {"workspace", "race"},
                         {"validation", outcome.validation},
                         {"seconds", outcome.seconds}};
  if (!outcome.ok) {  // race.json without left_out: every stage runs
    spdlog::warn("race: no verdict ({}); every stage runs", outcome.problem);
    race["problem"] = outcome.problem;
    WriteFileAtomic(Workspace(config_.workspace).Path("race.json"), DumpJson(race, 2) + "\n");
    return;
  }
  race["models"] = outcome.scores;
  race["best"] = outcome.best;
  race["winners"] = outcome.winners;
  // Which models each stage after the model stage feeds: the stages a drawn model's inputs come
  // from, and the stages those read from, after the model stage.
  std::map<size_t, std::set<std::string>> feeds;
  for (size_t r = model_stage + 1; r < config_.stages.size(); ++r) {
    const Stage& drawer = *registry_.Find(config_.stages[r].name);
    const StageContext context = MakeContext(drawer, config_.stages[r]);
    for (const DrawnModel& drawn : drawer.DrawsModels(context)) {
      std::vector<size_t> queue;
      for (size_t j = model_stage + 1; j < r; ++j) {
        for (const std::string& output : DeclaredOutputs(j)) {
          for (const std::string& input : drawn.inputs) {
            if (Overlaps(Resolve(context.workspace, input), Resolve(context.workspace, output))) queue.push_back(j);
          }
        }
      }
      std::set<size_t> producers;
      while (!queue.empty()) {
        const size_t j = queue.back();
        queue.pop_back();
        if (!producers.insert(j).second) continue;
        for (size_t k : Upstream(j)) {
          if (k > model_stage) queue.push_back(k);
        }
      }
      for (size_t j : producers) feeds[j].insert(drawn.name);
    }
  }
  nlohmann::json left_out = nlohmann::json::array();
  double saved = 0;
  const double pixel_ratio = config_.plan.race.scale * config_.plan.race.scale;
  for (const auto& [j, models] : feeds) {
    bool needed = false;
    std::string scored;
    for (const std::string& name : models) {
      const auto score = outcome.scores.find(name);
      needed |= score == outcome.scores.end() || outcome.winners.count(name) > 0;  // unscored: kept
      if (score != outcome.scores.end()) scored += fmt::format("{}{} {:.2f} dB", scored.empty() ? "" : ", ", name, score->second);
    }
    if (needed) continue;
    const std::string& name = config_.stages[j].name;
    const std::string reason = fmt::format("{}: skipped, the race left it out: the models drawn from it scored {} at {}x size, more "
                                 "than {} dB below {}'s {:.2f} dB (race.json); --with {} runs it",
                                 name, scored, config_.plan.race.scale, config_.plan.race.margin_db, outcome.best,
                                 outcome.best_score, name);
    const auto seconds = outcome.stage_seconds.find(name);
    const double race_seconds = seconds == outcome.stage_seconds.end() ? 0 : seconds->second;
    left_out.push_back({{"stage", name}, {"models", models}, {"race_seconds", race_seconds},
                        {"estimated_full_seconds", race_seconds / pixel_ratio}, {"reason", reason}});
    saved += race_seconds / pixel_ratio;
  }
  race["left_out"] = left_out;
  race["estimated_saving_seconds"] = saved;
  spdlog::info("race: {} best with {:.2f} dB ({}), {} model(s) within {} dB; {} stage(s) left out, saving about {:.0f} s "
               "at full size (estimated from the race's times); the race took {:.1f} s",
               outcome.best, outcome.best_score, config_.plan.race.metric, outcome.winners.size(),
               config_.plan.race.margin_db, left_out.size(), saved, outcome.seconds);
  WriteFileAtomic(Workspace(config_.workspace).Path("race.json"), DumpJson(race, 2) + "\n");
}

void Runner::LoadRaceSkips() const {
  race_skips_.clear();
  race_losers_.clear();
  if (!config_.plan.race.enabled) return;
  const nlohmann::json race = ReadJsonOr(Workspace(config_.workspace).Path("race.json"), nlohmann::json());
  if (race.is_object() && race.contains("models") && race["models"].is_object() && race.contains("winners") &&
      race.contains("best") && race["best"].is_string()) {
    const nlohmann::json& models = race["models"];
    const std::string best = race["best"];
    for (auto it = models.begin(); it != models.end(); ++it) {
      if (!it.value().is_number() || !models.contains(best)) continue;
      bool winner = false;
      for (const nlohmann::json& w : race["winners"]) winner |= w == it.key();
      if (!winner) {
        race_losers_[it.key()] = fmt::format("the race left it out: {:.2f} dB at {}x size, more than {} dB below {}'s {:.2f} dB (race.json)",
                                             it.value().get<double>(), race.value("scale", 0.0), race.value("margin_db", 0.0),
                                             best, models[best].get<double>());
      }
    }
  }
  if (!race.is_object() || !race.contains("left_out") || !race["left_out"].is_array()) return;
  const auto& with = config_.plan.with;
  if (std::find(with.begin(), with.end(), "all") != with.end()) race_losers_.clear();  // --with all: every model
  for (const nlohmann::json& entry : race["left_out"]) {
    if (!entry.is_object() || !entry.contains("stage") || !entry.contains("reason")) continue;
    if (config_.plan.Forces(entry["stage"].get<std::string>()) && entry.contains("models")) {
      for (const nlohmann::json& model : entry["models"]) race_losers_.erase(model.get<std::string>());  // --with STAGE draws its models
    }
    for (size_t i = 0; i < config_.stages.size(); ++i) {
      if (config_.stages[i].name == entry["stage"]) race_skips_[i] = entry["reason"].get<std::string>();
    }
  }
}

int Runner::Run(const RunOptions& options) {
  if (!options.views.empty()) return RunShard(options);
  const auto start = std::chrono::steady_clock::now();
  std::vector<size_t> selected;
  if (!SelectStages(options, &selected)) return 2;
  const int first = static_cast<int>(selected.front()), last = static_cast<int>(selected.back());

  std::unique_ptr<tbb::global_control> threads;
  if (options.jobs > 0) {
    threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, options.jobs);
  }
  // A dry run changes nothing, not even an empty records/ in a workspace that is not there yet.
  if (!options.dry_run) fs::create_directories(Workspace(config_.workspace).RecordsDir());

  int ran = 0;
  std::vector<bool> stale_before(config_.stages.size(), false);
  skipped_outputs_.clear();
  shapes_.clear();
  write_capture_ = !options.dry_run;
  // The race runs after the last stage that writes the model, in a whole run of the config.
  int model_stage = -1;
  for (size_t i = 0; i < config_.stages.size(); ++i) {
    if (!registry_.Find(config_.stages[i].name)->WritesModel().sparse.empty()) model_stage = static_cast<int>(i);
  }
  const bool whole_run = options.only.empty() && options.from.empty() && options.to.empty();
  if (config_.plan.race.enabled && !whole_run) {
    spdlog::info("race: not run with --only, --from or --to; an earlier race's verdict (race.json) holds");
  }
  const bool race_due = config_.plan.race.enabled && whole_run && !options.dry_run && model_stage >= 0 &&
                        model_stage + 1 < static_cast<int>(config_.stages.size());
  if (config_.plan.race.enabled && whole_run && options.dry_run && model_stage >= 0) {
    spdlog::info("race: would run after {} at {}x size (WORKSPACE/race); the stages it leaves out are known then",
                 config_.stages[model_stage].name, config_.plan.race.scale);
  }
  LoadRaceSkips();  // an earlier race's verdict, for the stages before this run's race (or without one)
  for (int i = 0; i < static_cast<int>(config_.stages.size()); ++i) {
    if (race_due && i == model_stage + 1) {
      RunRaceAfter(static_cast<size_t>(model_stage), options);
      LoadRaceSkips();
    }
    const Stage& stage = *registry_.Find(config_.stages[i].name);
    StageContext context = MakeContext(stage, config_.stages[i]);
    nlohmann::json inputs;
    const std::string key = CacheKey(stage, context, &inputs);
    const bool in_selection = i >= first && i <= last;
    CaptureOf(i);  // capture.json and the log's line as soon as poses exist, whatever runs
    if (const std::string skip = SkipReason(i); !skip.empty()) {
      if (in_selection && options.dry_run) spdlog::info("[{}] would be skipped: {}", stage.Name(), skip);
      Skip(i, context, key, skip, in_selection && !options.dry_run);
      continue;
    }
    if (options.dry_run && in_selection && !stage.Serves().kinds.empty() && !CaptureOf(i) &&
        !config_.plan.Forces(stage.Name())) {
      spdlog::info("[{}] serves {} captures only: whether it runs is known once the poses are (capture.json)",
                   stage.Name(), fmt::join(stage.Serves().kinds, ", "));
    }
    std::string reason = OwnStaleness(stage, context, key);
    if (reason.empty() && options.dry_run) {
      for (size_t j : Upstream(i)) {
        if (stale_before[j]) reason = "upstream stage '" + config_.stages[j].name + "' will run";
      }
    }
    const bool selected = i >= first && i <= last;
    if (selected && options.force && reason.empty()) reason = "--force";
    stale_before[i] = !reason.empty() && selected;
    if (!selected) {
      if (!reason.empty() && i < first) spdlog::warn("[{}] is stale ({}) but not selected", stage.Name(), reason);
      continue;
    }
    if (reason.empty()) {
      spdlog::info("[{}] up to date", stage.Name());
      continue;
    }
    if (options.dry_run) {
      spdlog::info("[{}] would run: {}", stage.Name(), reason);
      continue;
    }
    StageLock lock;
    std::string holder;
    if (!lock.TryLock(LockPath(stage.Name()), true, &holder)) {
      spdlog::error("[{}] is running in another ibmr process on workspace {} ({}); wait for it to finish "
                    "('ibmr status' shows it) or stop that process, then run again",
                    stage.Name(), config_.workspace, holder);
      return 1;
    }
    // Decided before the lock: another process may have run the stage in between.
    if (!options.force && Finished(stage, context, key)) {
      spdlog::info("[{}] up to date (another process has just run it)", stage.Name());
      continue;
    }
    if (!options.force && !options.reuse_from.empty() && Reuse(stage, context, key, options.reuse_from)) continue;
    spdlog::info("[{}] runs: {}", stage.Name(), reason);
    ++ran;
    if (!Execute(stage, context, key, inputs, options)) return 1;
    if (!stage.WritesModel().sparse.empty()) {  // a new model: its capture analysed again, now
      shapes_.clear();
      CaptureIn(WorkspaceAfter(i));
    }
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (options.dry_run) {
    spdlog::info("dry run: nothing was changed ({:.2f}s)", seconds);
  } else if (ran == 0) {
    spdlog::info("nothing to do: all selected stages are up to date ({:.2f}s)", seconds);
  } else {
    spdlog::info("{} stage(s) ran in {:.1f}s; workspace {}", ran, seconds, config_.workspace);
  }
  return 0;
}

}  // namespace ibmr
