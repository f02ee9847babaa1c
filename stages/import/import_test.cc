// Tests of the import stage: format parsers on inline text, and real Middlebury and Strecha
// folders from ../shared/datasets (skipped with a message when absent).
#include "stages/import/import.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/nerf_formats.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_import(StageRegistry* registry);

namespace {

const std::string kDatasets = std::string(IBMR_SHARED_DIR) + "/datasets";

std::string TempDir(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / ("ibmr_import_test_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

// Runs the import adapter on `source` into a fresh workspace and returns the model written.
SparseModel RunImport(const std::string& source, const std::string& workspace, int64_t max_image_size = 0) {
  StageRegistry registry;
  RegisterStage_import(&registry);
  const Stage* stage = registry.Find("import");
  StageContext context;
  context.workspace = Workspace(workspace);
  context.params.Set("source", source);
  context.params.Set("format", std::string("auto"));
  context.params.Set("images", std::string());
  context.params.Set("focal_prior", 1.2);
  context.params.Set("folder_camera_model", std::string("SIMPLE_RADIAL"));
  context.params.Set("max_image_size", max_image_size);
  context.params.Set("llff_downscale", int64_t{1});
  context.params.Set("splits", std::vector<std::string>{"train", "test"});
  context.params.Set("alpha", std::string("composite"));
  context.params.Set("background", std::string("white"));
  context.params.Set("alpha_premultiplied", false);
  NullProgress progress;
  context.progress = &progress;
  EXPECT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  return ReadSparseModelText(context.workspace.SparseDir());
}

TEST(ImportOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(ImportOptions().Check(&error)) << error;
}

TEST(ImportOptions, RejectsBadValues) {
  std::string error;
  ImportOptions options;
  options.focal_prior = 0;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind("focal_prior", 0), 0u) << error;
  options = ImportOptions();
  options.folder_camera_model = "FISHEYE";
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind("folder_camera_model", 0), 0u) << error;
}

TEST(MiddleburyPar, AddsHalfPixelToPrincipalPoint) {
  const std::string text =
      "1\nv1.png 1000 0 300 0 1100 200 0 0 1  1 0 0 0 1 0 0 0 1  0.1 0.2 0.3\n";
  const SparseModel model = ParseMiddleburyPar(text, "x_par.txt", [](const std::string&) { return std::make_pair(640, 480); });
  ASSERT_EQ(model.images.size(), 1u);
  const Camera& camera = model.cameras.begin()->second;
  EXPECT_DOUBLE_EQ(camera.PrincipalX(), 300.5);
  EXPECT_DOUBLE_EQ(camera.PrincipalY(), 200.5);
  // The Middlebury projection K [R t] of a point, with the pixel-centre shift, equals ours.
  const Eigen::Vector3d x(0.05, -0.02, 1.0);
  const Image& image = model.images.begin()->second;
  const Eigen::Vector2d pixel = camera.ImgFromCam(image.cam_from_world * x);
  const Eigen::Vector3d cam = x + Eigen::Vector3d(0.1, 0.2, 0.3);
  EXPECT_NEAR(pixel.x(), 1000 * cam.x() / cam.z() + 300 + 0.5, 1e-9);
  EXPECT_NEAR(pixel.y(), 1100 * cam.y() / cam.z() + 200 + 0.5, 1e-9);
}

TEST(MiddleburyPar, ErrorsNameFileAndLine) {
  const std::string text = "2\nv1.png 1000 0 300 0 1100 200 0 0 1 1 0 0 0 1 0 0 0 1 0 0 0\nv2.png 1 2 3\n";
  try {
    ParseMiddleburyPar(text, "t_par.txt", [](const std::string&) { return std::make_pair(64, 48); });
    FAIL() << "expected an error";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("t_par.txt:3"), std::string::npos) << e.what();
  }
}

TEST(StrechaCamera, CentreAndProjection) {
  const std::string text =
      "100 0 50\n0 110 40\n0 0 1\n0 0 0\n0 0 1\n1 0 0\n0 1 0\n1 2 3\n100 80\n";
  Camera camera;
  Rigid3d cam_from_world;
  ParseStrechaCamera(text, "a.camera", &camera, &cam_from_world);
  EXPECT_TRUE(cam_from_world.Inverse().translation.isApprox(Eigen::Vector3d(1, 2, 3), 1e-12));
  EXPECT_EQ(camera.width, 100);
  EXPECT_EQ(camera.height, 80);
  // Columns of R are the camera axes in the world: the third column (1, 0, 0) is the optical
  // axis, so a point ahead along world +x projects onto the principal point.
  const Eigen::Vector3d ahead(1 + 5, 2, 3);
  const Eigen::Vector2d pixel = camera.ImgFromCam(cam_from_world * ahead);
  EXPECT_NEAR(pixel.x(), 50.5, 1e-9);
  EXPECT_NEAR(pixel.y(), 40.5, 1e-9);
}

// Found by tests/fuzz/fuzz_strecha_camera: a width of 2e111 was cast to int (undefined behaviour).
// Sizes, focal lengths and centres out of range are errors naming the file.
TEST(StrechaCamera, FuzzRegressionOutOfRangeValuesAreErrors) {
  const std::string rotation = "0 0 0\n0 0 1\n1 0 0\n0 1 0\n";
  const std::vector<std::string> bad = {
      "2759.48 0 1520.6\n0 2764 81\n0 0 1\n" + rotation + "1 2 0\n3072 2011111111111111111111111111111111111111\n",
      "100 0 50\n0 110 40\n0 0 1\n" + rotation + "1 2 3\n100.5 80\n",
      "100 0 50\n0 110 40\n0 0 1\n" + rotation + "1 2 3\n-100 80\n",
      "-100 0 50\n0 110 40\n0 0 1\n" + rotation + "1 2 3\n100 80\n",
      "100 0 nan\n0 110 40\n0 0 1\n" + rotation + "1 2 3\n100 80\n",
      "100 0 50\n0 110 40\n0 0 1\n" + rotation + "1 inf 3\n100 80\n"};
  for (const std::string& text : bad) {
    Camera camera;
    Rigid3d cam_from_world;
    try {
      ParseStrechaCamera(text, "bad.camera", &camera, &cam_from_world);
      ADD_FAILURE() << "accepted:\n" << text;
    } catch (const IoError& e) {
      EXPECT_NE(std::string(e.what()).find("bad.camera"), std::string::npos) << e.what();
    }
  }
}

TEST(ImportMiddlebury, BoundingBoxProjectsInsideEveryTempleView) {
  const std::string source = kDatasets + "/middlebury_templeSparseRing";
  if (!fs::exists(source)) GTEST_SKIP() << source << " is absent; real-data test skipped";
  const std::string workspace = TempDir("temple");
  const SparseModel model = RunImport(source, workspace);
  ASSERT_EQ(model.images.size(), 16u);
  EXPECT_TRUE(fs::exists(workspace + "/images/templeSR0001.png"));
  // Tight bounding box from the data set's README.txt.
  const Eigen::Vector3d lo(-0.073568, 0.021728, -0.012445), hi(0.028855, 0.181892, 0.062736);
  for (const auto& [id, image] : model.images) {
    const Camera& camera = model.CameraOf(image);
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d x((corner & 1) ? hi.x() : lo.x(), (corner & 2) ? hi.y() : lo.y(),
                              (corner & 4) ? hi.z() : lo.z());
      const Eigen::Vector3d in_cam = image.cam_from_world * x;
      ASSERT_GT(in_cam.z(), 0) << image.name;
      const Eigen::Vector2d pixel = camera.ImgFromCam(in_cam);
      EXPECT_GE(pixel.x(), 0) << image.name;
      EXPECT_LE(pixel.x(), camera.width) << image.name;
      EXPECT_GE(pixel.y(), 0) << image.name;
      EXPECT_LE(pixel.y(), camera.height) << image.name;
    }
  }
  fs::remove_all(workspace);
}

TEST(ImportStrecha, FountainCamerasMatchTheFiles) {
  const std::string source = kDatasets + "/strecha_fountain-P11";
  if (!fs::exists(source)) GTEST_SKIP() << source << " is absent; real-data test skipped";
  const std::string workspace = TempDir("fountain");
  const SparseModel model = RunImport(source, workspace);
  ASSERT_EQ(model.images.size(), 11u);
  const Image* first = model.FindImage("0000.jpg");
  ASSERT_NE(first, nullptr);
  // 0000.jpg.camera: centre on line 8, K on lines 1-3.
  EXPECT_TRUE(first->Center().isApprox(Eigen::Vector3d(-7.28137, -7.57667, 0.204446), 1e-6));
  EXPECT_NEAR(model.CameraOf(*first).FocalX(), 2759.48, 1e-9);
  EXPECT_NEAR(model.CameraOf(*first).PrincipalX(), 1520.69 + 0.5, 1e-9);
  // The cameras face a common scene: every optical axis passes near the centroid of the others.
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& [id, image] : model.images) centroid += image.Center() + 10 * image.ViewingDirection();
  centroid /= model.images.size();
  for (const auto& [id, image] : model.images) {
    const Eigen::Vector3d to = (centroid - image.Center()).normalized();
    EXPECT_GT(to.dot(image.ViewingDirection()), 0.8) << image.name;
  }
  fs::remove_all(workspace);
}

// max_image_size: the 3072x2048 photos are resampled to 768x512 and the cameras scaled with them,
// so a world point projects to the same place relative to the image (a quarter of the pixels).
TEST(ImportStrecha, MaxImageSizeResamplesPhotosAndScalesCameras) {
  const std::string source = kDatasets + "/strecha_fountain-P11";
  if (!fs::exists(source)) GTEST_SKIP() << source << " is absent; real-data test skipped";
  const std::string full_dir = TempDir("fountain_full"), small_dir = TempDir("fountain_small");
  const SparseModel full = RunImport(source, full_dir);
  const SparseModel small = RunImport(source, small_dir, 768);
  const Image& image = *small.FindImage("0004.jpg");
  const Camera& camera = small.CameraOf(image);
  EXPECT_EQ(camera.width, 768);
  EXPECT_EQ(camera.height, 512);
  const cv::Mat photo = ReadImageColor(Workspace(small_dir).ImagesDir() + "/0004.jpg");
  EXPECT_EQ(photo.cols, 768);
  EXPECT_EQ(photo.rows, 512);
  const Camera& full_camera = full.CameraOf(*full.FindImage("0004.jpg"));
  const Eigen::Vector3d point = image.Center() + 8.0 * image.ViewingDirection() + Eigen::Vector3d(0.5, -0.3, 0.2);
  const Eigen::Vector2d p_small = camera.ImgFromCam(image.cam_from_world * point);
  const Eigen::Vector2d p_full = full_camera.ImgFromCam(image.cam_from_world * point);
  EXPECT_NEAR(p_small.x(), p_full.x() / 4, 1e-6);
  EXPECT_NEAR(p_small.y(), p_full.y() / 4, 1e-6);
  fs::remove_all(full_dir);
  fs::remove_all(small_dir);
}

// An LLFF folder (images/ and poses_bounds.npy, detected automatically): the poses and the
// centred pinhole cameras come back as written.
TEST(ImportLlff, PosesBoundsFolder) {
  const std::string source = TempDir("llff_source");
  fs::create_directories(source + "/images");
  SparseModel model;
  std::vector<std::string> names;
  std::vector<std::pair<double, double>> bounds;
  for (int i = 0; i < 3; ++i) {
    Camera camera = Camera::Pinhole(40, 30, 50, 50, 20, 15);
    camera.camera_id = i + 1;
    model.cameras[i + 1] = camera;
    Image image;
    image.image_id = image.camera_id = i + 1;
    image.name = "img" + std::to_string(i) + ".png";
    image.cam_from_world = LookAt(Eigen::Vector3d(i, -2, 0.5), Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0, 0, 1));
    model.images[i + 1] = image;
    names.push_back(image.name);
    bounds.emplace_back(1.0 + 0.25 * i, 5.0 + i);
    WriteImage(source + "/images/" + image.name, cv::Mat(30, 40, CV_8UC3, cv::Scalar(10 * i, 50, 90)));
  }
  WriteFileAtomic(source + "/poses_bounds.npy", WritePosesBounds(model, names, bounds));
  const std::string workspace = TempDir("llff_ws");
  const SparseModel imported = RunImport(source, workspace);
  ASSERT_EQ(imported.images.size(), 3u);
  for (const auto& [id, image] : model.images) {
    const Image* other = imported.FindImage(image.name);
    ASSERT_NE(other, nullptr);
    EXPECT_LT((image.Center() - other->Center()).norm(), 1e-9);
    EXPECT_LT((image.cam_from_world.R() - other->cam_from_world.R()).norm(), 1e-9);
    EXPECT_NEAR(imported.CameraOf(*other).FocalX(), 50, 1e-9);
  }
  // Each view's near/far bounds, recorded so that plane_sweep and volume need no depth range.
  const nlohmann::json recorded = nlohmann::json::parse(ReadFile(workspace + "/sparse/depth_bounds.json"));
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(recorded.at(names[i]).at("near").get<double>(), 1.0 + 0.25 * i, 1e-12) << names[i];
    EXPECT_NEAR(recorded.at(names[i]).at("far").get<double>(), 5.0 + i, 1e-12) << names[i];
  }
  fs::remove_all(source);
  fs::remove_all(workspace);
}

TEST(ImportFolder, MissingSourceIsAClearError) {
  const std::string workspace = TempDir("missing");
  try {
    RunImport("/nonexistent/folder", workspace);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/folder"), std::string::npos);
  }
  fs::remove_all(workspace);
}

// A dataset folder whose photos sit in a subfolder (fountain-P11's images/ beside its calibration):
// the error names the subfolder with the most photos and how many it holds.
TEST(ImportFolder, PhotosInASubfolderAreNamedInTheError) {
  const std::string source = TempDir("subfolder_source"), workspace = TempDir("subfolder");
  fs::create_directories(source + "/images");
  fs::create_directories(source + "/calibration");
  for (int i = 0; i < 3; ++i) WriteImage(source + "/images/" + std::to_string(i) + ".png", cv::Mat(30, 40, CV_8UC3, cv::Scalar(10 * i, 50, 90)));
  WriteImage(source + "/calibration/chart.png", cv::Mat(30, 40, CV_8UC3, cv::Scalar(1, 2, 3)));
  try {
    RunImport(source, workspace);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("no usable images"), std::string::npos) << message;
    EXPECT_NE(message.find("subfolder images holds 3"), std::string::npos) << message;
  }
  fs::remove_all(source);
  fs::remove_all(workspace);
}

}  // namespace
}  // namespace ibmr
