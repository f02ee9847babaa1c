// `ibmr run CONFIG --executor slurm`: the config's stale stages as Slurm jobs. A per-view stage
// (Stage::Shardable) becomes a job array, one task per view (`ibmr run --only STAGE --views V`),
// and then its merge, one job that depends on the array (afterok); any other stage is one job.
// Jobs run the same ibmr on the same workspace (a shared file system), so the project's cache
// still decides what is stale and a finished sharded stage leaves the records of a local run.
//
// Waiting polls squeue (Slurm's accounting database is not needed). Success is read from the
// workspace, not from exit codes: a view is done when its per-view mark is there, a stage when its
// record is up to date. What a killed or failed job left undone is submitted again (`retries`
// times); a view that still fails is reported by name with its log, logs/slurm/<stage>/<view>.log.
#pragma once

#include <string>
#include <vector>

#include "pipeline/runner/runner.h"

namespace ibmr {

struct SlurmOptions {
  std::string ibmr;                      // the ibmr program the jobs run (absolute path)
  std::vector<std::string> run_args;     // after `ibmr run`: the config and its overrides
  std::vector<std::string> sbatch_args;  // passed to every sbatch (partition, account, time, ...)
  int retries = 1;                       // resubmissions of what a job left undone
  int threads_per_view = 1;              // cpus of one array task
  int threads_per_stage = 0;             // cpus of a whole-stage or merge job; 0: the machine's
  int mem_per_view_mb = 0;               // 0: the stage's estimate (Stage::ViewMemoryMb), else 2000
  double poll_seconds = 0.5;

  bool Check(std::string* error) const;
};

// Returns 0 when every selected stage is up to date at the end, 1 when a job failed (after
// retries), 2 on a usage error (a bad selection, sbatch missing).
int RunOnSlurm(const Runner& runner, const RunOptions& options, const SlurmOptions& slurm);

}  // namespace ibmr
