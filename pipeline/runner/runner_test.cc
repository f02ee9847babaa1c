// The runner's cache: what runs after a parameter change, an input change, a resource-knob
// change; --only / --from / --to / --force; status reasons; failures keep earlier outputs.
#include "pipeline/runner/runner.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/capture_info.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/process_memory.h"
#include "pipeline/runner/fake_stages_for_test.h"
#include "pipeline/runner/record.h"
#include "pipeline/runner/stage_lock.h"

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

// A stage that gains a parameter in a later version: a workspace run before it stays up to date
// while the parameter is at its default (nothing else in the key changed), and setting it away
// from the default reruns the stage as any parameter change does.
TEST_F(RunnerTest, AParameterAddedLaterAtItsDefaultLeavesOldRunsUpToDate) {
  Run({"produce.value=3"});
  testing_stages::produce_gains_a_parameter = true;
  for (const auto& s : Status({"produce.value=3"})) EXPECT_TRUE(s.up_to_date) << s.name << ": " << s.reason;
  EXPECT_EQ(Run({"produce.value=3"}), std::make_pair(0, 0));
  EXPECT_EQ(Run({"produce.value=3", "produce.added=0"}), std::make_pair(0, 0)) << "set, but to its default";
  const auto status = Status({"produce.value=3", "produce.added=2"});
  EXPECT_NE(status[0].reason.find("parameter 'added' changed"), std::string::npos) << status[0].reason;
  EXPECT_EQ(Run({"produce.value=3", "produce.added=2"}), std::make_pair(1, 0)) << "a.txt the same: consume's input unchanged";
  // Another parameter changed beside the default one: stale as ever.
  EXPECT_EQ(Run({"produce.value=4", "produce.added=2"}), std::make_pair(1, 1));
  testing_stages::produce_gains_a_parameter = false;
  EXPECT_EQ(Run({"produce.value=4"}), std::make_pair(1, 0)) << "the record holds 'added': a parameter gone changes the key";
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
  // Was: --from/--to silently widened --only.
  for (const bool use_from : {true, false}) {
    RunOptions both;
    both.only = "consume";
    (use_from ? both.from : both.to) = "produce";
    both.force = true;
    EXPECT_EQ(Run({}, both), std::make_pair(0, 0));
    EXPECT_EQ(last_exit_, 2);
  }
}

// A second run on a workspace whose stage was still running elsewhere took the record's
// "running" for an interrupted run, started the stage again and removed the first run's
// temporary files as left-overs.
TEST_F(RunnerTest, AStageRunningInAnotherProcessIsNotStartedAgain) {
  Run();
  const std::string before = Read("a.txt");
  const std::string record_path = (dir_ / "ws/records/produce.json").string();
  StageRecord record = *ReadRecord(record_path);
  record.status = "running";
  WriteRecord(record_path, record);
  {
    StageLock elsewhere;  // another open of the lock file stands for another process
    std::string holder;
    ASSERT_TRUE(elsewhere.TryLock((dir_ / "ws/records/produce.lock").string(), true, &holder));
    const std::vector<StageStatus> status = Status();
    EXPECT_NE(status[0].reason.find("running now in another process (pid " + std::to_string(::getpid())),
              std::string::npos)
        << status[0].reason;
    EXPECT_EQ(Run({"produce.value=5"}), std::make_pair(0, 0));
    EXPECT_EQ(last_exit_, 1);
    EXPECT_EQ(Read("a.txt"), before);
  }
  EXPECT_EQ(Status()[0].reason, "interrupted while running (will resume)");
  EXPECT_EQ(Run({"produce.value=5"}), std::make_pair(1, 1));
  EXPECT_EQ(last_exit_, 0);
}

TEST_F(RunnerTest, DryRunChangesNothing) {
  RunOptions dry;
  dry.dry_run = true;
  EXPECT_EQ(Run({}, dry), std::make_pair(0, 0));
  EXPECT_FALSE(fs::exists(dir_ / "ws" / "a.txt"));
  EXPECT_FALSE(fs::exists(dir_ / "ws")) << "a dry run made the workspace's records/";
}

// A name of holdout.images that the model does not have was accepted, and the log said the view
// was held out while every view trained.
TEST_F(RunnerTest, UnknownHeldOutImageNameIsAnError) {
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(4, 4, 2, 2, 2, 2);
  for (int id = 1; id <= 4; ++id) {
    Image image;
    image.image_id = id;
    image.camera_id = 1;
    image.name = "view_00" + std::to_string(id) + ".png";
    model.images[id] = image;
  }
  WriteSparseModelText((dir_ / "ws" / "sparse").string(), model);
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\nholdout:\n  images:\n    - view_002.png\n    - view_03.png\n"
                                    "stages:\n  - produce\n  - consume\n";
  try {
    Run();
    ADD_FAILURE() << "ran with an unknown held-out image";
  } catch (const ConfigError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("c.yaml:5: key 'holdout.images': 'view_03.png' is not an image of the model"),
              std::string::npos) << message;
    EXPECT_NE(message.find("did you mean 'view_003.png'?"), std::string::npos) << message;
  }
  EXPECT_FALSE(fs::exists(dir_ / "ws" / "b.txt"));
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\nholdout:\n  images: [view_003.png]\nstages:\n  - produce\n  - consume\n";
  EXPECT_EQ(Run().second, 1);
  EXPECT_EQ(ReadRecord((dir_ / "ws/records/consume.json").string())->heldout, nlohmann::json({"view_003.png"}));
}

// holdout: {split: test} reads the import's splits.json; a capture without that split is an error
// naming the key and what the capture holds.
TEST_F(RunnerTest, HoldoutSplitReadsTheCapturesSplits) {
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(4, 4, 2, 2, 2, 2);
  const std::vector<std::string> names = {"test/r_0.png", "test/r_1.png", "train/r_0.png", "train/r_1.png"};
  for (size_t i = 0; i < names.size(); ++i) {
    Image image;
    image.image_id = static_cast<int>(i) + 1;
    image.camera_id = 1;
    image.name = names[i];
    model.images[image.image_id] = image;
  }
  WriteSparseModelText((dir_ / "ws" / "sparse").string(), model);
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\nholdout:\n  split: test\nstages:\n  - produce\n  - consume\n";
  try {
    Run();
    ADD_FAILURE() << "ran without splits";
  } catch (const ConfigError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("c.yaml:3: key 'holdout.split': the capture has no image of the test split"), std::string::npos)
        << message;
    EXPECT_NE(message.find("no splits.json"), std::string::npos) << message;
  }
  WriteImageSplits(Workspace((dir_ / "ws").string()), {{"test/r_0.png", "test"}, {"test/r_1.png", "test"},
                                                      {"train/r_0.png", "train"}, {"train/r_1.png", "train"}});
  EXPECT_EQ(Run().second, 1);
  EXPECT_EQ(ReadRecord((dir_ / "ws/records/consume.json").string())->heldout,
            nlohmann::json({"test/r_0.png", "test/r_1.png"}));
}

// A workspace inside the folder a stage reads (inputs.images: . with workspace: ibmr_out): the
// folder's hash took in the workspace's own records and logs, so the stage ran again every time.
TEST_F(RunnerTest, WorkspaceInsideAnInputFolderIsLeftOutOfItsHash) {
  fs::create_directories(dir_ / "photos");
  std::ofstream(dir_ / "photos" / "a.png") << "A";
  std::ofstream(dir_ / "c.yaml") << "workspace: photos/ibmr_out\nstages:\n  - list_folder: {folder: photos}\n";
  const auto runs = [&]() {
    const int before = testing_stages::list_folder_runs;
    Run();
    EXPECT_EQ(last_exit_, 0);
    return testing_stages::list_folder_runs - before;
  };
  EXPECT_EQ(runs(), 1);
  EXPECT_EQ(runs(), 0);
  std::ofstream(dir_ / "photos" / "b.png") << "B";
  EXPECT_EQ(runs(), 1) << "the photos still count";
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

// A stage's warnings go into its record; a later stage's failure quotes them (the likely cause
// upstream), from the record even when the warning stage was cached.
TEST_F(RunnerTest, AFailureQuotesTheWarningsOfTheStagesBeforeIt) {
  Run({"produce.warn=true"});
  const auto produced = ReadRecord((dir_ / "ws" / "records" / "produce.json").string());
  ASSERT_TRUE(produced.has_value());
  EXPECT_EQ(produced->warning_count, 2u);
  ASSERT_EQ(produced->warnings.size(), 2u);
  EXPECT_EQ(produced->warnings[0], "[produce] the source is thin");
  EXPECT_EQ(Run({"produce.warn=true", "consume.fail=true"}), std::make_pair(0, 1));
  const auto consumed = ReadRecord((dir_ / "ws" / "records" / "consume.json").string());
  ASSERT_TRUE(consumed.has_value());
  EXPECT_EQ(consumed->status, "failed");
  EXPECT_EQ(consumed->error, "consume: a.txt is too thin (earlier warnings: [produce] the source is thin (2 warnings))");
  // A stage that warned of nothing adds nothing.
  Run({"consume.fail=true"});
  const auto quiet = ReadRecord((dir_ / "ws" / "records" / "consume.json").string());
  EXPECT_EQ(quiet->error, "consume: a.txt is too thin");
  EXPECT_TRUE(ReadRecord((dir_ / "ws" / "records" / "produce.json").string())->warnings.empty());
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
// File names in another encoding are legal on Linux; dump() threw "[json.exception.type_error.316]
// incomplete UTF-8 string" naming no file, and the stage's record was never written.
TEST_F(RunnerTest, RecordsOfNonUtf8NamesAreWritten) {
  StageRecord record;
  record.stage = "produce";
  record.status = "ok";
  record.outputs = nlohmann::json::array({"photos/caf\xe9.png"});
  record.inputs = {{"/data/caf\xe9", "0123"}};
  const std::string path = (dir_ / "records" / "produce.json").string();
  ASSERT_NO_THROW(WriteRecord(path, record));
  const auto back = ReadRecord(path);
  ASSERT_TRUE(back.has_value());
  EXPECT_EQ(back->outputs[0], "photos/caf\xef\xbf\xbd.png");  // U+FFFD in place of the byte
  EXPECT_EQ(DumpJson(nlohmann::json("caf\xc3\xa9")), "\"caf\xc3\xa9\"") << "UTF-8 is kept as it is";
  // A whole run in a workspace whose name is not UTF-8.
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\xff\nstages:\n  - produce\n  - consume\n";
  EXPECT_EQ(Run(), std::make_pair(1, 1));
  EXPECT_EQ(last_exit_, 0);
  EXPECT_EQ(Run(), std::make_pair(0, 0));
}

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
