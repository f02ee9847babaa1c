// ibmr sweep: one config run as several variants (parameter overrides), each in its own workspace
// under one sweep folder, upstream outputs shared through the stage cache (a variant that changes
// only `render` recomputes only render and score: RunOptions::reuse_from). What each variant cost
// and how well it predicts held-out views is collected into <sweep>/sweep.json with the Pareto
// front of time against held-out error, the table `ibmr report` charts.
//
//   ibmr sweep configs/x.yaml --vary plane_sweep.num_planes=64,128 --vary render.supersample=1,2
//   ibmr sweep configs/x.yaml --variant "plane_sweep.num_planes=64 surfels.spacing_scale=2" --variant ...
//
// --vary lists are crossed (their product); each --variant is one listed combination. Variants run
// in order, v00, v01, ...; a variant that fails is recorded with its error and the sweep goes on.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/core/stage_api.h"
#include "pipeline/runner/config.h"

namespace ibmr {

// One variant: its overrides ("stage.key", "value") in the order given.
using Assignments = std::vector<std::pair<std::string, std::string>>;

// The variants of `vary` ("stage.key=v1,v2,...", crossed in order, the last varying fastest) followed
// by the `listed` ones ("stage.key=v stage.key=v"). No axes and no listed variants: one variant, the
// config as it is. Throws ConfigError naming a malformed argument.
std::vector<Assignments> ExpandVariants(const std::vector<std::string>& vary, const std::vector<std::string>& listed);

// The Pareto front of `points` (objects with numeric "seconds" and "psnr"): those no other point
// beats on both (less time and higher PSNR, one of them strictly), by increasing time.
nlohmann::json ParetoFront(const nlohmann::json& points);

// What one variant's workspace holds: per stage (in `config` order) its status, wall/CPU seconds,
// peak memory, whether it was reused, and its metrics; the totals; per scored model its held-out
// means and its size. Reads records/, scores/heldout.json and renders/renders.json.
// Stages whose record is not current (after a failure) are reported as stale, and the held-out
// scores only when every stage is current; `ran_clean` (the run just succeeded) says they all are.
nlohmann::json CollectVariant(const Config& config, const StageRegistry& registry, bool ran_clean);

struct SweepOptions {
  std::string config_path;
  std::vector<std::string> vary;
  std::vector<std::string> listed;
  std::string out;      // the sweep folder; default: the config's workspace + ".sweep"
  std::string metric = "photo_psnr";  // held-out mean charted against time (photo_psnr counts holes; psnr, mask_psnr, ...)
  int jobs = -1;
  bool interactive = false;
};

// The sweep folder: options.out, or the config's workspace + ".sweep"; absolute.
std::string SweepFolder(const SweepOptions& options, const Config& base);

// Runs every variant and writes <out>/sweep.json (after each variant, atomically). Returns 0 when
// every variant ran, 1 when some failed, 2 on a usage error (reported by ConfigError).
int RunSweep(const SweepOptions& options, const StageRegistry& registry);

}  // namespace ibmr
