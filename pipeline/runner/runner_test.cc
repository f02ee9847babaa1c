// The runner's cache: what runs after a parameter change, an input change, a resource-knob
// change; --only / --from / --to / --force; status reasons; failures keep earlier outputs.
#include "pipeline/runner/runner.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/process_memory.h"
#include "pipeline/runner/fake_stages_for_test.h"
#include "pipeline/runner/record.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

using testing_stages::consume_runs;
using testing_stages::produce_runs;

class RunnerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_runner_test_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    testing_stages::Register(&registry_);
    std::ofstream(dir_ / "source.txt") << "hello";
    std::ofstream(dir_ / "c.yaml") << "workspace: ws\nstages:\n  - produce\n  - consume\n";
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Runs the config with overrides; returns {produce runs, consume runs} of this call.
  std::pair<int, int> Run(const std::vector<std::string>& sets = {}, RunOptions options = RunOptions()) {
    Config config = LoadConfig((dir_ / "c.yaml").string(), registry_);
    for (const auto& s : sets) ApplyOverride(s, registry_, &config);
    const int p = produce_runs, c = consume_runs;
    last_exit_ = Runner(config, registry_).Run(options);
    return {produce_runs - p, consume_runs - c};
  }
  std::vector<StageStatus> Status(const std::vector<std::string>& sets = {}) {
    Config config = LoadConfig((dir_ / "c.yaml").string(), registry_);
    for (const auto& s : sets) ApplyOverride(s, registry_, &config);
    return Runner(config, registry_).Status();
  }
  std::string Read(const std::string& name) {
    std::ifstream in(dir_ / "ws" / name);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }

  fs::path dir_;
  StageRegistry registry_;
  int last_exit_ = -1;
};

TEST_F(RunnerTest, SecondRunDoesNoWork) {
  EXPECT_EQ(Run(), std::make_pair(1, 1));
  EXPECT_EQ(Read("b.txt"), "hello1x");
  EXPECT_EQ(Run(), std::make_pair(0, 0));
  for (const auto& s : Status()) EXPECT_TRUE(s.up_to_date) << s.name << ": " << s.reason;
}

TEST_F(RunnerTest, ParameterChangeRerunsStageAndDownstream) {
  Run();
  const auto status = Status({"produce.value=2"});
  EXPECT_FALSE(status[0].up_to_date);
  EXPECT_NE(status[0].reason.find("parameter 'value' changed"), std::string::npos) << status[0].reason;
  EXPECT_NE(status[1].reason.find("upstream stage 'produce'"), std::string::npos) << status[1].reason;
  EXPECT_EQ(Run({"produce.value=2"}), std::make_pair(1, 1));
  EXPECT_EQ(Read("b.txt"), "hello2x");
  EXPECT_EQ(Run({"produce.value=2"}), std::make_pair(0, 0));
}

TEST_F(RunnerTest, DownstreamParameterChangeLeavesUpstreamAlone) {
  Run();
  EXPECT_EQ(Run({"consume.suffix=y"}), std::make_pair(0, 1));
}

TEST_F(RunnerTest, ResourceKnobDoesNotMakeStale) {
  Run();
  EXPECT_EQ(Run({"produce.threads=8"}), std::make_pair(0, 0));
}

TEST_F(RunnerTest, InputContentChangeReruns) {
  Run();
  std::ofstream(dir_ / "source.txt") << "bye";
  const auto status = Status();
  EXPECT_NE(status[0].reason.find("input"), std::string::npos) << status[0].reason;
  EXPECT_EQ(Run(), std::make_pair(1, 1));
  EXPECT_EQ(Read("b.txt"), "bye1x");
  // Touching a file without changing its content does nothing: the cache hashes content.
  std::ofstream(dir_ / "source.txt") << "bye";
  EXPECT_EQ(Run(), std::make_pair(0, 0));
}

TEST_F(RunnerTest, OnlyFromToAndForce) {
  Run();
  RunOptions only;
  only.only = "consume";
  only.force = true;
  EXPECT_EQ(Run({}, only), std::make_pair(0, 1));
  RunOptions to;
  to.to = "produce";
  to.force = true;
  EXPECT_EQ(Run({}, to), std::make_pair(1, 0));
  RunOptions from;
  from.from = "consume";
  EXPECT_EQ(Run({"produce.value=5"}, from), std::make_pair(0, 0));  // produce stale but not selected
  EXPECT_EQ(Run({"produce.value=5"}), std::make_pair(1, 1));
  RunOptions unknown;
  unknown.only = "nope";
  Run({}, unknown);
  EXPECT_EQ(last_exit_, 2);
}

TEST_F(RunnerTest, DryRunChangesNothing) {
  RunOptions dry;
  dry.dry_run = true;
  EXPECT_EQ(Run({}, dry), std::make_pair(0, 0));
  EXPECT_FALSE(fs::exists(dir_ / "ws" / "a.txt"));
}

TEST_F(RunnerTest, FailureKeepsPreviousOutputsAndRecordsError) {
  Run();
  EXPECT_EQ(Run({"produce.value=3", "produce.fail=true"}), std::make_pair(1, 0));
  EXPECT_EQ(last_exit_, 1);
  EXPECT_EQ(Read("a.txt"), "hello1");
  const auto record = ReadRecord((dir_ / "ws" / "records" / "produce.json").string());
  ASSERT_TRUE(record.has_value());
  EXPECT_EQ(record->status, "failed");
  EXPECT_NE(record->error.find("asked to fail"), std::string::npos);
  EXPECT_FALSE(Status()[0].up_to_date);
  EXPECT_EQ(Run(), std::make_pair(1, 0));  // identical a.txt again: consume stays up to date
}

TEST_F(RunnerTest, RecordHoldsInputsParamsAndCosts) {
  Run();
  const auto record = ReadRecord((dir_ / "ws" / "records" / "produce.json").string());
  ASSERT_TRUE(record.has_value());
  EXPECT_EQ(record->status, "ok");
  EXPECT_EQ(record->params["value"], 1);
  EXPECT_FALSE(record->params.contains("threads"));  // resource knobs are not part of the key
  EXPECT_EQ(record->inputs.size(), 1u);
  EXPECT_GE(record->wall_seconds, 0);
  EXPECT_GT(record->peak_memory_mb, 0);
  EXPECT_EQ(record->metrics["bytes"], 1);
}

// A per-view stage runs as many views at once as the memory budget holds (one at least), and its
// record keeps the budget, the estimate of one view and the views in flight. The budget is the
// process's: what it holds already counts against it.
TEST_F(RunnerTest, MemoryLimitCapsTheViewsInFlight) {
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\nstages:\n  - per_view\n";
  const double held = ResidentMemoryMb();
  ASSERT_GT(held, 0);
  for (const auto& [above, expected] : std::vector<std::pair<double, int>>{{150, 1}, {50, 1}, {260, 2}}) {
    const double limit = held + above;
    testing_stages::most_views_in_flight = 0;
    RunOptions options;
    options.jobs = 4;
    options.force = true;
    options.memory_limit_mb = limit;
    Run({}, options);
    ASSERT_EQ(last_exit_, 0);
    const auto record = ReadRecord((dir_ / "ws/records/per_view.json").string());
    ASSERT_TRUE(record);
    EXPECT_EQ(record->memory_budget_mb, limit);
    EXPECT_EQ(record->view_memory_mb, 100);
    EXPECT_EQ(record->views_in_flight, expected) << "limit " << limit;
    EXPECT_LE(testing_stages::most_views_in_flight, expected) << "limit " << limit;
    EXPECT_TRUE(fs::exists(dir_ / "ws/views/v7"));
  }
  // Memory the stage takes before its per-view loop (a loaded model) leaves room for fewer views.
  testing_stages::per_view_model_mb = 150;
  testing_stages::most_views_in_flight = 0;
  {
    RunOptions options;
    options.jobs = 4;
    options.force = true;
    options.memory_limit_mb = held + 260;
    Run({}, options);
    testing_stages::per_view_model_mb = 0;
    ASSERT_EQ(last_exit_, 0);
    EXPECT_EQ(ReadRecord((dir_ / "ws/records/per_view.json").string())->views_in_flight, 1);
    EXPECT_EQ(testing_stages::most_views_in_flight, 1);
  }
  // Without a limit: what the system has available, recorded.
  RunOptions options;
  options.force = true;
  Run({}, options);
  EXPECT_GT(ReadRecord((dir_ / "ws/records/per_view.json").string())->memory_budget_mb, 0);
}

// One writer per file: a config whose stages declare the same output (or one inside the other)
// is refused, naming both stages and the file.
TEST_F(RunnerTest, TwoStagesDeclaringOneOutputAreRefused) {
  auto shared = [&](const std::string& yaml) {
    std::ofstream(dir_ / "c.yaml") << yaml;
    return Runner(LoadConfig((dir_ / "c.yaml").string(), registry_), registry_).SharedOutputs();
  };
  EXPECT_EQ(shared("workspace: ws\nstages:\n  - produce\n  - consume\n"), "");
  const std::string same = shared("workspace: ws\nstages:\n  - produce\n  - consume: {output: a.txt}\n");
  EXPECT_NE(same.find("'produce' and 'consume' both write a.txt"), std::string::npos) << same;
  const std::string inside = shared("workspace: ws\nstages:\n  - per_view\n  - consume: {output: views/v1}\n");
  EXPECT_NE(inside.find("'per_view' and 'consume' both write views"), std::string::npos) << inside;
}

}  // namespace
}  // namespace ibmr
