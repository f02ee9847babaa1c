// Runs a config's stages in order with a content-hash cache. A stage runs again only when its
// cache key changes: code version, result-affecting parameters, the holdout set (for stages that
// respect it) or the content hash of an input file. Stages that depend on a stale stage (their
// inputs overlap its outputs) are stale too. Each run leaves records/<stage>.json.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/core/capture_shape.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/runner/config.h"

namespace ibmr {

struct StageRecord;  // record.h

struct RunOptions {
  std::string only;   // run just this stage
  std::string from;   // run this stage and all after it
  std::string to;     // run up to and including this stage
  bool force = false; // run the selected stages even when up to date
  bool dry_run = false;
  int jobs = -1;      // TBB threads; -1: all cores
  // Memory the views in flight of a per-view stage may take together, MB (Stage::ViewMemoryMb
  // each); 0: what the system has available when the stage starts.
  double memory_limit_mb = 0;
  bool interactive = false;  // draw progress bars (stderr is a terminal)
  // Other workspaces (a sweep's earlier variants): a stale stage whose cache key matches an ok
  // record there gets that workspace's outputs hard-linked (or copied) in instead of running.
  std::vector<std::string> reuse_from;
  // A shard: with `only` naming a shardable stage, compute just these of its views (their outputs
  // and per-view marks; no record). A later run of the stage without `views` merges.
  std::vector<std::string> views;
};

struct StageStatus {
  std::string name;
  bool up_to_date = false;
  std::string reason;  // why stale, or "up to date", or why the plan skips it
  bool skipped = false;  // the plan skips it (Runner::SkipReason)
};

class Runner {
 public:
  Runner(Config config, const StageRegistry& registry) : config_(std::move(config)), registry_(registry) {}

  // "shardable stages: a, b" of this config, for messages.
  std::string ShardableStagesText() const;
  // The views a shardable stage works on (Stage::ShardViews, once its inputs exist), sorted.
  std::vector<std::string> ShardViews(const std::string& stage) const;
  // The stage's estimate of one view's peak memory, MB (Stage::ViewMemoryMb); 0: none.
  double ViewMemoryMb(const std::string& stage) const;
  // Of those, the ones not yet marked done under the stage's current cache key.
  std::vector<std::string> UnfinishedViews(const std::string& stage) const;
  // Why the config's stage `index` would run (its own staleness, as Run decides); "" when up to date.
  std::string Staleness(size_t index) const;
  // The config's stage indices that `options` selects (--only, --from, --to); false, with the
  // problem logged, when one names a stage the config does not have or --only comes with --from/--to.
  bool SelectStages(const RunOptions& options, std::vector<size_t>* selected) const;
  // Indices of the earlier stages whose outputs a stage reads.
  std::vector<size_t> Upstream(size_t index) const;
  // A stage's declared inputs and outputs in this config (see Stage::Inputs / Outputs).
  std::vector<std::string> DeclaredInputs(size_t index) const;
  std::vector<std::string> DeclaredOutputs(size_t index) const;
  const Config& config() const { return config_; }
  const StageRegistry& registry() const { return registry_; }

  // One writer per file: the problem when two stages of the config declare the same output (or
  // one inside the other), naming both and the path; "" when none do.
  std::string SharedOutputs() const;
  // What is up to date and what is stale, and why (no work done).
  std::vector<StageStatus> Status() const;
  // The plan: why config stage `index` is skipped (its model cannot serve the capture's kind, or
  // it needs a skipped stage's outputs), "" when it runs. Decided from the capture's shape as the
  // model the stage reads shows it, and the stages skipped before it (in this run, or as Status
  // walks the config).
  std::string SkipReason(size_t index) const;
  // The shape of the capture as the model of config stage `index` shows it, analysed once per
  // model folder and run and written to capture.json when it changed; nullopt before that model
  // exists. plan.kind, when not auto, replaces the kind.
  std::optional<CaptureShape> CaptureOf(size_t index) const;
  // Runs the selected stale stages. Returns 0 on success, 1 when a stage failed, 2 on a usage error.
  int Run(const RunOptions& options);

 private:
  StageContext MakeContext(const Stage& stage, const StageConfig& stage_config) const;
  // The workspace with the model and images folders the stage reads (those of the last stage
  // before it that writes them, Stage::WritesModel).
  Workspace WorkspaceBefore(const StageConfig& stage_config) const;
  // The same after config stage `index` (its own model folders applied).
  Workspace WorkspaceAfter(size_t index) const;
  // The workspace with the model folders of the first `stages` config stages applied.
  Workspace ModelWorkspace(size_t stages) const;
  // CaptureOf for the model folder `workspace` reads.
  std::optional<CaptureShape> CaptureIn(const Workspace& workspace) const;
  // `params_override`: the parameters' JSON to key instead of the context's (KeyMatches).
  std::string CacheKey(const Stage& stage, const StageContext& context, nlohmann::json* input_hashes,
                       const nlohmann::json* params_override = nullptr) const;
  // `key` is the record's, or differs from it only by parameters the record lacks that are at
  // their defaults (a parameter added since the record's run).
  bool KeyMatches(const Stage& stage, const StageContext& context, const std::string& key,
                  const StageRecord& record) const;
  // Own staleness of one stage, ignoring upstream; "" when up to date.
  std::string OwnStaleness(const Stage& stage, const StageContext& context, const std::string& key) const;
  // "output 'x' is missing" for the first declared output not there, else "".
  std::string MissingOutput(const Stage& stage, const StageContext& context) const;
  // The record shows a finished run with cache key `key` and the outputs are there: the check a
  // run repeats once it holds the stage's lock, without hashing the inputs again.
  bool Finished(const Stage& stage, const StageContext& context, const std::string& key) const;
  std::string RecordPath(const std::string& stage) const;
  // records/<stage>.lock: see stage_lock.h.
  std::string LockPath(const std::string& stage) const;
  // The per-view marks of a stage's run with cache key `key` (records/<stage>.views/).
  ViewCheckpoint CheckpointOf(const Stage& stage, const std::string& key) const;
  bool Execute(const Stage& stage, StageContext& context, const std::string& key, const nlohmann::json& inputs,
               const RunOptions& options);
  // Runs the shard `options.views` of the stage `options.only` (see RunOptions::views).
  int RunShard(const RunOptions& options);
  // Links in the outputs of `stage` from the first workspace of `from` whose record has `key`;
  // false when none has.
  bool Reuse(const Stage& stage, const StageContext& context, const std::string& key,
             const std::vector<std::string>& from) const;

  // Skips stage `index` for `reason`: adds its outputs to skipped_outputs_ and, with
  // `write_record`, records it (status "skipped") unless its record already says so under `key`.
  void Skip(size_t index, const StageContext& context, const std::string& key, const std::string& reason,
            bool write_record) const;

  // The race (plan.race, race.h) after config stage `model_stage`, the last that writes the model:
  // runs it, fills race_skips_ and writes race.json. Logs and goes on without a verdict when the
  // race cannot give one.
  void RunRaceAfter(size_t model_stage, const RunOptions& options);
  // race_skips_ from race.json's verdict (none without plan.race or a race.json).
  void LoadRaceSkips() const;
  // The plan's state (skipped_outputs_, race_skips_) as a whole run has it when it reaches config
  // stage `index`, decided from what is on disk; writes nothing.
  void PlanUpTo(size_t index) const;

  Config config_;
  const StageRegistry& registry_;
  // Config stages the race left out of this run, with the reason (SkipReason).
  mutable std::map<size_t, std::string> race_skips_;
  // Models the race found below its margin, with the reason (StageContext::left_out_models).
  mutable std::map<std::string, std::string> race_losers_;
  // CaptureIn writes capture.json (a run that is not a dry run); status and dry runs only look.
  mutable bool write_capture_ = false;
  // Per model folder (absolute): the capture's shape, analysed once per run (nullopt: no model yet).
  mutable std::map<std::string, std::optional<CaptureShape>> shapes_;
  // Outputs (absolute) of the stages skipped so far, with the reason (StageContext::skipped_outputs).
  mutable std::map<std::string, std::string> skipped_outputs_;
};

}  // namespace ibmr
