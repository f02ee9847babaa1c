// Tests of the silhouettes stage: options, threshold/morphology/components on drawn images with a
// known answer, background differencing, user masks, and adapter runs on a temporary workspace
// (holdout routing to heldout/masks/, wrong-size masks named in the error).
#include "stages/silhouettes/silhouettes.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_silhouettes(StageRegistry* registry);

namespace {

double Iou(const cv::Mat& a, const cv::Mat& b) {
  return static_cast<double>(cv::countNonZero(a & b)) / std::max(1, cv::countNonZero(a | b));
}

// A grey disc (with dark "shadow" spots inside) and a small bright speck on a black background.
cv::Mat DiscImage(cv::Mat* truth) {
  cv::Mat image(120, 160, CV_8UC3, cv::Scalar(10, 10, 10));
  cv::circle(image, {80, 60}, 35, cv::Scalar(150, 140, 130), cv::FILLED);
  cv::circle(image, {70, 55}, 3, cv::Scalar(20, 20, 20), cv::FILLED);  // shadow: a hole
  cv::circle(image, {90, 70}, 2, cv::Scalar(5, 5, 5), cv::FILLED);
  cv::circle(image, {10, 10}, 1, cv::Scalar(200, 200, 200), cv::FILLED);  // speck
  *truth = cv::Mat::zeros(image.size(), CV_8UC1);
  cv::circle(*truth, {80, 60}, 35, 255, cv::FILLED);
  return image;
}

TEST(SilhouetteOptions, DefaultsAreValidAndMatchTheDinoRecipe) {
  SilhouetteOptions options;
  std::string error;
  EXPECT_TRUE(options.Check(&error)) << error;
  EXPECT_DOUBLE_EQ(options.threshold, 0.19);
  EXPECT_EQ(options.dilate_px, 10);
  EXPECT_EQ(options.erode_px, 7);
}

TEST(SilhouetteOptions, RejectsOutOfRange) {
  const std::vector<std::pair<std::string, std::function<void(SilhouetteOptions*)>>> cases = {
      {"threshold", [](SilhouetteOptions* o) { o->threshold = 1.0; }},
      {"threshold", [](SilhouetteOptions* o) { o->threshold = -0.1; }},
      {"dilate_px", [](SilhouetteOptions* o) { o->dilate_px = -1; }},
      {"erode_px", [](SilhouetteOptions* o) { o->erode_px = 201; }},
      {"max_components", [](SilhouetteOptions* o) { o->max_components = -1; }},
      {"min_component_px", [](SilhouetteOptions* o) { o->min_component_px = -5; }},
      {"max_hole_px", [](SilhouetteOptions* o) { o->max_hole_px = -2; }},
  };
  for (const auto& [key, mutate] : cases) {
    SilhouetteOptions options;
    mutate(&options);
    std::string error;
    EXPECT_FALSE(options.Check(&error)) << key;
    EXPECT_EQ(error.rfind(key, 0), 0u) << error;
  }
}

TEST(ExtractSilhouette, ThresholdMorphologyComponentsRecoverTheDisc) {
  cv::Mat truth;
  const cv::Mat image = DiscImage(&truth);
  SilhouetteOptions options;  // dino recipe: closes the shadows, net dilation ~3 px
  const SilhouetteResult result = ExtractSilhouette(image, cv::Mat(), options);
  EXPECT_EQ(result.report.components_kept, 1);
  EXPECT_EQ(result.report.components_found, 2);  // disc and speck
  EXPECT_EQ(result.mask.at<uint8_t>(10, 10), 0);  // speck removed
  EXPECT_EQ(result.mask.at<uint8_t>(55, 70), 255);  // shadow closed
  // Conservative: the disc is inside the mask, and the mask is at most ~3 px wider.
  EXPECT_EQ(cv::countNonZero(truth & ~result.mask), 0);
  cv::Mat grown;
  cv::dilate(truth, grown, cv::getStructuringElement(cv::MORPH_ELLIPSE, {9, 9}));
  EXPECT_EQ(cv::countNonZero(result.mask & ~grown), 0);
  EXPECT_FALSE(result.report.touches_border);

  options.dilate_px = options.erode_px = 0;
  options.max_hole_px = 0;
  const SilhouetteResult raw = ExtractSilhouette(image, cv::Mat(), options);
  EXPECT_EQ(raw.mask.at<uint8_t>(55, 70), 0);  // without morphology or filling the shadow is a hole
  options.max_hole_px = -1;
  const SilhouetteResult filled = ExtractSilhouette(image, cv::Mat(), options);
  EXPECT_EQ(filled.report.holes_filled, 2);
  EXPECT_GT(Iou(filled.mask, truth), 0.99);
}

TEST(ExtractSilhouette, BackgroundDifferencing) {
  cv::Mat background(80, 100, CV_8UC3, cv::Scalar(40, 160, 90));
  cv::randu(background, cv::Scalar(30, 150, 80), cv::Scalar(50, 170, 100));
  cv::Mat image = background.clone();
  cv::rectangle(image, {20, 10}, {59, 69}, cv::Scalar(200, 30, 30), cv::FILLED);  // touches no border
  cv::rectangle(image, {90, 30}, {99, 40}, cv::Scalar(0, 0, 0), cv::FILLED);      // touches the border
  SilhouetteOptions options;
  options.mode = SilhouetteMode::kBackground;
  options.threshold = 0.2;
  options.dilate_px = options.erode_px = 0;
  options.max_components = 0;
  const SilhouetteResult result = ExtractSilhouette(image, background, options);
  EXPECT_EQ(cv::countNonZero(result.mask), 40 * 60 + 10 * 11);
  EXPECT_EQ(result.report.components_kept, 2);
  EXPECT_TRUE(result.report.touches_border);
  EXPECT_THROW(ExtractSilhouette(image, cv::Mat(10, 10, CV_8UC3), options), std::invalid_argument);
}

TEST(ExtractSilhouette, UserMaskIsBinarisedOnly) {
  cv::Mat mask = cv::Mat::zeros(20, 30, CV_8UC1);
  mask(cv::Rect(5, 5, 4, 4)) = 200;
  mask(cv::Rect(20, 5, 1, 1)) = 100;  // below 127: background
  SilhouetteOptions options;
  options.mode = SilhouetteMode::kUserMask;
  const SilhouetteResult result = ExtractSilhouette(mask, cv::Mat(), options);
  EXPECT_EQ(cv::countNonZero(result.mask), 16);
  EXPECT_NEAR(result.report.foreground_fraction, 16.0 / 600, 1e-12);
}

// A workspace with four 64x48 views of a bright square; returns its root.
std::string TinyWorkspace(const std::string& tag) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_sil_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "images");
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(64, 48, 50, 50, 32, 24);
  model.cameras[1].camera_id = 1;
  for (int i = 0; i < 4; ++i) {
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    model.images[image.image_id] = image;
    cv::Mat pixels(48, 64, CV_8UC3, cv::Scalar(0, 0, 0));
    cv::rectangle(pixels, {20 + i, 10}, {40 + i, 30}, cv::Scalar(255, 255, 255), cv::FILLED);
    WriteImage((root / "images" / image.name).string(), pixels);
  }
  fs::create_directories(root / "sparse");
  WriteSparseModelText((root / "sparse").string(), model);
  return root.string();
}

StageContext MakeContext(const std::string& root, const Stage& stage, NullProgress* progress) {
  StageContext context;
  context.workspace = Workspace(root);
  for (const ParamSpec& spec : stage.Parameters()) {
    switch (spec.type) {
      case ParamType::kInt: context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml))); break;
      case ParamType::kDouble: context.params.Set(spec.key, std::stod(spec.default_yaml)); break;
      default: {
        std::string value = spec.default_yaml;
        if (value == "\"\"") value.clear();
        context.params.Set(spec.key, value);
      }
    }
  }
  context.role = stage.Role();
  context.progress = progress;
  return context;
}

TEST(SilhouettesStage, RoutesHeldOutViewsToTheirOwnFolder) {
  StageRegistry registry;
  RegisterStage_silhouettes(&registry);
  const Stage* stage = registry.Find("silhouettes");
  ASSERT_NE(stage, nullptr);
  EXPECT_EQ(stage->Role(), HoldoutRole::kScoring);
  const std::string root = TinyWorkspace("route");
  NullProgress progress;
  StageContext context = MakeContext(root, *stage, &progress);
  context.params.Set("dilate_px", int64_t{0});
  context.params.Set("erode_px", int64_t{0});
  context.heldout_images = {"v2.png"};
  // A stale mask of the held-out view in masks/ (from a run without holdout) must disappear.
  fs::create_directories(root + "/masks");
  WriteImage(root + "/masks/v2.png.png", cv::Mat::zeros(48, 64, CV_8UC1));
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  EXPECT_TRUE(fs::exists(root + "/masks/v0.png.png"));
  EXPECT_FALSE(fs::exists(root + "/masks/v2.png.png"));
  EXPECT_TRUE(fs::exists(root + "/heldout/masks/v2.png.png"));
  const cv::Mat mask = ReadImageUnchanged(root + "/masks/v1.png.png");
  EXPECT_EQ(mask.size(), cv::Size(64, 48));
  EXPECT_EQ(cv::countNonZero(mask), 21 * 21);
  std::ifstream in(root + "/masks/report.json");
  const nlohmann::json report = nlohmann::json::parse(in);
  EXPECT_EQ(report["views"].size(), 3u);
  EXPECT_FALSE(report["views"].contains("v2.png"));
  EXPECT_NEAR(report["views"]["v0.png"]["foreground_fraction"].get<double>(), 441.0 / (64 * 48), 1e-9);
  EXPECT_EQ(context.metrics["heldout_views"], 1);
  fs::remove_all(root);
}

TEST(SilhouettesStage, WrongSizeUserMaskNamesTheFile) {
  StageRegistry registry;
  RegisterStage_silhouettes(&registry);
  const Stage* stage = registry.Find("silhouettes");
  const std::string root = TinyWorkspace("wrongsize");
  fs::create_directories(root + "/user");
  for (int i = 0; i < 4; ++i) {
    WriteImage(root + "/user/v" + std::to_string(i) + ".png", cv::Mat::zeros(48, i == 3 ? 32 : 64, CV_8UC1));
  }
  NullProgress progress;
  StageContext context = MakeContext(root, *stage, &progress);
  context.params.Set("mode", std::string("user"));
  EXPECT_TRUE(stage->CheckParams(context.params).has_value());  // no folder given
  context.params.Set("mask_folder", std::string("workspace:user"));
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  try {
    stage->Run(context);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("user/v3.png"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("32x48"), std::string::npos) << e.what();
  }
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
