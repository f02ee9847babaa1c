// Captures as people download them: NeRF's Blender layout with its three splits and RGBA photos,
// nerfstudio's split lists, through the import adapter into a workspace (images/, alpha/,
// splits.json, background.json), and the errors for a split naming a missing photo, a frame
// without a matrix and a mix of sizes.
#include "stages/import/transforms_splits.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_info.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_import(StageRegistry* registry);

namespace {

std::string TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("ibmr_splits_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

// A frame looking at the origin from `x` along the world x axis (OpenGL camera axes).
nlohmann::json Frame(const std::string& file_path, double x) {
  // Camera at (x, 0, 0) looking towards -x: its backwards axis +x, right +y... any rotation will do.
  return {{"file_path", file_path},
          {"transform_matrix", {{0, 0, 1, x}, {1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 0, 1}}}};
}

// An RGBA photo: left half opaque red-ish, right half transparent with green under it.
cv::Mat RgbaPhoto(int size, int depth = CV_8U) {
  cv::Mat image(size, size, CV_8UC4, cv::Scalar(0, 255, 0, 0));
  image(cv::Rect(0, 0, size / 2, size)).setTo(cv::Scalar(40, 60, 200, 255));
  if (depth == CV_16U) image.convertTo(image, CV_16UC4, 257.0);
  return image;
}

// A Blender-layout folder: `per_split` frames in each of train, val and test, RGBA PNGs of `size`.
std::string BlenderFolder(const std::string& name, int per_split, int size = 16) {
  const std::string dir = TempDir(name);
  for (const std::string split : {"train", "val", "test"}) {
    fs::create_directories(fs::path(dir) / split);
    nlohmann::json top = {{"camera_angle_x", 0.69}, {"frames", nlohmann::json::array()}};
    for (int i = 0; i < per_split; ++i) {
      WriteImage(dir + "/" + split + "/r_" + std::to_string(i) + ".png", RgbaPhoto(size));
      top["frames"].push_back(Frame("./" + split + "/r_" + std::to_string(i), 4.0 + i + (split == "test" ? 0.5 : 0)));
    }
    std::ofstream(dir + "/transforms_" + split + ".json") << top.dump(2);
  }
  return dir;
}

struct Imported {
  SparseModel model;
  Workspace workspace;
};

Imported RunImport(const std::string& source, const std::string& name, std::vector<std::string> splits = {"train", "test"},
                   const std::string& alpha = "composite", const std::string& background = "white",
                   bool premultiplied = false) {
  StageRegistry registry;
  RegisterStage_import(&registry);
  const Stage* stage = registry.Find("import");
  StageContext context;
  context.workspace = Workspace(TempDir(name + "_ws"));
  context.params.Set("source", source);
  context.params.Set("format", std::string("transforms"));
  context.params.Set("images", std::string());
  context.params.Set("focal_prior", 1.2);
  context.params.Set("folder_camera_model", std::string("SIMPLE_RADIAL"));
  context.params.Set("max_image_size", int64_t{0});
  context.params.Set("llff_downscale", int64_t{1});
  context.params.Set("splits", splits);
  context.params.Set("alpha", alpha);
  context.params.Set("background", background);
  context.params.Set("alpha_premultiplied", premultiplied);
  NullProgress progress;
  context.progress = &progress;
  const std::optional<ParamError> error = stage->CheckParams(context.params);
  if (error) throw InputError(error->key + ": " + error->message);
  stage->Run(context);
  return {ReadSparseModelText(context.workspace.SparseDir()), context.workspace};
}

std::string ErrorOf(const std::function<void()>& run) {
  try {
    run();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

TEST(BlenderLayout, TrainAndTestSplitsReadValOnlyWhenAsked) {
  const std::string dir = BlenderFolder("splits", 3);
  const Imported imported = RunImport(dir, "splits");
  EXPECT_EQ(imported.model.images.size(), 6u) << "train and test, not val";
  ASSERT_NE(imported.model.FindImage("train/r_0.png"), nullptr);
  ASSERT_NE(imported.model.FindImage("test/r_0.png"), nullptr) << "one file name in two splits stays two images";
  EXPECT_EQ(imported.model.FindImage("val/r_0.png"), nullptr);
  const ImageSplits splits = ReadImageSplits(imported.workspace);
  EXPECT_EQ(splits.at("train/r_2.png"), "train");
  EXPECT_EQ(splits.at("test/r_1.png"), "test");
  EXPECT_EQ(splits.size(), 6u);
  // Both splits' cameras: identical intrinsics share one camera; the test poses are the files'.
  EXPECT_EQ(imported.model.cameras.size(), 1u);
  EXPECT_NEAR(imported.model.FindImage("test/r_0.png")->Center().x(), 4.5, 1e-12);

  const Imported with_val = RunImport(dir, "splits_val", {"train", "val", "test"});
  EXPECT_EQ(with_val.model.images.size(), 9u);
  EXPECT_EQ(ReadImageSplits(with_val.workspace).at("val/r_0.png"), "val");
  EXPECT_NE(ErrorOf([&] { RunImport(dir, "no_train", {"test"}); }).find("train"), std::string::npos);
}

TEST(BlenderLayout, AlphaCompositedOnEachBackgroundAndKeptAsMasks) {
  const std::string dir = BlenderFolder("alpha", 1);
  for (const auto& [background, bgr] : std::vector<std::pair<std::string, cv::Vec3b>>{
           {"white", {255, 255, 255}}, {"black", {0, 0, 0}}, {"[10, 20, 30]", {30, 20, 10}}}) {
    const Imported imported = RunImport(dir, "alpha", {"train", "test"}, "composite", background);
    const cv::Mat image = ReadImageColor(imported.workspace.ImagesDir() + "/test/r_0.png");
    EXPECT_EQ(image.at<cv::Vec3b>(5, 12), bgr) << background << ": transparent pixels take the background";
    EXPECT_EQ(image.at<cv::Vec3b>(5, 2), cv::Vec3b(40, 60, 200)) << background << ": opaque ones keep their colour";
    const cv::Mat alpha = ReadImageUnchanged(imported.workspace.Path("alpha/test/r_0.png.png"));
    ASSERT_EQ(alpha.type(), CV_8UC1);
    EXPECT_EQ(alpha.at<uint8_t>(5, 2), 255);
    EXPECT_EQ(alpha.at<uint8_t>(5, 12), 0);
    const std::optional<CaptureBackground> recorded = ReadCaptureBackground(imported.workspace);
    ASSERT_TRUE(recorded.has_value());
    EXPECT_EQ(recorded->bgr, bgr);
  }
  // mask: alpha kept, colour as stored (green under the transparent half); no background colour.
  const Imported masked = RunImport(dir, "alpha_mask", {"train", "test"}, "mask");
  EXPECT_EQ(ReadImageColor(masked.workspace.ImagesDir() + "/test/r_0.png").at<cv::Vec3b>(5, 12), cv::Vec3b(0, 255, 0));
  EXPECT_TRUE(fs::exists(masked.workspace.Path("alpha/test/r_0.png.png")));
  EXPECT_FALSE(ReadCaptureBackground(masked.workspace).has_value());
  // ignore: neither.
  const Imported ignored = RunImport(dir, "alpha_ignore", {"train", "test"}, "ignore");
  EXPECT_FALSE(fs::exists(ignored.workspace.Path("alpha/test/r_0.png.png")));
  EXPECT_FALSE(ReadCaptureBackground(ignored.workspace).has_value());
}

TEST(BlenderLayout, SixteenBitAndPremultipliedPhotos) {
  const std::string dir = BlenderFolder("sixteen", 1);
  cv::Mat photo = RgbaPhoto(16, CV_16U);
  photo.at<cv::Vec4w>(3, 3) = {65535, 65535, 65535, 32768};  // white at just over one half
  WriteImage(dir + "/test/r_0.png", photo);
  const Imported imported = RunImport(dir, "sixteen", {"train", "test"}, "composite", "black");
  const cv::Mat image = ReadImageColor(imported.workspace.ImagesDir() + "/test/r_0.png");
  EXPECT_EQ(image.at<cv::Vec3b>(5, 2), cv::Vec3b(40, 60, 200));
  EXPECT_EQ(image.at<cv::Vec3b>(3, 3), cv::Vec3b(128, 128, 128));
  EXPECT_EQ(ReadImageUnchanged(imported.workspace.Path("alpha/test/r_0.png.png")).at<uint8_t>(3, 3), 128);

  cv::Mat premultiplied(16, 16, CV_8UC4, cv::Scalar(50, 50, 50, 128));
  WriteImage(dir + "/test/r_0.png", premultiplied);
  const Imported pre = RunImport(dir, "premultiplied", {"train", "test"}, "composite", "white", true);
  // 50 + 255 * (1 - 128 / 255) = 177; read straight it would be 50 * 0.502 + 127 = 152.
  EXPECT_EQ(ReadImageColor(pre.workspace.ImagesDir() + "/test/r_0.png").at<cv::Vec3b>(0, 0), cv::Vec3b(177, 177, 177));
}

TEST(BlenderLayout, PhotosWithoutAlphaAreUntouched) {
  const std::string dir = BlenderFolder("opaque", 1);
  cv::Mat rgb(16, 16, CV_8UC3, cv::Scalar(1, 2, 3));
  WriteImage(dir + "/train/r_0.png", rgb);
  const Imported imported = RunImport(dir, "opaque");
  EXPECT_EQ(ReadFile(imported.workspace.ImagesDir() + "/train/r_0.png"), ReadFile(dir + "/train/r_0.png"));
  EXPECT_FALSE(fs::exists(imported.workspace.Path("alpha/train/r_0.png.png")));
  EXPECT_TRUE(fs::exists(imported.workspace.Path("alpha/test/r_0.png.png")));
}

TEST(BlenderLayout, BadInputNamesTheFileAndFrame) {
  {
    const std::string dir = BlenderFolder("missing", 3);
    fs::remove(dir + "/test/r_2.png");
    const std::string error = ErrorOf([&] { RunImport(dir, "missing"); });
    EXPECT_NE(error.find("transforms_test.json"), std::string::npos) << error;
    EXPECT_NE(error.find("frame 2"), std::string::npos) << error;
    EXPECT_NE(error.find("test/r_2.png"), std::string::npos) << error;
  }
  {
    const std::string dir = BlenderFolder("no_matrix", 2);
    nlohmann::json top = nlohmann::json::parse(ReadFile(dir + "/transforms_train.json"));
    top["frames"][1].erase("transform_matrix");
    std::ofstream(dir + "/transforms_train.json") << top.dump();
    const std::string error = ErrorOf([&] { RunImport(dir, "no_matrix"); });
    EXPECT_NE(error.find("transforms_train.json"), std::string::npos) << error;
    EXPECT_NE(error.find("frame 1"), std::string::npos) << error;
    EXPECT_NE(error.find("transform_matrix"), std::string::npos) << error;
  }
  {
    const std::string dir = BlenderFolder("sizes", 2);
    WriteImage(dir + "/test/r_1.png", RgbaPhoto(24));
    const std::string error = ErrorOf([&] { RunImport(dir, "sizes"); });
    EXPECT_NE(error.find("transforms_test.json"), std::string::npos) << error;
    EXPECT_NE(error.find("frame 1"), std::string::npos) << error;
    EXPECT_NE(error.find("24x24"), std::string::npos) << error;
    EXPECT_NE(error.find("16x16"), std::string::npos) << error;
  }
  {
    const std::string dir = BlenderFolder("shared", 1);
    nlohmann::json top = nlohmann::json::parse(ReadFile(dir + "/transforms_test.json"));
    top["frames"][0]["file_path"] = "./train/r_0";
    std::ofstream(dir + "/transforms_test.json") << top.dump();
    const std::string error = ErrorOf([&] { RunImport(dir, "shared"); });
    EXPECT_NE(error.find("train split names too"), std::string::npos) << error;
  }
}

TEST(NerfstudioSplits, FilenameListsGiveEachFramesSplit) {
  const std::string dir = TempDir("nerfstudio");
  fs::create_directories(dir + "/images");
  nlohmann::json top = {{"fl_x", 20.0}, {"fl_y", 20.0}, {"cx", 8.0}, {"cy", 8.0}, {"w", 16}, {"h", 16},
                        {"frames", nlohmann::json::array()}};
  for (int i = 0; i < 4; ++i) {
    WriteImage(dir + "/images/f" + std::to_string(i) + ".png", cv::Mat(16, 16, CV_8UC3, cv::Scalar(i, i, i)));
    top["frames"].push_back(Frame("images/f" + std::to_string(i) + ".png", 4.0 + i));
  }
  top["train_filenames"] = {"images/f0.png", "images/f1.png"};
  top["val_filenames"] = {"images/f2.png"};
  top["test_filenames"] = {"./images/f3.png"};
  std::ofstream(dir + "/transforms.json") << top.dump(2);
  const Imported imported = RunImport(dir, "nerfstudio");
  EXPECT_EQ(imported.model.images.size(), 3u) << "val left out unless asked";
  const ImageSplits splits = ReadImageSplits(imported.workspace);
  EXPECT_EQ(splits.at("images/f3.png"), "test");
  EXPECT_EQ(splits.at("images/f0.png"), "train");
  EXPECT_EQ(splits.count("images/f2.png"), 0u);

  top["test_filenames"] = {"images/f9.png"};
  std::ofstream(dir + "/transforms.json") << top.dump(2);
  const std::string error = ErrorOf([&] { RunImport(dir, "nerfstudio_bad"); });
  EXPECT_NE(error.find("test_filenames"), std::string::npos) << error;
  EXPECT_NE(error.find("images/f9.png"), std::string::npos) << error;
}

TEST(BackgroundColour, ParsesNamesAndTriples) {
  cv::Vec3b bgr;
  std::string error;
  ASSERT_TRUE(ParseBackgroundColor("[255, 128, 0]", &bgr, &error));
  EXPECT_EQ(bgr, cv::Vec3b(0, 128, 255));
  ASSERT_TRUE(ParseBackgroundColor("1,2,3", &bgr, &error));
  EXPECT_EQ(bgr, cv::Vec3b(3, 2, 1));
  EXPECT_FALSE(ParseBackgroundColor("grey", &bgr, &error));
  EXPECT_NE(error.find("white, black or [r, g, b]"), std::string::npos);
  EXPECT_FALSE(ParseBackgroundColor("[1, 2, 300]", &bgr, &error));
  EXPECT_FALSE(ParseBackgroundColor("[1, 2]", &bgr, &error));
  EXPECT_FALSE(ParseBackgroundColor("[1, 2, 3, 4]", &bgr, &error));
}

}  // namespace
}  // namespace ibmr
