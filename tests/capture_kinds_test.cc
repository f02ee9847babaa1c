// The capture's kind as a run finds it (issue 66): the synthetic ring (object), forward-facing
// grid (forward_facing) and a walk past a room's objects (general), and the repository's real
// captures with their known cameras: templeRing (a ring round the temple: object) and
// fountain-P11 (a quarter turn in front of the fountain: general). Sceaux, whose poses come from
// sfm, is checked in mixed_sizes_test.cc where COLMAP has already run.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

const fs::path kDatasets = fs::path(IBMR_SOURCE_DIR) / "../shared/datasets";

class CaptureKinds : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_capture_kinds_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // Runs a one-stage config (synth or import) and returns capture.json.
  nlohmann::json KindOf(const std::string& stage, const std::string& images = "") {
    std::ofstream(dir_ / "c.yaml") << "workspace: ws\n"
                                   << (images.empty() ? "" : "inputs:\n  images: " + images + "\n")
                                   << "stages:\n  - " << stage << "\n";
    fs::remove_all(dir_ / "ws");
    const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run " + (dir_ / "c.yaml").string());
    EXPECT_EQ(run.exit_code, 0) << run.output;
    EXPECT_NE(run.output.find("capture: "), std::string::npos) << run.output;
    return ibmr::ReadJsonOr((dir_ / "ws/capture.json").string(), nullptr);
  }

  fs::path dir_;
};

TEST_F(CaptureKinds, SyntheticScenes) {
  const nlohmann::json ring = KindOf("synth: {scene: object_ring, views: 12, width: 80, height: 60, supersample: 1}");
  EXPECT_EQ(ring["kind"], "object") << ring.dump();
  EXPECT_GT(ring["convergence"]["surround_deg"].get<double>(), 300);
  const nlohmann::json forward = KindOf("synth: {scene: forward_facing, views: 12, width: 80, height: 60, supersample: 1}");
  EXPECT_EQ(forward["kind"], "forward_facing") << forward.dump();
  EXPECT_LT(forward["baseline_over_near"].get<double>(), 0.5);
  const nlohmann::json walk =
      KindOf("synth: {scene: room, baseline: 4, views: 12, width: 80, height: 60, supersample: 1}");
  EXPECT_EQ(walk["kind"], "general") << walk.dump();
  EXPECT_GT(walk["baseline_over_near"].get<double>(), 0.5);
}

TEST_F(CaptureKinds, RealCapturesWithKnownCameras) {
  if (!fs::exists(kDatasets / "middlebury_templeRing/templeR_par.txt") ||
      !fs::exists(kDatasets / "strecha_fountain-P11/images")) {
    GTEST_SKIP() << kDatasets << " lacks templeRing or fountain-P11; real-data test skipped";
  }
  const nlohmann::json temple =
      KindOf("import: {format: middlebury}", (kDatasets / "middlebury_templeRing").string());
  EXPECT_EQ(temple["kind"], "object") << temple.dump();
  EXPECT_EQ(temple["views"], 47);
  EXPECT_GT(temple["convergence"]["surround_deg"].get<double>(), 300);
  const nlohmann::json fountain =
      KindOf("import: {format: strecha, max_image_size: 256}", (kDatasets / "strecha_fountain-P11").string());
  EXPECT_EQ(fountain["kind"], "general") << fountain.dump();
  EXPECT_EQ(fountain["views"], 11);
  EXPECT_GT(fountain["axis_spread_deg"].get<double>(), 35);  // too wide for planes facing one way
  EXPECT_LT(fountain["convergence"]["surround_deg"].get<double>(), 150);  // converging, not round it
}

}  // namespace

namespace {

// A folder of photos has no poses: a config without sfm stops at the first stage that needs them,
// saying that sfm gives them (tried as a new user would: it used to say "no images; run import").
TEST_F(CaptureKinds, PhotosWithoutPosesNameTheMissingStep) {
  fs::create_directories(dir_ / "photos");
  for (int i = 0; i < 7; ++i) {  // each its own (import sets exact duplicates aside)
    const cv::Mat photo(48, 64, CV_8UC3, cv::Scalar(40 + 20 * i, 80, 120));
    ibmr::WriteImage((dir_ / "photos" / ("p" + std::to_string(i) + ".png")).string(), photo);
  }
  std::ofstream(dir_ / "c.yaml") << "workspace: ws\ninputs:\n  images: photos\nstages:\n"
                                    "  - import: {format: folder}\n  - silhouettes: {}\n";
  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run " + (dir_ / "c.yaml").string());
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("the 7 photos in images/ have no poses yet"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("add an sfm stage after import"), std::string::npos) << run.output;
  EXPECT_FALSE(fs::exists(dir_ / "ws/capture.json"));  // no poses, no shape
}

}  // namespace

namespace {

// The one command a newcomer needs: `ibmr run FOLDER` on a folder of photos picks the photo chain,
// would write it beside the folder, and (here, as a dry run) says what it would run.
TEST_F(CaptureKinds, RunOnAFolderOfPhotos) {
  fs::create_directories(dir_ / "garden");
  for (int i = 0; i < 3; ++i) {
    ibmr::WriteImage((dir_ / "garden" / ("p" + std::to_string(i) + ".jpg")).string(),
                     cv::Mat(48, 64, CV_8UC3, cv::Scalar(40 + 20 * i, 80, 120)));
  }
  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run " + (dir_ / "garden").string() + " --dry-run");
  EXPECT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("a folder of 3 photos without poses; would run configs/photos.yaml in " +
                            (dir_ / "garden.ibmr").string()),
            std::string::npos)
      << run.output;
  EXPECT_FALSE(fs::exists(dir_ / "garden.ibmr"));  // a dry run leaves nothing behind
  EXPECT_NE(run.output.find("[sfm] would run"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("[volume] serves forward_facing captures only"), std::string::npos) << run.output;
}

}  // namespace
