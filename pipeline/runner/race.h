// The race (issue 66; successive halving as hyperparameter searches run it, one round): before
// the stages that build models run at full size, they run on a reduced copy of the capture, and
// the stages whose outputs feed only the models that lose are left out of the full-size run.
//
// The reduced capture lives in WORKSPACE/race/: the model and images the stages after the last
// model-writing stage (import, sfm, undistort) read, with the held-out views removed from both
// (the race cannot read a held-out photo: it is not there), every photo (and its alpha) scaled by
// plan.race.scale, cameras and observations scaled with it, and the capture's background.json.
// Every plan.race.validation_every-th training view (sorted by name, from the middle of the first
// stride) is held out there and scored: a validation split of the training views. The race runs
// the config's stages after the model stage in that workspace with its own cache, so a second run
// costs nothing; it writes race.json to the workspace root.
#pragma once

#include <map>
#include <set>
#include <string>
#include <vector>

#include "pipeline/core/stage_api.h"
#include "pipeline/runner/config.h"
#include "pipeline/runner/runner.h"

namespace ibmr {

struct RaceOutcome {
  bool ok = false;
  std::string problem;                    // why the race has no verdict (ok false): every stage then runs
  std::string workspace;                  // WORKSPACE/race
  std::vector<std::string> validation;    // training views held out and scored in the race
  std::map<std::string, double> scores;   // model -> the metric's mean over the validation views
  std::string best;
  double best_score = 0;
  std::set<std::string> winners;          // within margin_db of the best
  double seconds = 0;                     // the race's own run, wall (about 0 when it was up to date)
  std::map<std::string, double> stage_seconds;  // each race stage's wall seconds (from its record)
};

// Every `every`-th of the sorted `training` names from every / 2: the race's validation views.
std::vector<std::string> ValidationViews(const std::vector<std::string>& training, int every);

// Writes the reduced capture to `race_workspace` from the model and images `model` reads: the
// views not in `heldout`, scaled by `scale`. Photos already there and newer than their source are
// kept. Throws IoError / InputError naming the file.
void PrepareRaceCapture(const Workspace& model, const std::set<std::string>& heldout, double scale,
                        const std::string& race_workspace);

// Prepares the race and runs config stages model_stage + 1 ... there (the kind of the capture set
// to `kind`, so that the race leaves out what the full run does).
RaceOutcome RunRace(const Config& config, const StageRegistry& registry, size_t model_stage, const Workspace& model,
                    const std::set<std::string>& heldout, const std::string& kind, const RunOptions& options);

}  // namespace ibmr
