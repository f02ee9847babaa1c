// Sharded runs leave what a local run leaves. configs/synth_dense.yaml (at 320x240, 16 views, so
// that each run takes seconds) runs once locally as the reference; then
//   - by hand as shards (`--views`, two processes at once) and merges, for plane_sweep,
//     multi_depth and render (whose views are the held-out ones),
//   - through `ibmr export snakemake` and Snakemake with --cores 2 (a second Snakemake run has
//     nothing to do),
//   - on a single-node Slurm started for the test (scripts/local_slurm.sh: munged, slurmctld,
//     slurmd, no systemd) through `--executor slurm`, with one array task cancelled mid-run (it is
//     resubmitted), and through Snakemake's cluster mode (sbatch),
// and each must give byte-identical outputs and the same records but for times. A corrupt image
// must reach the user with the view's name and its log. Snakemake and Slurm are test-only packages
// (scripts/test.sh); their tests skip with a message where they are missing.
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "tests/run_command.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace {

using ibmr_e2e::CommandResult;
using ibmr_e2e::RunCommand;

const std::string kConfig = std::string(IBMR_SOURCE_DIR) + "/configs/synth_dense.yaml";
const std::string kSmall = " --set synth.width=320 --set synth.height=240 --set synth.views=16 --set splat_fit.iterations=30";

std::string Ibmr(const std::string& args) { return std::string(IBMR_BINARY) + " " + args; }

bool OnPath(const std::string& program) { return RunCommand("command -v " + program + " >/dev/null").exit_code == 0; }

std::string ReadText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// A record without what differs between two runs of the same work: when and how long it ran, its
// memory and the memory budget (what was free), how many views an earlier run or a shard had
// finished, and the metrics that are times.
nlohmann::json WithoutTimes(nlohmann::json record) {
  for (const char* key : {"started", "wall_seconds", "cpu_seconds", "peak_memory_mb", "views_resumed", "memory_budget_mb", "child_peak_memory_mb",
                          "views_in_flight", "start_memory_mb"})
    record.erase(key);
  nlohmann::json metrics = nlohmann::json::object();
  for (auto it = record["metrics"].begin(); it != record["metrics"].end(); ++it) {
    const std::string& k = it.key();
    const bool time = k.find("seconds") != std::string::npos || k.find("per_second") != std::string::npos ||
                      k.find("rss") != std::string::npos || k.rfind("ms_per_", 0) == 0;
    if (!time) metrics[k] = it.value();
  }
  record["metrics"] = metrics;
  return record;
}

// Every output file byte for byte, and every stage record but for times; records/ and logs/ hold
// the engines' own files (stamps, job scripts), compared only through the records.
void ExpectSameWorkspace(const fs::path& reference, const fs::path& other) {
  size_t files = 0;
  for (const auto& entry : fs::recursive_directory_iterator(reference)) {
    if (!entry.is_regular_file()) continue;
    const fs::path relative = fs::relative(entry.path(), reference);
    const std::string top = relative.begin()->string();
    if (top == "logs" || top == ".snakemake") continue;
    if (top == "records") {
      if (relative.parent_path() != "records" || relative.extension() != ".json") continue;
      ASSERT_TRUE(fs::exists(other / relative)) << relative;
      EXPECT_EQ(WithoutTimes(nlohmann::json::parse(ReadText(entry.path()))),
                WithoutTimes(nlohmann::json::parse(ReadText(other / relative))))
          << relative;
      continue;
    }
    ++files;
    ASSERT_TRUE(fs::exists(other / relative)) << relative << " is missing in " << other;
    EXPECT_TRUE(ReadText(entry.path()) == ReadText(other / relative)) << relative << " differs";
  }
  EXPECT_GT(files, 300u) << "the reference should hold images, depth maps, meshes, renders and scores";
}

class WorkflowEngines : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = ibmr_testing::ScratchDir(std::string("ibmr_engines_") +
                                    ::testing::UnitTest::GetInstance()->current_test_info()->name());
    reference_ = dir_ / "local";
    const CommandResult local = RunCommand(Ibmr("run " + kConfig + " --workspace " + reference_.string() + kSmall));
    ASSERT_EQ(local.exit_code, 0) << local.output;
  }
  std::string Run(const fs::path& workspace, const std::string& args) {
    return Ibmr("run " + kConfig + " --workspace " + workspace.string() + kSmall + " " + args);
  }

  fs::path dir_, reference_;
};

TEST_F(WorkflowEngines, ShardsThenMergeEqualALocalRun) {
  const fs::path ws = dir_ / "sharded";
  ASSERT_EQ(RunCommand(Run(ws, "--to carve")).exit_code, 0);
  for (const std::string stage : {"plane_sweep", "multi_depth", "render"}) {
    if (stage == "render") ASSERT_EQ(RunCommand(Run(ws, "--from fuse --to surfels")).exit_code, 0);
    const CommandResult listed = RunCommand(Ibmr("views " + kConfig + " " + stage + " --workspace " + ws.string() + kSmall));
    ASSERT_EQ(listed.exit_code, 0) << listed.output;
    std::vector<std::string> views;
    std::istringstream lines(listed.output);
    for (std::string line; std::getline(lines, line);) views.push_back(line);
    // 16 views, every 8th held out: 14 training views; render's views are the 2 held out.
    const size_t expected = stage == "render" ? 2 : 14;
    ASSERT_EQ(views.size(), expected) << listed.output;
    // Two shards at once, like two cluster jobs: the first half and the second.
    std::string first, second;
    const size_t half = views.size() / 2;
    for (size_t i = 0; i < views.size(); ++i) {
      std::string& shard = i < half ? first : second;
      shard += (shard.empty() ? "" : ",") + views[i];
    }
    const CommandResult both = RunCommand("(" + Run(ws, "--only " + stage + " --views " + first + " --jobs 1") + ") & (" +
                                          Run(ws, "--only " + stage + " --views " + second + " --jobs 1") + "); wait");
    ASSERT_EQ(both.exit_code, 0) << both.output;
    EXPECT_FALSE(fs::exists(ws / "records" / (stage + ".json"))) << "a shard writes no record; the merge does";
    const CommandResult status =
        RunCommand(Ibmr("status " + kConfig + " --workspace " + ws.string() + kSmall));
    const std::string done = std::to_string(expected) + " of " + std::to_string(expected) + " views done";
    EXPECT_NE(status.output.find(stage + ": never ran (" + done + ")"), std::string::npos) << status.output;
    const CommandResult merge = RunCommand(Run(ws, "--only " + stage));
    ASSERT_EQ(merge.exit_code, 0) << merge.output;
    const nlohmann::json record = nlohmann::json::parse(ReadText(ws / "records" / (stage + ".json")));
    EXPECT_GE(record.value("views_resumed", 0), static_cast<int>(expected)) << "the merge computes no view again:\n"
                                                                             << merge.output;
  }
  ASSERT_EQ(RunCommand(Run(ws, "")).exit_code, 0);
  ExpectSameWorkspace(reference_, ws);

  const CommandResult not_per_view = RunCommand(Run(ws, "--only fuse --views view_001.png"));
  EXPECT_EQ(not_per_view.exit_code, 2);
  EXPECT_NE(not_per_view.output.find("(shardable stages: plane_sweep, multi_depth, render)"), std::string::npos)
      << not_per_view.output;
  const CommandResult unknown = RunCommand(Run(ws, "--only plane_sweep --views nope.png --force"));
  EXPECT_EQ(unknown.exit_code, 1);
  EXPECT_NE(unknown.output.find("nope.png"), std::string::npos) << unknown.output;
}

TEST_F(WorkflowEngines, SnakemakeLocallyEqualsALocalRunAndThenHasNothingToDo) {
  if (!OnPath("snakemake")) GTEST_SKIP() << "snakemake is not installed (scripts/test.sh installs it); skipping";
  const fs::path ws = dir_ / "snakemake";
  fs::create_directories(ws);
  const std::string snakefile = (dir_ / "Snakefile").string();
  const CommandResult exported = RunCommand(Ibmr("export snakemake " + kConfig + " --workspace " + ws.string() + kSmall) +
                                            " > " + snakefile);
  ASSERT_EQ(exported.exit_code, 0) << exported.output;
  const CommandResult run = RunCommand("snakemake -s " + snakefile + " --cores 2 --quiet");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  ExpectSameWorkspace(reference_, ws);
  const CommandResult again = RunCommand("snakemake -s " + snakefile + " --cores 2 --dry-run");
  ASSERT_EQ(again.exit_code, 0) << again.output;
  EXPECT_NE(again.output.find("Nothing to be done"), std::string::npos) << again.output;

  // A stage named like a Python keyword (import) still makes a Snakefile Snakemake reads.
  const std::string with_import = (dir_ / "import.yaml").string();
  std::ofstream(with_import) << "workspace: ws\nstages:\n  - import:\n      source: " << reference_.string()
                             << "\n  - plane_sweep: {}\n";
  const std::string snakefile2 = (dir_ / "Snakefile.import").string();
  ASSERT_EQ(RunCommand(Ibmr("export snakemake " + with_import) + " > " + snakefile2).exit_code, 0);
  const CommandResult listed = RunCommand("snakemake -s " + snakefile2 + " --list");
  EXPECT_EQ(listed.exit_code, 0) << listed.output;
  EXPECT_NE(listed.output.find("ibmr_import"), std::string::npos) << listed.output;
}

// Starts the cluster for one test and stops it, whatever the test's outcome.
class LocalSlurm {
 public:
  explicit LocalSlurm(const fs::path& dir) : dir_(dir) {
    const CommandResult started = RunCommand(std::string(IBMR_SOURCE_DIR) + "/scripts/local_slurm.sh start " + dir.string());
    up_ = started.exit_code == 0;
    problem_ = started.output;
  }
  ~LocalSlurm() { RunCommand(std::string(IBMR_SOURCE_DIR) + "/scripts/local_slurm.sh stop " + dir_.string()); }
  bool up() const { return up_; }
  const std::string& problem() const { return problem_; }
  std::string Env() const { return "SLURM_CONF=" + (dir_ / "slurm.conf").string() + " "; }

 private:
  fs::path dir_;
  bool up_ = false;
  std::string problem_;
};

TEST_F(WorkflowEngines, SlurmExecutorAndSnakemakeClusterModeEqualALocalRun) {
  if (!OnPath("slurmctld") || !OnPath("munged") || !OnPath("snakemake") || ::geteuid() != 0) {
    GTEST_SKIP() << "needs root and slurm-wlm, munge and snakemake (scripts/test.sh installs them); skipping";
  }
  const LocalSlurm slurm(dir_ / "cluster");
  ASSERT_TRUE(slurm.up()) << slurm.problem();

  // --executor slurm, with one plane_sweep task cancelled while it runs.
  const fs::path ws = dir_ / "slurm";
  const std::string log = (dir_ / "slurm.log").string();
  const std::string background = slurm.Env() + Run(ws, "--executor slurm") + " > " + log + " 2>&1; echo $? > " + log + ".exit";
  // Detached from RunCommand's pipe, which would otherwise wait for the whole run.
  ASSERT_EQ(RunCommand("(" + background + ") > /dev/null 2>&1 < /dev/null &").exit_code, 0);
  std::string cancelled;
  for (int i = 0; i < 600 && cancelled.empty(); ++i) {
    const CommandResult running =
        RunCommand(slurm.Env() + "squeue --noheader --array --name=ibmr-plane_sweep --states=RUNNING --format=%i");
    if (!running.output.empty() && running.output.find('_') != std::string::npos) {
      cancelled = running.output.substr(0, running.output.find('\n'));
      RunCommand(slurm.Env() + "scancel " + cancelled);
    } else {
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }
  EXPECT_FALSE(cancelled.empty()) << "no plane_sweep task was seen running";
  for (int i = 0; i < 3000 && !fs::exists(log + ".exit"); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  ASSERT_TRUE(fs::exists(log + ".exit")) << ReadText(log);
  ASSERT_EQ(ReadText(log + ".exit"), "0\n") << ReadText(log);
  // The runner saw the cancelled task: either its view was left undone and is submitted again, or
  // (cancelled after it wrote its outputs) the merge that waited on the array lost its dependency
  // and is submitted again.
  const std::string text = ReadText(log);
  EXPECT_TRUE(text.find("submitting them again") != std::string::npos ||
              text.find("merge did not finish; submitting it again") != std::string::npos)
      << text;
  ExpectSameWorkspace(reference_, ws);

  // Snakemake submitting each rule with sbatch. Snakemake 7 looks for finished cluster jobs every
  // 10 s, every second with CI=true (its executors' sleep()): the run is a chain of short jobs.
  const fs::path snake_ws = dir_ / "snakemake_slurm";
  fs::create_directories(snake_ws);
  const std::string snakefile = (dir_ / "Snakefile").string();
  ASSERT_EQ(RunCommand(Ibmr("export snakemake " + kConfig + " --workspace " + snake_ws.string() + kSmall) + " > " +
                       snakefile).exit_code, 0);
  const CommandResult snake = RunCommand(
      slurm.Env() + "CI=true snakemake -s " + snakefile +
      " --cores 2 --jobs 8 --latency-wait 5 --quiet --cluster-cancel scancel --cluster 'sbatch --parsable "
      "--cpus-per-task={threads} --mem={resources.mem_mb} --output=.snakemake/slurm-%j.out'");
  ASSERT_EQ(snake.exit_code, 0) << snake.output;
  ExpectSameWorkspace(reference_, snake_ws);

  // A corrupt photo: the failed views come back by name, with their logs.
  std::ofstream(ws / "images" / "view_003.png", std::ios::binary | std::ios::trunc) << "not a PNG";
  const CommandResult failed = RunCommand(slurm.Env() + Run(ws, "--executor slurm --from plane_sweep --retries 0"));
  EXPECT_EQ(failed.exit_code, 1) << failed.output;
  const std::string view_log = (ws / "logs/slurm/plane_sweep/view_003.png.log").string();
  EXPECT_NE(failed.output.find("view view_003.png failed 1 time(s); log " + view_log), std::string::npos) << failed.output;
  EXPECT_NE(ReadText(view_log).find("images/view_003.png"), std::string::npos) << ReadText(view_log);
}

}  // namespace
