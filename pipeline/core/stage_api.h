// The contract between a stage and the runner. A stage (stages/<name>/<name>_stage.cc) declares
// its parameters, inputs and outputs, checks parameter values, and runs on a StageContext. The
// runner owns config parsing, caching, records, holdout, progress display and logs; the stage
// only calls the context. Stages register themselves through `RegisterStage_<name>(registry)`,
// which the build calls from a generated list, so pipeline/runner names no stage.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "pipeline/core/params.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/sparse_model.h"
#include "pipeline/core/view_checkpoint.h"
#include "pipeline/core/workspace.h"

namespace ibmr {

// How a stage treats held-out views (the config's holdout policy).
enum class HoldoutRole {
  kAllViews,       // import, synth: sees every view; the holdout set does not affect it
  kTrainingOnly,   // reconstruction (silhouettes, carving, stereo, fusion, texturing): never sees held-out views
  kScoring,        // render/score: reads the trained model and the held-out views' cameras and photos
};

struct StageContext {
  Workspace workspace;
  Params params;
  std::string config_dir;                  // folder of the config file (relative paths resolve here)
  std::map<std::string, std::string> inputs;  // the config's named inputs (absolute paths)
  HoldoutRole role = HoldoutRole::kAllViews;
  std::set<std::string> heldout_images;    // names of held-out images (empty: no holdout)
  // kScoring: the held-out views to draw and score, where the holdout policy scores a subset of
  // them (holdout: {split: test, every: 8}); empty: every held-out view.
  std::set<std::string> scored_heldout;
  ProgressReporter* progress = nullptr;    // never null while running
  ViewCheckpoint checkpoint;               // per-view resumption for this run's cache key
  nlohmann::json metrics = nlohmann::json::object();  // the stage's own metrics, kept in the record
  int num_threads = -1;                    // -1: all cores
  // A shard run (`ibmr run CONFIG --only STAGE --views NAMES`): the stage's per-view loop computes
  // just these views, marks them done with their pieces, and ends the stage there (ShardFinished);
  // the merge, a run without a shard, aggregates. Empty: the whole stage.
  std::set<std::string> shard_views;
  size_t views_resumed = 0;                // views the per-view loops found already done (for the record)
  // Views ForEachView works on at once (each with all threads' help), so that their memory fits
  // the run's budget; 0: as many as there are threads. ForEachView lowers it when what the stage
  // already holds (a model loaded before its per-view loop) leaves room for fewer.
  int max_views_in_flight = 0;
  // The budget behind it: the stage's estimate of one view (Stage::ViewMemoryMb; 0: none), and
  // the process's limit (--memory-limit; 0: what the system has available).
  double view_memory_mb = 0;
  double memory_limit_mb = 0;

  // Outputs of the stages the run's plan skipped (Stage::Serves: the capture's kind is not one
  // their model serves), absolute paths, each with the one-line reason. A stage that reads one
  // finds it absent, or left by an earlier run, and must not use it (render drops the model).
  std::map<std::string, std::string> skipped_outputs;
  // The reason when `path` (workspace-relative or absolute) is, or lies inside, a skipped output;
  // nullptr otherwise.
  const std::string* SkippedBy(const std::string& path) const;
  // Models (DrawnModel names) the run's race found more than its margin below the best, with the
  // reason: a stage that draws models leaves them out (render draws the background model anyway).
  std::map<std::string, std::string> left_out_models;

  bool IsHeldOut(const std::string& image_name) const { return heldout_images.count(image_name) > 0; }
  // Reads the workspace's model (SparseDir). For kTrainingOnly stages the held-out images are removed (and their
  // observations from the tracks), which is how the runner keeps them out of reconstruction.
  SparseModel LoadModel() const;
  // Names of the views this stage may reconstruct from, sorted (held-out views removed for
  // kTrainingOnly stages).
  std::vector<std::string> TrainingImageNames(const SparseModel& model) const;
  // The same from the workspace's model, or empty when it is missing or unreadable: for declaring
  // per-view inputs before the stage runs (Run() then reports the problem).
  std::vector<std::string> TrainingImageNamesIfReadable() const;
};

// The capture kinds (pipeline/core/capture_shape.h: forward_facing, object, general) a stage's
// model can serve, and why, for the run's plan: the runner skips a stage whose kinds leave out the
// capture's (capture.json) unless the config's `plan.with` or `--with` names it. Empty kinds: every
// capture.
struct CaptureUse {
  std::vector<std::string> kinds;
  std::string why;  // "volumes of fronto-parallel planes sample forward-facing captures only"
};

// A model a stage draws (render: one per entry of render.proxies) and the files it is drawn from
// (workspace-relative), for the run's race (plan.race): the stages whose outputs only losing
// models are drawn from are left out of the full-size run.
struct DrawnModel {
  std::string name;
  std::vector<std::string> inputs;
};

class Stage {
 public:
  virtual ~Stage() = default;
  virtual std::string Name() const = 0;
  virtual std::string Summary() const = 0;  // one line for `ibmr stages`
  // Bump when the code's results change: a new version makes the stage and all downstream stale.
  virtual std::string Version() const = 0;
  virtual std::vector<ParamSpec> Parameters() const = 0;
  virtual HoldoutRole Role() const = 0;
  // Maps params to the stage's Options and calls their Check(); nullopt when valid.
  virtual std::optional<ParamError> CheckParams(const Params& params) const = 0;
  // Files or folders read and written: workspace-relative ("sparse") or absolute (external input).
  // Inputs are hashed for the cache; an optional input that does not exist hashes as "missing".
  virtual std::vector<std::string> Inputs(const StageContext& context) const = 0;
  virtual std::vector<std::string> Outputs(const StageContext& context) const = 0;
  // The model and images folders (workspace-relative, among its outputs) this stage leaves for the
  // stages after it to read (Workspace::SparseDir, ImagesDir); an empty member leaves that folder
  // as it was. Import: sparse, images; sfm: sfm/sparse; undistort: dense/sparse, dense/images.
  struct ModelFolders {
    std::string sparse, images;
  };
  virtual ModelFolders WritesModel() const { return {}; }
  // The captures the stage's model can serve (see CaptureUse). Default: every capture.
  virtual CaptureUse Serves() const { return {}; }
  // True when the stage cannot run without the outputs of a stage the plan skipped (carve without
  // the silhouettes' masks): it is skipped with it, naming the reason. False (the default): it
  // reads what it finds, as with any optional input (plane_sweep without a hull; render drops the
  // models made by skipped stages, see StageContext::SkippedBy).
  virtual bool SkippedWithItsInputs() const { return false; }
  // The models the stage draws and scores, each with its inputs (see DrawnModel). Default: none.
  virtual std::vector<DrawnModel> DrawsModels(const StageContext&) const { return {}; }
  // Does the work. Throws IoError / InputError with a message for the user on failure.
  virtual void Run(StageContext& context) const = 0;
  // True when shards of the stage's views may run as separate processes or cluster jobs (`--views`,
  // `ibmr export snakemake`, `--executor slurm`): its per-view work runs in ForEachView, and what
  // it writes outside that work comes after it, in the merge. Typically one ForEachView over the
  // training views (ShardFinished ends a shard there); a stage with several loops ends its shards
  // itself (render).
  virtual bool Shardable() const { return false; }
  // The views a shard names (`--views`), sorted: by default the training views.
  virtual std::vector<std::string> ShardViews(const StageContext& context) const {
    return context.TrainingImageNamesIfReadable();
  }
  // Peak memory of one view's work, MB, estimated from the inputs (image sizes) and parameters:
  // what a cluster job for one view asks for (`--executor slurm`, the Snakefile's mem_mb). 0: no
  // estimate (the inputs are not there yet, or the stage has none).
  virtual double ViewMemoryMb(const StageContext&) const { return 0; }
};

// A command a stage offers beside `ibmr run` (e.g. `ibmr stereo-pair LEFT RIGHT ...`). It gets
// the arguments after its name, parses them itself (--help included) and returns an exit code.
struct StageCommand {
  std::string name;
  std::string help;
  std::function<int(const std::vector<std::string>& args)> main;
};

// The largest camera (most pixels) among the training views of the workspace's model; 0 x 0 when
// it is missing or unreadable (for estimates made before the stage runs).
struct ImageSize {
  int width = 0, height = 0;
  double Pixels() const { return static_cast<double>(width) * height; }
};
ImageSize LargestTrainingImage(const StageContext& context);

class StageRegistry {
 public:
  void Add(std::unique_ptr<Stage> stage);
  void AddCommand(StageCommand command) { commands_.push_back(std::move(command)); }
  const Stage* Find(const std::string& name) const;  // nullptr when unknown
  std::vector<std::string> Names() const;
  const std::vector<StageCommand>& Commands() const { return commands_; }

 private:
  std::vector<std::unique_ptr<Stage>> stages_;
  std::vector<StageCommand> commands_;
};

}  // namespace ibmr
