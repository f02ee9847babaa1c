// `ibmr export snakemake CONFIG > Snakefile`: the config as a Snakemake 7 workflow. One rule per
// stage; a per-view stage (Stage::Shardable) gets a rule per view (`ibmr run --only STAGE --views
// V`) and a merge rule that gathers them. The rules' order comes from the stages' declared inputs
// and outputs (Runner::Upstream). Each rule runs ibmr on the config's workspace, so ibmr's cache
// still decides what is stale and the workspace and records equal those of `ibmr run`.
//
// Snakemake's outputs are stamps under records/snakemake/, not the stages' files: Snakemake
// deletes a job's declared outputs before running it, which would throw away what ibmr keeps (the
// last good outputs of a failed run, a sweep's hard links). The stages' own files are listed in a
// comment above each rule. Rules before a per-view stage are checkpoints, so that its views (which
// exist only once sparse/ does) are listed when the DAG reaches it (`ibmr views`).
#pragma once

#include <string>
#include <vector>

#include "pipeline/runner/runner.h"

namespace ibmr {

struct SnakemakeExportOptions {
  std::string ibmr;                   // the ibmr program the rules run (absolute path)
  std::vector<std::string> run_args;  // the config (absolute) and overrides, as `ibmr run` takes them
  int threads_per_view = 1;
  int mem_per_view_mb = 0;  // 0: the stage's estimate once its inputs exist (ibmr views --memory-mb), else 2000
  int mem_per_stage_mb = 4000;
};

std::string SnakemakeFile(const Runner& runner, const SnakemakeExportOptions& options);

}  // namespace ibmr
