// The run's plan (issue 66): the runner analyses the capture once poses exist (capture.json),
// skips a stage whose model cannot serve its kind with a one-line reason and a "skipped" record,
// skips with it a stage that needs its outputs, and keeps what an earlier run of it left out of
// the stages after it; --with / plan.with force it, plan.kind overrides the analysis.
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <tuple>
#include <fstream>
#include <opencv2/core.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_rigs_for_test.h"
#include "pipeline/core/capture_shape.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/runner/config.h"
#include "pipeline/runner/record.h"
#include "pipeline/runner/runner.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

// Writes sparse/ with a rig (ring, grid or walk): what import or sfm leaves.
class Rig : public Stage {
 public:
  std::string Name() const override { return "rig"; }
  std::string Summary() const override { return "test: writes a camera rig to sparse/"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override { return {{"layout", ParamType::kString, "ring", "ring, grid or walk"}}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext&) const override { return {}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"sparse"}; }
  ModelFolders WritesModel() const override { return {"sparse", ""}; }
  void Run(StageContext& c) const override {
    const std::string layout = c.params.String("layout");
    const SparseModel model = layout == "grid"   ? capture_rigs::ForwardGrid()
                              : layout == "walk" ? capture_rigs::FacadeWalk()
                                                 : capture_rigs::Ring(12);
    WriteSparseModelText(c.workspace.Path("sparse"), model);
  }
};

// A model that serves forward-facing captures only (as the plane volume).
class Planes : public Stage {
 public:
  std::string Name() const override { return "planes"; }
  std::string Summary() const override { return "test: a forward-facing model"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext& c) const override { return {c.workspace.SparseRelative()}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"planes"}; }
  CaptureUse Serves() const override { return {{"forward_facing"}, "planes serve forward-facing captures"}; }
  void Run(StageContext& c) const override {
    fs::create_directories(c.workspace.Path("planes"));
    WriteFileAtomic(c.workspace.Path("planes/model.txt"), "planes");
  }
};

// Needs the planes (as carve needs the silhouettes' masks).
class OnPlanes : public Stage {
 public:
  std::string Name() const override { return "on_planes"; }
  std::string Summary() const override { return "test: needs planes/"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext&) const override { return {"planes/model.txt"}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"on_planes.txt"}; }
  bool SkippedWithItsInputs() const override { return true; }
  void Run(StageContext& c) const override {
    WriteFileAtomic(c.workspace.Path("on_planes.txt"), ReadFile(c.workspace.Path("planes/model.txt")));
  }
};

// Draws what it may (as render): the planes where they were not skipped, always the rig.
class Draw : public Stage {
 public:
  std::string Name() const override { return "draw"; }
  std::string Summary() const override { return "test: lists the models it draws"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kScoring; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext& c) const override { return {c.workspace.SparseRelative(), "planes"}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"drawn.txt"}; }
  void Run(StageContext& c) const override {
    std::string drawn = "rig";
    if (fs::exists(c.workspace.Path("planes")) && c.SkippedBy("planes") == nullptr) drawn += " planes";
    WriteFileAtomic(c.workspace.Path("drawn.txt"), drawn);
  }
};

class RunPlanTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_run_plan_test_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    registry_.Add(std::make_unique<Rig>());
    registry_.Add(std::make_unique<Planes>());
    registry_.Add(std::make_unique<OnPlanes>());
    registry_.Add(std::make_unique<Draw>());
  }
  void TearDown() override { fs::remove_all(dir_); }

  void WriteConfig(const std::string& layout, const std::string& plan = "") {
    std::ofstream(dir_ / "c.yaml") << "workspace: ws\n" << plan << "stages:\n  - rig: {layout: " << layout
                                   << "}\n  - planes\n  - on_planes\n  - draw\n";
  }
  int Run(const std::vector<std::string>& with = {}) {
    Config config = LoadConfig((dir_ / "c.yaml").string(), registry_);
    ApplyWith(with, &config);
    return Runner(config, registry_).Run(RunOptions());
  }
  std::string Read(const std::string& name) const { return ReadFile((dir_ / "ws" / name).string()); }
  StageRecord Record(const std::string& stage) const {
    return *ReadRecord((dir_ / "ws/records" / (stage + ".json")).string());
  }

  fs::path dir_;
  StageRegistry registry_;
};

TEST_F(RunPlanTest, AnObjectSkipsTheForwardFacingModelAndWhatNeedsIt) {
  WriteConfig("ring");
  ASSERT_EQ(Run(), 0);
  const nlohmann::json capture = ReadJsonOr((dir_ / "ws" / kCaptureFile).string(), nullptr);
  EXPECT_EQ(capture["kind"], "object") << capture.dump();
  EXPECT_EQ(capture["views"], 12);
  EXPECT_EQ(capture["model"], "sparse");

  const StageRecord planes = Record("planes");
  EXPECT_EQ(planes.status, "skipped");
  EXPECT_EQ(planes.skipped_because.rfind("planes: skipped, the capture is object (12 views; axis spread", 0), 0u)
      << planes.skipped_because;
  EXPECT_NE(planes.skipped_because.find("; planes serve forward-facing captures; --with planes runs it"), std::string::npos)
      << planes.skipped_because;
  EXPECT_FALSE(fs::exists(dir_ / "ws/planes"));
  const StageRecord on_planes = Record("on_planes");
  EXPECT_EQ(on_planes.status, "skipped");
  EXPECT_EQ(on_planes.skipped_because.rfind("on_planes: skipped, it needs 'planes/model.txt', which a skipped stage makes (planes: skipped", 0), 0u)
      << on_planes.skipped_because;
  EXPECT_EQ(Read("drawn.txt"), "rig");
  EXPECT_EQ(Record("draw").inputs["planes"], "skipped");

  // Again: nothing runs, the decisions stand; status says so.
  fs::remove(dir_ / "ws/drawn.txt");
  const nlohmann::json draw_inputs = Record("draw").inputs;
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(Record("draw").inputs, draw_inputs);
  EXPECT_EQ(Read("drawn.txt"), "rig");  // run again only for its missing output, with the same inputs
  const std::vector<StageStatus> status =
      Runner(LoadConfig((dir_ / "c.yaml").string(), registry_), registry_).Status();
  ASSERT_EQ(status.size(), 4u);
  EXPECT_TRUE(status[1].skipped);
  EXPECT_TRUE(status[2].skipped);
  EXPECT_FALSE(status[3].skipped);
  EXPECT_EQ(status[3].reason, "up to date");
}

TEST_F(RunPlanTest, AForwardFacingCaptureRunsIt) {
  WriteConfig("grid");
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(ReadJsonOr((dir_ / "ws" / kCaptureFile).string(), nullptr)["kind"], "forward_facing");
  EXPECT_EQ(Record("planes").status, "ok");
  EXPECT_EQ(Read("on_planes.txt"), "planes");
  EXPECT_EQ(Read("drawn.txt"), "rig planes");
}

TEST_F(RunPlanTest, WithForcesItAndLeavingItOutAgainDropsItsModel) {
  WriteConfig("walk");
  ASSERT_EQ(Run({"planes"}), 0);
  EXPECT_EQ(ReadJsonOr((dir_ / "ws" / kCaptureFile).string(), nullptr)["kind"], "general");
  EXPECT_EQ(Record("planes").status, "ok");
  EXPECT_EQ(Read("drawn.txt"), "rig planes");
  // Without --with: skipped again; the planes an earlier run left are kept on disk, but the stage
  // after it no longer draws them (its cache key changed with them).
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(Record("planes").status, "skipped");
  EXPECT_TRUE(fs::exists(dir_ / "ws/planes/model.txt"));
  EXPECT_EQ(Read("drawn.txt"), "rig");
  // A config's plan forces it too, and plan.kind overrides the analysis.
  WriteConfig("walk", "plan:\n  with: [planes]\n");
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(Record("planes").status, "ok");
  WriteConfig("walk", "plan:\n  kind: forward_facing\n");
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(Record("planes").status, "ok");
  const nlohmann::json capture = ReadJsonOr((dir_ / "ws" / kCaptureFile).string(), nullptr);
  EXPECT_EQ(capture["kind"], "forward_facing");
  EXPECT_EQ(capture["set_by"], "plan.kind (the analysis: general)");
}

TEST_F(RunPlanTest, PlanErrorsNameTheKey) {
  WriteConfig("ring", "plan:\n  with: [plane]\n");
  try {
    LoadConfig((dir_ / "c.yaml").string(), registry_);
    FAIL() << "a misspelt stage in plan.with was accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find(":3: key 'plan.with': 'plane' is not a stage of this config"), std::string::npos)
        << e.what();
    EXPECT_NE(std::string(e.what()).find("planes"), std::string::npos) << e.what();
  }
  WriteConfig("ring", "plan:\n  kind: turntable\n");
  EXPECT_THROW(LoadConfig((dir_ / "c.yaml").string(), registry_), ConfigError);
  WriteConfig("ring");
  Config config = LoadConfig((dir_ / "c.yaml").string(), registry_);
  EXPECT_THROW(ApplyWith({"volume"}, &config), ConfigError);
  ApplyWith({"all"}, &config);
  EXPECT_TRUE(config.plan.Forces("planes"));
}

}  // namespace
}  // namespace ibmr

// The race: a rig of 20 views with photos (the held-out ones garbage: a race that decoded one
// would fail), two models, one clearly better; the stage feeding only the worse one is left out
// of the full-size run.
namespace ibmr {
namespace {

std::atomic<int> good_runs{0}, bad_runs{0};

class PhotoRig : public Stage {
 public:
  std::string Name() const override { return "photo_rig"; }
  std::string Summary() const override { return "test: a forward grid with photos"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override { return {{"garbage", ParamType::kStringList, "[]", "photos written as garbage"}}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext&) const override { return {}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"sparse", "images"}; }
  ModelFolders WritesModel() const override { return {"sparse", "images"}; }
  void Run(StageContext& c) const override {
    const SparseModel model = capture_rigs::ForwardGrid();
    WriteSparseModelText(c.workspace.Path("sparse"), model);
    fs::create_directories(c.workspace.Path("images"));
    const std::vector<std::string> garbage = c.params.StringList("garbage");
    for (const auto& [id, image] : model.images) {
      const std::string path = c.workspace.Path("images/" + image.name);
      if (std::find(garbage.begin(), garbage.end(), image.name) != garbage.end()) {
        WriteFileAtomic(path, "not a photo: a held-out view the race must not read");
      } else {
        WriteImage(path, cv::Mat(48, 64, CV_8UC3, cv::Scalar(id * 10 % 255, 100, 50)));
      }
    }
  }
};

template <const char* kName, std::atomic<int>* kRuns>
class ModelStage : public Stage {
 public:
  std::string Name() const override { return kName; }
  std::string Summary() const override { return "test: a model"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext& c) const override { return {c.workspace.ImagesRelative()}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {std::string(kName) + "/model.txt"}; }
  void Run(StageContext& c) const override {
    ++*kRuns;
    // Reads every photo it may: the training views (LoadModel leaves the held-out ones out).
    for (const std::string& name : c.TrainingImageNames(c.LoadModel())) {
      if (ReadImageUnchanged(c.workspace.ImagesDir() + "/" + name).empty()) throw IoError(name + ": unreadable");
    }
    fs::create_directories(c.workspace.Path(kName));
    WriteFileAtomic(c.workspace.Path(std::string(kName) + "/model.txt"), kName);
  }
};
constexpr char kGood[] = "good";
constexpr char kBad[] = "bad";

// Draws and scores (render and score in one): good 30 dB, bad 20 dB, each where its model is.
class DrawAndScore : public Stage {
 public:
  std::string Name() const override { return "draw_score"; }
  std::string Summary() const override { return "test: scores the models"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kScoring; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext&) const override { return {"good/model.txt", "bad/model.txt"}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"scores"}; }
  std::vector<DrawnModel> DrawsModels(const StageContext&) const override {
    return {{"good", {"good/model.txt"}}, {"good_lite", {"good/model.txt"}}, {"bad", {"bad/model.txt"}}};
  }
  void Run(StageContext& c) const override {
    nlohmann::json proxies = nlohmann::json::object();
    const std::vector<std::tuple<std::string, std::string, double>> models = {
        {"good", "good", 30}, {"good_lite", "good", 25}, {"bad", "bad", 20}};
    for (const auto& [name, folder, psnr] : models) {
      if (c.left_out_models.count(name)) continue;  // lost the race
      if (fs::exists(c.workspace.Path(folder + "/model.txt")) && c.SkippedBy(folder + "/model.txt") == nullptr) {
        proxies[name] = {{"mean", {{"photo_psnr", psnr}, {"views", c.heldout_images.size()}}}};
      }
    }
    fs::create_directories(c.workspace.Path("scores"));
    WriteFileAtomic(c.workspace.Path("scores/heldout.json"),
                    nlohmann::json({{"proxies", proxies}, {"heldout", c.heldout_images}}).dump());
  }
};

TEST_F(RunPlanTest, TheRaceLeavesOutWhatFeedsOnlyTheLoserAndNeverReadsAHeldOutPhoto) {
  registry_.Add(std::make_unique<PhotoRig>());
  registry_.Add(std::make_unique<ModelStage<kGood, &good_runs>>());
  registry_.Add(std::make_unique<ModelStage<kBad, &bad_runs>>());
  registry_.Add(std::make_unique<DrawAndScore>());
  // Every 8th of the 20 sorted views held out: v101, v109, v117.
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\nholdout: {every: 8}\nplan:\n  race: {scale: 0.5, validation_every: 4}\n"
                                    "stages:\n  - photo_rig: {garbage: [v101.png, v109.png, v117.png]}\n"
                                    "  - good\n  - bad\n  - draw_score\n";
  const int good_before = good_runs, bad_before = bad_runs;
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(good_runs - good_before, 2);  // in the race and at full size
  EXPECT_EQ(bad_runs - bad_before, 1);    // in the race only
  const nlohmann::json race = ReadJsonOr((dir_ / "ws/race.json").string(), nullptr);
  EXPECT_EQ(race["best"], "good") << race.dump();
  EXPECT_EQ(race["winners"], nlohmann::json::array({"good"})) << race.dump();
  ASSERT_EQ(race["left_out"].size(), 1u) << race.dump();
  EXPECT_EQ(race["left_out"][0]["stage"], "bad");
  const StageRecord bad = Record("bad");
  EXPECT_EQ(bad.status, "skipped");
  EXPECT_NE(bad.skipped_because.find("the race left it out: the models drawn from it scored bad 20.00 dB at 0.5x size, "
                                     "more than 1 dB below good's 30.00 dB"),
            std::string::npos)
      << bad.skipped_because;
  const nlohmann::json scores = ReadJsonOr((dir_ / "ws/scores/heldout.json").string(), nullptr);
  EXPECT_TRUE(scores["proxies"].contains("good"));
  EXPECT_FALSE(scores["proxies"].contains("bad"));
  // good_lite lost too (25 dB): its stage is kept for good, but it is not drawn at full size.
  EXPECT_FALSE(scores["proxies"].contains("good_lite"));
  EXPECT_DOUBLE_EQ(race["models"]["good_lite"].get<double>(), 25);
  // The race's capture: the 17 training views at half size, none of the held-out ones; it scored
  // 4 of them (every 4th from the 2nd), none held out of the full run.
  const SparseModel raced = ReadSparseModelText((dir_ / "ws/race/sparse").string());
  EXPECT_EQ(raced.images.size(), 17u);
  for (const auto& [id, image] : raced.images) {
    EXPECT_NE(image.name, "v101.png");
    EXPECT_EQ(raced.CameraOf(image).width, 32);
  }
  EXPECT_FALSE(fs::exists(dir_ / "ws/race/images/v109.png"));
  EXPECT_EQ(ReadImageUnchanged((dir_ / "ws/race/images/v102.png").string()).cols, 32);
  const nlohmann::json raced_scores = ReadJsonOr((dir_ / "ws/race/scores/heldout.json").string(), nullptr);
  EXPECT_EQ(raced_scores["heldout"], nlohmann::json::array({"v104.png", "v108.png", "v113.png", "v118.png"}));
  EXPECT_EQ(race["validation"], raced_scores["heldout"]);
  // Again: the race is up to date, the decision stands, nothing runs; status says why.
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(good_runs - good_before, 2);
  EXPECT_EQ(bad_runs - bad_before, 1);
  const std::vector<StageStatus> status = Runner(LoadConfig((dir_ / "c.yaml").string(), registry_), registry_).Status();
  ASSERT_EQ(status.size(), 4u);
  EXPECT_TRUE(status[2].skipped);
  EXPECT_EQ(status[2].reason.rfind("skipped, the race left it out", 0), 0u) << status[2].reason;
  EXPECT_EQ(status[3].reason, "up to date");
  // --with runs it; the next whole run leaves it out again.
  ASSERT_EQ(Run({"bad"}), 0);
  EXPECT_EQ(bad_runs - bad_before, 2);
  EXPECT_TRUE(ReadJsonOr((dir_ / "ws/scores/heldout.json").string(), nullptr)["proxies"].contains("bad"));
  ASSERT_EQ(Run(), 0);
  EXPECT_EQ(Record("bad").status, "skipped");
  EXPECT_EQ(bad_runs - bad_before, 2);
  EXPECT_FALSE(ReadJsonOr((dir_ / "ws/scores/heldout.json").string(), nullptr)["proxies"].contains("bad"));
}

}  // namespace
}  // namespace ibmr
