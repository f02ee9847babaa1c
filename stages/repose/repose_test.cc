// Tests of repose (issue 67): options, and a textured ground plane seen by a ring of cameras
// whose photos and depth maps are rendered exactly; one camera's written pose is turned by a few
// degrees and the refinement must bring it back to the true pose within 0.05 degrees, or keep it
// (with the reason) when the references give too few matches. One adapter run on a temporary
// workspace with a flagged view.
#include "stages/repose/repose.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <filesystem>
#include <opencv2/imgproc.hpp>
#include <random>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_repose(StageRegistry* registry);

namespace {

// A blurred random texture covering the world square [-1, 1]^2 of the plane z = 0.
cv::Mat Texture() {
  cv::Mat noise(256, 256, CV_8U);
  cv::RNG rng(5);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
  cv::Mat texture;
  cv::GaussianBlur(noise, texture, cv::Size(0, 0), 1.5);
  cv::normalize(texture, texture, 0, 255, cv::NORM_MINMAX);
  return texture;
}

// The photo and depth map of a camera looking at the plane (grey 40 off the square).
ReposeView Render(const std::string& name, const Camera& camera, const Rigid3d& cam_from_world, const cv::Mat& texture) {
  ReposeView view;
  view.name = name;
  view.camera = camera;
  view.cam_from_world = cam_from_world;
  view.depth = DepthMap(camera.width, camera.height, 1, 0.f);
  cv::Mat map_x(camera.height, camera.width, CV_32F, cv::Scalar(-1)), map_y(camera.height, camera.width, CV_32F, cv::Scalar(-1));
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const Eigen::Vector3d ray = camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));  // z = 1
      const Eigen::Vector3d dir = world_from_cam.rotation * ray;
      if (std::abs(dir.z()) < 1e-9) continue;
      const double t = -world_from_cam.translation.z() / dir.z();
      if (t <= 0) continue;
      const Eigen::Vector3d p = world_from_cam.translation + t * dir;
      if (std::abs(p.x()) > 1 || std::abs(p.y()) > 1) continue;
      view.depth.At(x, y) = static_cast<float>(t);  // t along (x, y, 1) is z
      map_x.at<float>(y, x) = static_cast<float>((p.x() + 1) / 2 * (texture.cols - 1));
      map_y.at<float>(y, x) = static_cast<float>((p.y() + 1) / 2 * (texture.rows - 1));
    }
  }
  cv::remap(texture, view.gray, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(40));
  return view;
}

Rigid3d RingPose(double azimuth_deg) {
  const double a = azimuth_deg * M_PI / 180;
  return LookAt(Eigen::Vector3d(2.2 * std::cos(a), 2.2 * std::sin(a), 2.0), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ());
}

Rigid3d Turned(const Rigid3d& pose, double degrees) {
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(degrees * M_PI / 180, Eigen::Vector3d(0.6, 0.8, 0).normalized()).toRotationMatrix();
  return Rigid3d(turn * pose.R(), turn * pose.translation);
}

struct Capture {
  Camera camera = Camera::Pinhole(320, 240, 300, 300, 160, 120);
  cv::Mat texture = Texture();
  std::vector<ReposeView> references;
  ReposeView target;  // rendered from its true pose RingPose(45)
};

Capture MakeCapture() {
  Capture c;
  for (double azimuth : {0.0, 20.0, 70.0, 90.0}) {
    c.references.push_back(Render("r" + std::to_string(static_cast<int>(azimuth)) + ".png", c.camera, RingPose(azimuth), c.texture));
  }
  c.target = Render("target.png", c.camera, RingPose(45), c.texture);
  return c;
}

TEST(ReposeOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(ReposeOptions().Check(&error)) << error;
}

TEST(ReposeOptions, RejectsInvalidRanges) {
  std::string error;
  auto rejects = [&](auto set, const std::string& key) {
    ReposeOptions o;
    set(o);
    EXPECT_FALSE(o.Check(&error)) << key;
    EXPECT_EQ(error.rfind(key + ":", 0), 0u) << error;
  };
  rejects([](ReposeOptions& o) { o.max_features = 10; }, "max_features");
  rejects([](ReposeOptions& o) { o.ratio = 0; }, "ratio");
  rejects([](ReposeOptions& o) { o.ratio = 1.5; }, "ratio");
  rejects([](ReposeOptions& o) { o.ransac_px = 0; }, "ransac_px");
  rejects([](ReposeOptions& o) { o.min_inliers = 5; }, "min_inliers");
  rejects([](ReposeOptions& o) { o.max_rotation_deg = 0; }, "max_rotation_deg");
  rejects([](ReposeOptions& o) { o.num_neighbors = 0; }, "num_neighbors");
  rejects([](ReposeOptions& o) { o.min_rms_px = -1; }, "min_rms_px");
}

TEST(Repose, ATurnedCameraReturnsToItsTruePose) {
  Capture c = MakeCapture();
  const Rigid3d truth = c.target.cam_from_world;
  for (double degrees : {1.0, 3.0}) {
    c.target.cam_from_world = Turned(truth, degrees);
    const ReposeResult r = RefineViewPose(c.target, c.references, ReposeOptions());
    ASSERT_TRUE(r.accepted) << degrees << ": " << r.reason;
    EXPECT_GT(r.inliers, 100u);
    EXPECT_NEAR(r.rotation_change_deg, degrees, 0.05);
    EXPECT_LT(r.cam_from_world.rotation.angularDistance(truth.rotation) * 180 / M_PI, 0.05) << degrees;
    EXPECT_LT((r.cam_from_world.Inverse().translation - truth.Inverse().translation).norm(), 0.01) << degrees;
    EXPECT_LT(r.rms_after_px, 1.0);
    EXPECT_GT(r.rms_before_px, 4.0);  // a degree is ~5 px at f = 300
  }
}

TEST(Repose, KeepsAPoseThatAlreadyFits) {
  Capture c = MakeCapture();
  const Rigid3d truth = c.target.cam_from_world;
  const ReposeResult r = RefineViewPose(c.target, c.references, ReposeOptions());  // the true pose
  EXPECT_FALSE(r.accepted);
  EXPECT_LT(r.rms_before_px, 1.0);
  EXPECT_NE(r.reason.find("min_rms_px"), std::string::npos) << r.reason;
  EXPECT_TRUE(r.cam_from_world.rotation.isApprox(truth.rotation));
}

TEST(Repose, KeepsThePoseWithoutEnoughMatches) {
  Capture c = MakeCapture();
  c.target.cam_from_world = Turned(c.target.cam_from_world, 2.0);
  for (ReposeView& r : c.references) r.depth = DepthMap(r.depth.width, r.depth.height, 1, 0.f);  // nothing lifts to 3D
  const ReposeResult r = RefineViewPose(c.target, c.references, ReposeOptions());
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.reason.find("fewer than min_inliers"), std::string::npos) << r.reason;
  EXPECT_TRUE(r.cam_from_world.rotation.isApprox(c.target.cam_from_world.rotation));
}

TEST(ReposeStage, RefinesTheFlaggedViewOfAWorkspace) {
  Capture c = MakeCapture();
  const fs::path root = fs::temp_directory_path() / ("ibmr_repose_" + std::to_string(::getpid()));
  fs::remove_all(root);
  Workspace workspace(root.string());
  SparseModel model;
  model.cameras[1] = c.camera;
  std::vector<ReposeView> all = c.references;
  all.push_back(c.target);
  const Rigid3d truth = c.target.cam_from_world;
  for (size_t i = 0; i < all.size(); ++i) {
    Image image;
    image.image_id = static_cast<int>(i) + 1;
    image.camera_id = 1;
    image.name = all[i].name;
    image.cam_from_world = all[i].name == "target.png" ? Turned(truth, 2.0) : all[i].cam_from_world;
    model.images[image.image_id] = image;
    WriteImage(workspace.ImagesDir() + "/" + image.name, all[i].gray);
    WriteColmapArray(workspace.DepthMapPath(image.name, "geometric"), all[i].depth);
  }
  WriteSparseModelText(workspace.SparseDir(), model);
  WriteFileAtomic(workspace.ViewAgreementPath(), R"({"flagged": ["target.png"], "views": []})");
  StageRegistry registry;
  RegisterStage_repose(&registry);
  const Stage* stage = registry.Find("repose");
  ASSERT_NE(stage, nullptr);
  NullProgress progress;
  StageContext context;
  context.workspace = workspace;
  context.role = stage->Role();
  context.progress = &progress;
  for (const ParamSpec& spec : stage->Parameters()) {
    if (spec.type == ParamType::kInt) context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
    if (spec.type == ParamType::kDouble) context.params.Set(spec.key, std::stod(spec.default_yaml));
    if (spec.type == ParamType::kBool) context.params.Set(spec.key, spec.default_yaml == "true");
  }
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  EXPECT_EQ(context.metrics["views_refined"].get<size_t>(), 1u) << context.metrics.dump();
  const SparseModel refined = ReadSparseModelText(workspace.Path("repose/sparse"));
  ASSERT_EQ(refined.images.size(), 5u);
  const Image* target = refined.FindImage("target.png");
  ASSERT_NE(target, nullptr);
  EXPECT_LT(target->cam_from_world.rotation.angularDistance(truth.rotation) * 180 / M_PI, 0.05);
  EXPECT_TRUE(refined.FindImage("r0.png")->cam_from_world.rotation.isApprox(c.references[0].cam_from_world.rotation));
  EXPECT_TRUE(fs::exists(workspace.Path("repose/repose.json")));
  // Without multi_depth's file: a message naming it and the stage to run.
  fs::remove(workspace.ViewAgreementPath());
  try {
    stage->Run(context);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("view_agreement.json"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("multi_depth"), std::string::npos) << e.what();
  }
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
