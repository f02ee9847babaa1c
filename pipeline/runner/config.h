// The run configuration (YAML): workspace, named inputs, holdout policy and the ordered stages
// with their parameters. Paths are relative to the config file; ${VAR:-default} expands from
// the environment. Every error names the file, the line and the key, says what was expected,
// and suggests the nearest valid key for a misspelt one.
//
//   workspace: ${IBMR_WORKSPACE:-../workspaces/demo}
//   inputs:            # named paths stages may read (import's default source is inputs.images)
//     images: ../data/temple
//   holdout:           # views kept out of every reconstruction stage, scored by `score`
//     every: 8         # every 8th view of the sorted image list, starting at `offset`
//     offset: 0
//     images: [a.png]  # and/or explicit names
//   stages:
//     - synth: {scene: object_ring, views: 24}
//     - carve:
//         levels: 7
#pragma once

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
  int offset = 0;  // first held-out index in the sorted image list
  std::vector<std::string> images;

  bool Active() const { return every > 0 || !images.empty(); }
  // The held-out subset of `sorted_names`.
  std::set<std::string> Select(const std::vector<std::string>& sorted_names) const;
  std::string Describe() const;
};

struct StageConfig {
  std::string name;
  Params params;       // every declared key, defaults filled in
  int line = 0;        // 1-based line of the stage entry
  std::map<std::string, int> key_lines;  // 1-based line of each key given in the file
};

struct Config {
  std::string path;       // the config file
  std::string dir;        // its folder (absolute)
  std::string workspace;  // absolute
  std::map<std::string, std::string> inputs;  // absolute paths
  HoldoutPolicy holdout;
  std::vector<StageConfig> stages;

  const StageConfig* FindStage(const std::string& name) const;
};

// Expands ${VAR} and ${VAR:-default} from the environment in `text`.
std::string ExpandVariables(const std::string& text);
// Edit distance between two keys, for "did you mean" suggestions.
int EditDistance(const std::string& a, const std::string& b);

// The stage's declared defaults (paths resolved against `dir`).
Params DefaultParams(const Stage& stage, const std::string& dir);

// Loads and validates `path` against the registered stages' parameter declarations and the
// stages' own CheckParams. Throws ConfigError.
Config LoadConfig(const std::string& path, const StageRegistry& registry);
// Applies "--set stage.key=value" (value parsed as YAML) and re-checks the stage. Throws ConfigError.
void ApplyOverride(const std::string& assignment, const StageRegistry& registry, Config* config);

}  // namespace ibmr
