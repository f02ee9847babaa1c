// Tests of the undistort stage: a point seen through a distorted camera lands, after
// undistortion, where the pinhole camera projects it; the model conversion moves 2D points the
// same way; one adapter run on a temporary workspace.
#include "stages/undistort/undistort.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_undistort(StageRegistry* registry);

namespace {

Camera Distorted() {
  Camera camera;
  camera.model = CameraModelId::kOpenCV;
  camera.width = 320;
  camera.height = 240;
  camera.params = {300, 300, 161.3, 118.7, -0.2, 0.05, 0.001, -0.002};
  return camera;
}

TEST(UndistortOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(UndistortOptions().Check(&error)) << error;
}

// Source pixel values are their own x coordinate (a linear ramp, exact under bilinear lookup):
// the undistorted image at pixel p must hold the distorted x of p's ray.
TEST(Undistort, RampLandsWhereTheRayProjects) {
  const Camera camera = Distorted();
  cv::Mat image(camera.height, camera.width, CV_32F);
  for (int r = 0; r < image.rows; ++r) {
    for (int c = 0; c < image.cols; ++c) image.at<float>(r, c) = c + 0.5f;
  }
  cv::Mat mx, my;
  UndistortMaps(camera, &mx, &my);
  const cv::Mat out = UndistortImage(image, mx, my);
  const Camera pinhole = camera.Undistorted();
  for (const auto& [col, row] : std::vector<std::pair<int, int>>{{160, 120}, {40, 30}, {290, 200}, {100, 180}}) {
    const Eigen::Vector2d source = camera.ImgFromCam(pinhole.CamFromImg(Eigen::Vector2d(col + 0.5, row + 0.5)));
    EXPECT_NEAR(out.at<float>(row, col), source.x(), 0.04) << col << "," << row;  // remap: 1/32 px steps
  }
  EXPECT_NE(out.at<float>(30, 40), 40.5f);  // the lookup moved: distortion is not ignored
}

// One view of the Distorted() camera observing `point`.
SparseModel OneDistortedView(const Eigen::Vector3d& point) {
  SparseModel model;
  model.cameras[1] = Distorted();
  Image image;
  image.image_id = 1;
  image.camera_id = 1;
  image.name = "a.png";
  image.points2D.push_back({model.cameras[1].ImgFromCam(point), -1});
  model.images[1] = image;
  return model;
}

TEST(Undistort, ModelPointsFollowTheCamera) {
  const Eigen::Vector3d point(-0.3, 0.2, 1.0);
  const SparseModel model = OneDistortedView(point);
  const SparseModel out = UndistortModel(model);
  EXPECT_FALSE(out.cameras.at(1).HasDistortion());
  const Eigen::Vector2d expected = out.cameras.at(1).ImgFromCam(point);
  EXPECT_NEAR((out.images.at(1).points2D[0].xy - expected).norm(), 0, 1e-6);
}

// max_image_size: the undistorted camera is scaled so that its longest side fits, and the 2D
// points follow it (they still lie where the 3D point projects).
TEST(Undistort, LargeImagesAreScaledToTheMaxImageSize) {
  const Eigen::Vector3d point(-0.3, 0.2, 1.0);
  const SparseModel model = OneDistortedView(point);
  UndistortOptions options;
  const int longest = std::max(model.cameras.at(1).width, model.cameras.at(1).height);
  options.max_image_size = longest / 2;
  const SparseModel out = UndistortModel(model, options);
  const Camera& camera = out.cameras.at(1);
  EXPECT_EQ(std::max(camera.width, camera.height), longest / 2);
  EXPECT_NEAR(camera.FocalX(), 0.5 * model.cameras.at(1).FocalX(), 0.01 * camera.FocalX());
  EXPECT_NEAR((out.images.at(1).points2D[0].xy - camera.ImgFromCam(point)).norm(), 0, 1e-6);
  options.max_image_size = 0;  // as they are
  EXPECT_EQ(UndistortModel(model, options).cameras.at(1).width, model.cameras.at(1).width);
  options.max_image_size = 8;
  std::string error;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind("max_image_size:", 0), 0u) << error;
}

TEST(UndistortStage, AdapterWritesDenseFolders) {
  const fs::path ws = fs::temp_directory_path() / ("ibmr_undistort_test_" + std::to_string(::getpid()));
  fs::remove_all(ws);
  SparseModel model;
  model.cameras[1] = Distorted();
  Image image;
  image.image_id = 1;
  image.camera_id = 1;
  image.name = "a.png";
  model.images[1] = image;
  WriteSparseModelText((ws / "sparse").string(), model);
  fs::create_directories(ws / "images");
  WriteImage((ws / "images/a.png").string(), cv::Mat(240, 320, CV_8UC3, cv::Scalar(10, 20, 30)));
  StageRegistry registry;
  RegisterStage_undistort(&registry);
  const Stage* stage = registry.Find("undistort");
  StageContext context;
  context.workspace = Workspace(ws.string());
  NullProgress progress;
  context.progress = &progress;
  stage->Run(context);
  EXPECT_TRUE(fs::exists(ws / "dense/images/a.png"));
  EXPECT_FALSE(ReadSparseModelText((ws / "dense/sparse").string()).cameras.at(1).HasDistortion());
  fs::remove_all(ws);
}

}  // namespace
}  // namespace ibmr
