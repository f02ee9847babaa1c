// Tests of eval_poses: option checks, a known similarity with a known rotation perturbation,
// unregistered cameras, too few shared cameras, and one adapter run on a temporary workspace.
#include "stages/eval_poses/eval_poses.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_eval_poses(StageRegistry* registry);

namespace {

// A ring of n cameras of radius 1 looking at the origin.
SparseModel Ring(int n) {
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(640, 480, 500, 500, 320, 240);
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "view" + std::to_string(10 + i) + ".png";
    image.cam_from_world = LookAt(Eigen::Vector3d(std::cos(a), std::sin(a), 0.3), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ());
    model.images[image.image_id] = image;
  }
  return model;
}

// The same cameras in another world frame: X_est = s * R * X_true + t.
SparseModel Transformed(const SparseModel& truth, double s, const Eigen::Matrix3d& r, const Eigen::Vector3d& t) {
  SparseModel est = truth;
  for (auto& [id, image] : est.images) {
    const Eigen::Vector3d centre = s * r * image.Center() + t;
    const Eigen::Matrix3d rotation = image.cam_from_world.R() * r.transpose();
    image.cam_from_world = Rigid3d(rotation, -rotation * centre);
  }
  return est;
}

TEST(EvalPosesOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(EvalPosesOptions().Check(&error)) << error;
}

TEST(EvalPosesOptions, RejectsBadValues) {
  EvalPosesOptions options;
  options.min_common = 2;
  std::string error;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind("min_common:", 0), 0u);
}

TEST(EvalPoses, SimilarityIsRemovedExactly) {
  const SparseModel truth = Ring(12);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const PoseEvaluation eval = EvaluatePoses(Transformed(truth, 3.5, r, Eigen::Vector3d(1, -2, 5)), truth, EvalPosesOptions());
  EXPECT_EQ(eval.registered, 12);
  EXPECT_NEAR(eval.scale, 1 / 3.5, 1e-9);
  EXPECT_LT(eval.max_rotation_deg, 1e-6);
  EXPECT_LT(eval.max_centre_fraction, 1e-9);
  EXPECT_NEAR(eval.ring_diameter, 2.0, 1e-9);
}

TEST(EvalPoses, KnownRotationErrorAndUnregistered) {
  const SparseModel truth = Ring(12);
  SparseModel est = Transformed(truth, 2.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  // Rotate camera 3 by 0.5 degrees about its own axis (centre unchanged), drop camera 5.
  Image& image = est.images.at(3);
  const Eigen::Vector3d centre = image.Center();
  const Eigen::Matrix3d rotation = Eigen::AngleAxisd(0.5 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix() * image.cam_from_world.R();
  image.cam_from_world = Rigid3d(rotation, -rotation * centre);
  est.images.erase(5);
  est.cameras[1].params[0] = 510;
  const PoseEvaluation eval = EvaluatePoses(est, truth, EvalPosesOptions());
  EXPECT_EQ(eval.registered, 11);
  ASSERT_EQ(eval.unregistered.size(), 1u);
  EXPECT_EQ(eval.unregistered[0], "view14.png");
  // The joint alignment spreads camera 3's error a little over all eleven (least squares: about
  // 0.5/11 deg each); the centres alone leave it all on camera 3.
  EXPECT_NEAR(eval.cameras[2].rotation_deg, 0.5, 0.05);
  EXPECT_LT(eval.median_rotation_deg, 0.05);
  EXPECT_NEAR(eval.centre_only.max_rotation_deg, 0.5, 1e-6);
  EXPECT_LT(eval.centre_only.median_rotation_deg, 1e-6);
  EXPECT_NEAR(eval.median_focal_fraction, 0.02, 1e-9);
}

// Cameras with exact orientations whose centres are warped: z += 0.01 x (a shear the centres
// show as a tilt of the ring of about 0.6 deg), then a similarity applied.
SparseModel ShearedCentres(const SparseModel& truth) {
  SparseModel est = truth;
  for (auto& [id, image] : est.images) {
    Eigen::Vector3d centre = image.Center();
    centre.z() += 0.01 * centre.x();
    const Eigen::Matrix3d rotation = image.cam_from_world.R();
    image.cam_from_world = Rigid3d(rotation, -rotation * centre);
  }
  const Eigen::Matrix3d r = Eigen::AngleAxisd(-1.1, Eigen::Vector3d(0.3, -1, 2).normalized()).toRotationMatrix();
  return Transformed(est, 0.7, r, Eigen::Vector3d(2, 0, -1));
}

TEST(EvalPoses, AlignmentUsesOrientationsAndCentres) {
  const SparseModel truth = Ring(16);
  const PoseEvaluation eval = EvaluatePoses(ShearedCentres(truth), truth, EvalPosesOptions());
  EXPECT_FALSE(eval.identical_to_truth);
  // Centres alone tilt the frame to fit the sheared ring, turning every orientation with it.
  EXPECT_GT(eval.centre_only.median_rotation_deg, 0.2);
  // With the orientations in the fit the tilt is mostly taken back: a degree of orientation
  // error costs as much as 2.5% of the diameter of centre error, and the shear moves centres by
  // at most 0.5% of it.
  EXPECT_LT(eval.median_rotation_deg, 0.5 * eval.centre_only.median_rotation_deg);
  EXPECT_LT(eval.median_centre_fraction, 0.01);
  EXPECT_NEAR(eval.scale, 1 / 0.7, 0.01);
}

TEST(EvalPoses, TruthAgainstItselfIsFlagged) {
  const SparseModel truth = Ring(8);
  EXPECT_TRUE(EvaluatePoses(truth, truth, EvalPosesOptions()).identical_to_truth);
  // Through a text round trip (the sfm fallback writes the known cameras back).
  const fs::path dir = fs::temp_directory_path() / ("ibmr_eval_identical_" + std::to_string(::getpid()));
  WriteSparseModelText(dir.string(), truth);
  EXPECT_TRUE(EvaluatePoses(ReadSparseModelText(dir.string()), truth, EvalPosesOptions()).identical_to_truth);
  fs::remove_all(dir);
  EXPECT_FALSE(EvaluatePoses(Transformed(truth, 2.0, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero()), truth,
                             EvalPosesOptions()).identical_to_truth);
}

TEST(EvalPoses, TooFewSharedCamerasIsAnError) {
  const SparseModel truth = Ring(6);
  SparseModel est = truth;
  for (int id = 3; id <= 6; ++id) est.images.erase(id);
  EXPECT_THROW(EvaluatePoses(est, truth, EvalPosesOptions()), InputError);
}

TEST(EvalPosesStage, AdapterWritesMetrics) {
  const fs::path ws = fs::temp_directory_path() / ("ibmr_eval_poses_test_" + std::to_string(::getpid()));
  fs::remove_all(ws);
  const SparseModel truth = Ring(8);
  WriteSparseModelText((ws / "ground_truth/sparse").string(), truth);
  WriteSparseModelText((ws / "sparse").string(), Transformed(truth, 0.5, Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 1)));
  StageRegistry registry;
  RegisterStage_eval_poses(&registry);
  const Stage* stage = registry.Find("eval_poses");
  StageContext context;
  context.workspace = Workspace(ws.string());
  context.params.Set("min_common", int64_t{3});
  context.params.Set("truth", std::string("ground_truth/sparse"));
  NullProgress progress;
  context.progress = &progress;
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  EXPECT_EQ(context.metrics["registered"], 8);
  EXPECT_LT(context.metrics["median_rotation_error_deg"].get<double>(), 1e-6);
  EXPECT_TRUE(fs::exists(ws / "eval_poses/poses.json"));
  fs::remove_all(ws);
}

}  // namespace
}  // namespace ibmr
