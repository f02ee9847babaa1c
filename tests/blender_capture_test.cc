// A capture as people download it, end to end: `ibmr synth-blender` writes a small object capture
// in NeRF's Blender layout (RGBA PNGs, train / val / test splits), and a config in the manner of
// configs/blender.yaml runs import (splits, alpha composited on white) -> silhouettes from the
// alpha -> carve (its box from the cameras and masks) -> render -> score. Checks: the test split is
// held out (every 2nd of it scored, the rest kept out of training too), masks are alpha > 0.5,
// every model's holes take the capture's white, and the full-image score is the filled one; with
// import.alpha ignore the photos' transparent pixels show black and no capture colour exists.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/image_io.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

const char kConfig[] = R"(workspace: ws_${IBMR_TEST_ALPHA}
inputs:
  images: capture
holdout:
  split: test
  every: 2
stages:
  - import: {format: transforms, alpha: ${IBMR_TEST_ALPHA}}
  - silhouettes: {mode: ${IBMR_TEST_SILHOUETTES}}
  - carve: {levels: 6}
  - render: {proxies: [hull/hull.ply], supersample: 1}
  - score: {photo_threshold: -1}
)";

TEST(BlenderCapture, SplitsAlphaAndTheCaptureBackgroundEndToEnd) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_blender_capture_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root);
  const std::string ibmr = IBMR_BINARY;
  auto run = ibmr_e2e::RunCommand(ibmr + " synth-blender " + (root / "capture").string() +
                                  " --size 96 --train 16 --val 2 --test 4 --supersample 2");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  for (const char* file : {"transforms_train.json", "transforms_val.json", "transforms_test.json", "test/r_3.png"}) {
    ASSERT_TRUE(fs::exists(root / "capture" / file)) << file;
  }
  const cv::Mat rgba = ibmr::ReadImageUnchanged((root / "capture/train/r_0.png").string());
  ASSERT_EQ(rgba.type(), CV_8UC4) << "RGBA as the layout ships it";
  EXPECT_EQ(rgba.at<cv::Vec4b>(0, 0)[3], 0) << "a transparent corner";
  std::ofstream(root / "c.yaml") << kConfig;

  run = ibmr_e2e::RunCommand("cd " + root.string() + " && IBMR_TEST_ALPHA=composite IBMR_TEST_SILHOUETTES=alpha " + ibmr +
                             " run c.yaml");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const fs::path ws = root / "ws_composite";
  // Splits: train and test read (val not asked), test held out from every training stage.
  const nlohmann::json splits = nlohmann::json::parse(ibmr::ReadFile((ws / "splits.json").string()));
  EXPECT_EQ(splits.size(), 20u);
  EXPECT_EQ(splits.value("test/r_1.png", ""), "test");
  const nlohmann::json carve = nlohmann::json::parse(ibmr::ReadFile((ws / "records/carve.json").string()));
  EXPECT_EQ(carve["heldout"], nlohmann::json({"test/r_0.png", "test/r_1.png", "test/r_2.png", "test/r_3.png"}));
  // Masks: alpha > 0.5 exactly, training ones in masks/, held-out ones apart.
  const cv::Mat alpha = ibmr::ReadImageUnchanged((ws / "alpha/train/r_5.png.png").string());
  const cv::Mat mask = ibmr::ReadImageUnchanged((ws / "masks/train/r_5.png.png").string());
  ASSERT_EQ(alpha.size(), mask.size());
  EXPECT_EQ(cv::countNonZero(mask != (alpha > 127)), 0);
  EXPECT_GT(cv::countNonZero(mask), 100);
  EXPECT_FALSE(fs::exists(ws / "masks/test/r_0.png.png"));
  // The photos composited on white; the scored views every 2nd of the test split.
  EXPECT_EQ(ibmr::ReadImageColor((ws / "images/train/r_0.png").string()).at<cv::Vec3b>(0, 0), cv::Vec3b(255, 255, 255));
  const nlohmann::json scores = nlohmann::json::parse(ibmr::ReadFile((ws / "scores/heldout.json").string()));
  const nlohmann::json& hull = scores["proxies"]["hull"];
  ASSERT_EQ(hull["views"].size(), 2u) << hull.dump();
  EXPECT_TRUE(hull["views"].contains("test/r_0.png"));
  EXPECT_TRUE(hull["views"].contains("test/r_2.png"));
  // Every model's holes take the capture's white: the filled render covers everything, its corner
  // (no object there) is white, and the full-image score is better than holes left black.
  const cv::Mat filled = ibmr::ReadImageColor((ws / "renders/hull/r_0.filled.png").string());
  EXPECT_EQ(filled.at<cv::Vec3b>(0, 0), cv::Vec3b(255, 255, 255));
  const nlohmann::json& mean = hull["mean"];
  EXPECT_NEAR(mean.value("filled_coverage", 0.0), 1.0, 1e-9);
  EXPECT_GT(mean.value("filled_psnr", 0.0), mean.value("photo_psnr", 0.0) + 3) << mean.dump();

  // For contrast: the alpha ignored, the transparent pixels show what they hold (black), no
  // capture colour, and silhouettes cannot take the alpha.
  run = ibmr_e2e::RunCommand("cd " + root.string() + " && IBMR_TEST_ALPHA=ignore IBMR_TEST_SILHOUETTES=alpha " + ibmr +
                             " run c.yaml");
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.output.find("silhouettes.mode: alpha: no alpha for view"), std::string::npos) << run.output;
  EXPECT_EQ(ibmr::ReadImageColor((root / "ws_ignore/images/train/r_0.png").string()).at<cv::Vec3b>(0, 0),
            cv::Vec3b(0, 0, 0));
  EXPECT_EQ(nlohmann::json::parse(ibmr::ReadFile((root / "ws_ignore/background.json").string()))["bgr"], nullptr);
  if (!::testing::Test::HasFailure()) fs::remove_all(root);
}

}  // namespace
