// Slurm job arrays for per-view stages, single jobs for the others (see slurm_executor.h).
#include "pipeline/runner/slurm_executor.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <csignal>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <thread>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/child_process.h"
#include "pipeline/runner/shell_words.h"

namespace fs = std::filesystem;

namespace ibmr {

bool SlurmOptions::Check(std::string* error) const {
  if (ibmr.empty() || !fs::path(ibmr).is_absolute()) *error = "the ibmr program must be an absolute path";
  else if (retries < 0) *error = "--retries must be >= 0";
  else if (threads_per_view < 1) *error = "threads per view must be >= 1";
  else if (mem_per_view_mb < 0) *error = "memory per view must be >= 0 MB (0: the stage's estimate)";
  else if (poll_seconds <= 0) *error = "the poll interval must be > 0";
  else return true;
  return false;
}

namespace {

// One sbatch submission; returns the job id (sbatch --parsable prints "id" or "id;cluster").
std::string Submit(const std::vector<std::string>& sbatch_words) {
  std::vector<std::string> args = {"sbatch", "--parsable"};
  args.insert(args.end(), sbatch_words.begin(), sbatch_words.end());
  std::string id;
  const ProcessResult result = RunProcess(args, "", [&](const std::string& line) {
    if (id.empty() && !line.empty() && std::isdigit(static_cast<unsigned char>(line[0]))) id = line.substr(0, line.find(';'));
  });
  if (result.exit_code != 0 || id.empty()) {
    throw std::runtime_error("sbatch failed (exit " + std::to_string(result.exit_code) + "): " + result.last_lines +
                             "command: " + CommandLine(args));
  }
  return id;
}

// Set by SIGINT or SIGTERM while ibmr waits for its jobs: it then cancels them and stops.
volatile std::sig_atomic_t interrupted = 0;
void OnInterrupt(int) { interrupted = 1; }

struct Interrupted : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Blocks until squeue no longer lists the job (or any task of the array). Interrupted (Ctrl-C,
// a kill), it cancels the job, so that nothing keeps running on the cluster for a run that ended.
void WaitFor(const std::string& job, const std::string& what, double poll_seconds) {
  const auto start = std::chrono::steady_clock::now();
  size_t last_count = SIZE_MAX;
  auto last_line = start - std::chrono::seconds(60);
  while (true) {
    size_t count = 0;
    const ProcessResult result =
        RunProcess({"squeue", "--noheader", "--array", "--jobs", job, "--format", "%i %T"}, "",
                   [&](const std::string& line) { count += !line.empty(); });
    // squeue forgets a finished job after a while and then exits non-zero: also finished.
    if (result.exit_code != 0 || count == 0) break;
    const auto now = std::chrono::steady_clock::now();
    // A line when the count changed, at most every 5 s (plain lines: this usually goes to a log).
    if ((count != last_count && now - last_line > std::chrono::seconds(5)) || now - last_line > std::chrono::seconds(60)) {
      spdlog::info("[slurm] {}: job {}, {} task(s) queued or running ({:.0f}s)", what, job, count,
                   std::chrono::duration<double>(now - start).count());
      last_count = count;
      last_line = now;
    }
    if (interrupted) {
      RunProcess({"scancel", job}, "", [](const std::string&) {});
      throw Interrupted("interrupted: cancelled job " + job + " (" + what + "); what finished is kept, and the next "
                        "run goes on from there");
    }
    std::this_thread::sleep_for(std::chrono::duration<double>(poll_seconds));
  }
}

// Slurm's own output files stay empty when the job script redirects everything to its log.
void RemoveEmptySlurmOutputs(const std::string& folder) {
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("slurm-", 0) == 0 && entry.is_regular_file(ec) && entry.file_size(ec) == 0) fs::remove(entry.path(), ec);
  }
}

std::string LastLines(const std::string& path, size_t count) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  std::string tail;
  for (size_t i = lines.size() > count ? lines.size() - count : 0; i < lines.size(); ++i) tail += "    " + lines[i] + "\n";
  return tail;
}

class SlurmRun {
 public:
  SlurmRun(const Runner& runner, const SlurmOptions& options) : runner_(runner), options_(options) {
    workspace_ = runner.config().workspace;
  }

  // Decided as `ibmr run` decides (the stage's own cache key), hashing this stage's inputs only.
  bool StageUpToDate(size_t index) const { return runner_.Staleness(index).empty(); }

  // MB for one view's task: the user's figure, else the stage's estimate with a quarter more
  // for what it does not count, else 2000.
  int MemoryPerView(const std::string& stage) const {
    if (options_.mem_per_view_mb > 0) return options_.mem_per_view_mb;
    const double estimate = runner_.ViewMemoryMb(stage);
    return estimate > 0 ? static_cast<int>(std::ceil(1.25 * estimate)) : 2000;
  }

  // A per-view stage as its views' job array and then the merge; any other as one job.
  bool RunStage(size_t index, const std::string& stage) {
    if (!runner_.registry().Find(stage)->Shardable()) return RunStageJob(index, stage, "", "stage");
    std::string array_job;
    return RunViews(stage, &array_job) && RunStageJob(index, stage, array_job, "merge");
  }

  // The job array for the views of a per-view stage, resubmitting what failed; true when every
  // view is done. `array_job` is the last array's id (the merge depends on it).
  bool RunViews(const std::string& stage, std::string* array_job) {
    const std::string folder = LogFolder(stage);
    std::vector<std::string> todo = runner_.UnfinishedViews(stage);
    for (int attempt = 1; !todo.empty() && attempt <= options_.retries + 1; ++attempt) {
      const std::string list = folder + "/views." + std::to_string(attempt) + ".txt";
      std::string lines;
      for (const std::string& view : todo) lines += view + "\n";
      WriteFileAtomic(list, lines);
      std::vector<std::string> command = RunStage(stage);
      command.insert(command.end(), {"--jobs", std::to_string(options_.threads_per_view)});
      const std::string script = folder + "/view_job.sh";
      WriteFileAtomic(script,
                      "#!/bin/bash\n"
                      "# One view of ibmr stage " + stage + " per array task (written by ibmr run --executor slurm).\n"
                      "set -euo pipefail\n"
                      "VIEW=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" \"$1\")\n"
                      "LOG=" + ShellQuote(folder) + "/\"$VIEW\".log\n"
                      "mkdir -p \"$(dirname \"$LOG\")\"\n"
                      "exec " + CommandLine(command) + " --views \"$VIEW\" >> \"$LOG\" 2>&1\n");
      std::vector<std::string> words = {"--job-name=ibmr-" + stage,
                                        "--array=0-" + std::to_string(todo.size() - 1),
                                        "--cpus-per-task=" + std::to_string(options_.threads_per_view),
                                        "--mem=" + std::to_string(MemoryPerView(stage)),
                                        "--output=" + folder + "/slurm-%A_%a.out"};
      words.insert(words.end(), options_.sbatch_args.begin(), options_.sbatch_args.end());
      words.insert(words.end(), {script, list});
      *array_job = Submit(words);
      spdlog::info("[slurm] {}: {} view(s) as array job {}, {} MB each{}", stage, todo.size(), *array_job,
                   MemoryPerView(stage), attempt > 1 ? " (attempt " + std::to_string(attempt) + ")" : "");
      WaitFor(*array_job, stage + " views", options_.poll_seconds);
      RemoveEmptySlurmOutputs(folder);
      const std::vector<std::string> left = runner_.UnfinishedViews(stage);
      if (!left.empty() && attempt <= options_.retries) {
        spdlog::warn("[slurm] {}: {} view(s) not done after attempt {} (a job killed or failed); submitting them "
                     "again", stage, left.size(), attempt);
      }
      todo = left;
    }
    for (const std::string& view : todo) {
      const std::string log = folder + "/" + view + ".log";
      spdlog::error("[slurm] {}: view {} failed {} time(s); log {}\n{}", stage, view, options_.retries + 1, log,
                    LastLines(log, 4));
    }
    if (!todo.empty()) {
      std::string names;
      for (const std::string& view : todo) names += (names.empty() ? "" : ", ") + view;
      spdlog::error("[slurm] {}: {} view(s) failed: {}; logs in {}", stage, todo.size(), names, folder);
    }
    return todo.empty();
  }

  // One job running the whole stage (or, after its views, the merge); true when the stage ends
  // up to date.
  bool RunStageJob(size_t index, const std::string& stage, const std::string& after, const std::string& what) {
    const std::string folder = LogFolder(stage);
    const std::string log = folder + "/" + what + ".log";
    std::vector<std::string> command = RunStage(stage);
    if (options_.threads_per_stage > 0) command.insert(command.end(), {"--jobs", std::to_string(options_.threads_per_stage)});
    const std::string script = folder + "/" + what + "_job.sh";
    WriteFileAtomic(script, "#!/bin/bash\n# ibmr stage " + stage + " (" + what +
                                "), written by ibmr run --executor slurm.\nexec " + CommandLine(command) + " >> " +
                                ShellQuote(log) + " 2>&1\n");
    for (int attempt = 1; attempt <= options_.retries + 1; ++attempt) {
      std::vector<std::string> words = {"--job-name=ibmr-" + stage, "--output=" + folder + "/slurm-%j.out"};
      if (options_.threads_per_stage > 0) words.push_back("--cpus-per-task=" + std::to_string(options_.threads_per_stage));
      if (!after.empty() && attempt == 1) words.insert(words.end(), {"--dependency=afterok:" + after, "--kill-on-invalid-dep=yes"});
      words.insert(words.end(), options_.sbatch_args.begin(), options_.sbatch_args.end());
      words.push_back(script);
      const std::string job = Submit(words);
      spdlog::info("[slurm] {}: {} as job {}{}", stage, what, job, attempt > 1 ? " (attempt " + std::to_string(attempt) + ")" : "");
      WaitFor(job, stage + " " + what, options_.poll_seconds);
      RemoveEmptySlurmOutputs(folder);
      if (StageUpToDate(index)) return true;
      if (attempt <= options_.retries) spdlog::warn("[slurm] {}: {} did not finish; submitting it again", stage, what);
    }
    spdlog::error("[slurm] {}: {} failed {} time(s); log {}\n{}", stage, what, options_.retries + 1, log, LastLines(log, 6));
    return false;
  }

 private:
  // logs/slurm/<stage>/: job scripts, view lists and logs (made on first use).
  std::string LogFolder(const std::string& stage) const {
    const std::string folder = workspace_ + "/logs/slurm/" + stage;
    fs::create_directories(folder);
    return folder;
  }

  // `ibmr run CONFIG ... --only STAGE` as this process sees the config.
  std::vector<std::string> RunStage(const std::string& stage) const {
    std::vector<std::string> command = {options_.ibmr, "run"};
    command.insert(command.end(), options_.run_args.begin(), options_.run_args.end());
    command.insert(command.end(), {"--only", stage});
    return command;
  }

  const Runner& runner_;
  const SlurmOptions& options_;
  std::string workspace_;
};

}  // namespace

int RunOnSlurm(const Runner& runner, const RunOptions& options, const SlurmOptions& slurm) {
  std::string problem;
  if (!slurm.Check(&problem)) {
    spdlog::error("--executor slurm: {}", problem);
    return 2;
  }
  if (FindExecutable("sbatch").empty() || FindExecutable("squeue").empty()) {
    spdlog::error("--executor slurm: sbatch and squeue are not on PATH (Debian: apt install slurm-client; the "
                  "cluster's SLURM_CONF must be set)");
    return 2;
  }
  if (!options.views.empty() || options.dry_run || !options.reuse_from.empty()) {
    spdlog::error("--executor slurm runs whole stages; drop --views and --dry-run (use `ibmr status` to see what is stale)");
    return 2;
  }
  std::vector<size_t> selected;
  if (!runner.SelectStages(options, &selected)) return 2;
  const auto start = std::chrono::steady_clock::now();
  SlurmRun run(runner, slurm);
  interrupted = 0;
  std::signal(SIGINT, OnInterrupt);
  std::signal(SIGTERM, OnInterrupt);
  int submitted = 0;
  try {
    for (size_t index : selected) {
      const std::string& stage = runner.config().stages[index].name;
      if (!options.force && run.StageUpToDate(index)) {
        spdlog::info("[{}] up to date", stage);
        continue;
      }
      ++submitted;
      if (!run.RunStage(index, stage)) return 1;
    }
  } catch (const Interrupted& e) {
    spdlog::error("[slurm] {}", e.what());
    return 130;
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  spdlog::info("{} stage(s) ran on Slurm in {:.1f}s; workspace {}", submitted, seconds, runner.config().workspace);
  return 0;
}

}  // namespace ibmr
