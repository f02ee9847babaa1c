// The run configuration (YAML): workspace, named inputs, holdout policy and the ordered stages
// with their parameters. Paths are relative to the config file; ${VAR:-default} expands from
// the environment (a ${VAR} without default that is not set is an error). Every error names the
// file, the line and the key, says what was expected, and suggests the nearest valid key for a
// misspelt one.
//
//   workspace: ${IBMR_WORKSPACE:-../workspaces/demo}
//   inputs:            # named paths stages may read (import's default source is inputs.images)
//     images: ../data/temple
//   holdout:           # views kept out of every reconstruction stage, scored by `score`
//     every: 8         # every 8th view of the sorted image list, starting at `offset`
//     offset: 0
//     images: [a.png]  # and/or explicit names
//     split: test      # or: every image of the capture's test split (import's splits.json, NeRF's
//                      # Blender layout); `every`/`offset` then pick the views scored among them,
//                      # the others kept out of every stage but import
//   plan:              # optional: see RunPlan (what the capture's kind leaves out, the race)
//     with: [volume]
//   stages:
//     - synth: {scene: object_ring, views: 24}
//     - carve:
//         levels: 7
#pragma once

#include <algorithm>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "pipeline/core/params.h"
#include "pipeline/core/stage_api.h"

namespace ibmr {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct HoldoutPolicy {
  int every = 0;   // 0: no periodic holdout
  int offset = 0;  // first held-out index in the sorted image list (of the split's, with `split`)
  std::vector<std::string> images;
  std::vector<int> image_lines;  // 1-based config line of each of `images` (0: not from a file)
  std::string split;             // "": none; else every image of this split is held out
  int split_line = 0;

  bool Active() const { return every > 0 || !images.empty() || !split.empty(); }
  // The held-out subset of `sorted_names`; `splits` (name -> split) is used with `split`.
  std::set<std::string> Select(const std::vector<std::string>& sorted_names,
                               const std::map<std::string, std::string>& splits = {}) const;
  // The held-out views render draws and score scores: with `split` and `every`, every `every`-th
  // of the split's sorted images from `offset` (and the named `images`); empty: all held-out views.
  std::set<std::string> Scored(const std::vector<std::string>& sorted_names,
                               const std::map<std::string, std::string>& splits) const;
  std::string Describe() const;
};

struct StageConfig {
  std::string name;
  Params params;       // every declared key, defaults filled in
  int line = 0;        // 1-based line of the stage entry
  std::map<std::string, int> key_lines;  // 1-based line of each key given in the file
};

// What `ibmr sweep` runs when the config says (its optional `sweep:` block; `ibmr run` ignores it):
//   sweep:
//     vary: {synth.strength: [0.25, 0.5], synth.degradation: [specular, exposure]}   # crossed
//     variants: ["synth.degradation=none"]                                         # listed
//     metric: photo_psnr
//     stability:                       # a stability matrix over (degradation, strength)
//       degradation: synth.degradation # the varied key naming the degradation (or a list of keys)
//       strength: synth.strength       # the varied key giving its strength (a list: one per key)
//       methods:                       # what each method's error and confidence are
//         - {name: stereo, metric: multi_depth.geometric_within_1pct_of_textured, higher_is_better: true,
//            confidence: multi_depth.geometric_confidence_error_spearman,
//            sparsification: multi_depth.geometric_sparsification_auc_ratio}
//         - {name: surfel mesh held out, metric: models.surfels.photo_psnr, higher_is_better: true}
//       detectors:                     # optional: what calls failures out (StabilityDetector)
// A metric is "stage.key" (a number in records/<stage>.json's metrics) or "models.NAME.key" (a
// held-out mean of scores/heldout.json).
struct StabilityMethod {
  std::string name;
  std::string metric;
  std::string confidence;  // optional: Spearman's rho of the method's confidence and error
  bool higher_is_better = false;
  // Optional: the area under the sparsification curve of that confidence over the optimal one
  // (pipeline/core/sparsification.h; 1 is perfect).
  std::string sparsification;
};

// A detector in the stability matrix: something that calls out failures (multi_depth's per-view
// flag against the views whose poses are known to be wrong), judged per cell by its precision and
// recall as a stage records them (metrics; null where undefined) and its false calls.
//         - {name: view flag, precision: multi_depth.view_flag_precision, recall: multi_depth.view_flag_recall,
//            false_calls: multi_depth.view_flag_false_calls}
struct StabilityDetector {
  std::string name, precision, recall, false_calls;  // false_calls optional
};

struct SweepPlan {
  std::vector<std::string> vary;      // "stage.key=v1,v2,..."
  std::vector<std::string> variants;  // "stage.key=v stage.key=v"
  std::string metric;                 // empty: the sweep's default
  // Varied keys naming a variant's degradation and giving its strength, in pairs: the first
  // degradation key a variant sets to something other than "none" names its cell.
  std::vector<std::string> degradation_keys, strength_keys;
  std::vector<StabilityMethod> methods;
  std::vector<StabilityDetector> detectors;  // optional (stability: detectors)

  bool HasStability() const { return !methods.empty(); }
};

// The race (successive halving, one round): after the last stage that writes the model, every
// stage after it runs first on a reduced copy of the capture in WORKSPACE/race/ (the training
// views only, scaled by `scale`, every `validation_every`-th of them held out and scored), and the
// stages whose outputs only models more than `margin_db` below the race's best are drawn from are
// left out of the full-size run (pipeline/runner/race.h).
struct RacePlan {
  bool enabled = false;
  double scale = 0.25;
  int validation_every = 4;
  double margin_db = 1.0;
  std::string metric = "photo_psnr";  // a held-out mean of scores/heldout.json
};

// The run's plan (the config's optional `plan:` block; `ibmr run --with` adds to `with`):
//   plan:
//     kind: auto       # or forward_facing, object, general: instead of the capture analysis
//     with: [volume]   # stages run whatever the capture's kind (Stage::Serves); [all]: skip none
//     race: {scale: 0.25, validation_every: 4, margin_db: 1, metric: photo_psnr}   # or race: off
struct RunPlan {
  std::string kind = "auto";
  std::vector<std::string> with;
  RacePlan race;
  int line = 0;  // of the plan: block (0: none)

  bool Forces(const std::string& stage) const {
    return std::find(with.begin(), with.end(), stage) != with.end() ||
           std::find(with.begin(), with.end(), "all") != with.end();
  }
};

struct Config {
  std::string path;       // the config file
  std::string dir;        // its folder (absolute)
  std::string workspace;  // absolute
  std::map<std::string, std::string> inputs;  // absolute paths
  HoldoutPolicy holdout;
  std::vector<StageConfig> stages;
  SweepPlan sweep;  // empty unless the config has a sweep: block
  RunPlan plan;

  const StageConfig* FindStage(const std::string& name) const;
};

// Expands ${VAR} and ${VAR:-default} from the environment in `text` (an empty VAR counts as unset).
// Throws ConfigError naming `file` and the line for a ${VAR} without default whose VAR is unset or
// empty. LoadConfig does not expand the file's text with this: it expands each parsed value the
// same way, so that a value holding '#' or ': ' stays one value (and a comment's ${VAR} is dropped
// with the comment).
std::string ExpandVariables(const std::string& text, const std::string& file = "config");
// Edit distance between two keys, for "did you mean" suggestions.
int EditDistance(const std::string& a, const std::string& b);
// The candidate nearest to `name` by EditDistance (the first of equals; "" when there are none),
// and its distance in `distance` (optional).
std::string Nearest(const std::string& name, const std::vector<std::string>& candidates, int* distance = nullptr);

// The stage's declared defaults (paths resolved against `dir`).
Params DefaultParams(const Stage& stage, const std::string& dir);

// Loads and validates `path` against the registered stages' parameter declarations and the
// stages' own CheckParams. Throws ConfigError, also for a key given twice in one map, a key that
// is not a plain name, and a workspace that is empty or the filesystem root.
Config LoadConfig(const std::string& path, const StageRegistry& registry);
// Adds `--with` names to config->plan.with. Throws ConfigError for a name that is not a stage of
// the config (nor "all"), suggesting the nearest.
void ApplyWith(const std::vector<std::string>& names, Config* config);
// Applies "--set stage.key=value" (value parsed as YAML) and re-checks the stage. Throws ConfigError.
void ApplyOverride(const std::string& assignment, const StageRegistry& registry, Config* config);

}  // namespace ibmr
