// Tests for Rigid3d (apply, Inverse, Compose) and LookAt in the computer-vision camera frame.
#include "pipeline/core/rigid3.h"

#include <gtest/gtest.h>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

Rigid3d SomeTransform() {
  const Eigen::Quaterniond r(Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, -2, 0.5).normalized()));
  return Rigid3d(r, Eigen::Vector3d(0.3, -1.2, 2.5));
}

TEST(Rigid3d, InverseUndoesTransform) {
  const Rigid3d a = SomeTransform();
  const Eigen::Vector3d x(1.5, -0.25, 4);
  EXPECT_NEAR((a.Inverse() * (a * x) - x).norm(), 0, 1e-12);
  EXPECT_NEAR((a * (a.Inverse() * x) - x).norm(), 0, 1e-12);
  const Rigid3d identity = a.Compose(a.Inverse());
  EXPECT_NEAR(identity.translation.norm(), 0, 1e-12);
  EXPECT_NEAR(identity.rotation.angularDistance(Eigen::Quaterniond::Identity()), 0, 1e-12);
}

TEST(Rigid3d, ComposeAppliesRightThenLeft) {
  const Rigid3d a = SomeTransform();
  const Rigid3d b(Eigen::Quaterniond(Eigen::AngleAxisd(-1.1, Eigen::Vector3d::UnitY())),
                  Eigen::Vector3d(-2, 0.5, 1));
  const Eigen::Vector3d x(0.2, 0.4, -3);
  EXPECT_NEAR((a.Compose(b) * x - a * (b * x)).norm(), 0, 1e-12);
  EXPECT_GT((b.Compose(a) * x - a * (b * x)).norm(), 1e-3);  // order matters
}

TEST(Rigid3d, MatrixMatchesApply) {
  const Rigid3d a = SomeTransform();
  const Eigen::Vector3d x(1, 2, 3);
  EXPECT_NEAR((a.Matrix() * x.homogeneous() - a * x).norm(), 0, 1e-12);
}

TEST(LookAt, TargetOnOpticalAxisInFront) {
  const Eigen::Vector3d eye(1, 2, 3), target(-2, 0.5, 7), up(0, 0, 1);
  const Rigid3d cam_from_world = LookAt(eye, target, up);
  EXPECT_NEAR((cam_from_world * eye).norm(), 0, 1e-12);
  const Eigen::Vector3d target_in_cam = cam_from_world * target;
  EXPECT_NEAR(target_in_cam.x(), 0, 1e-12);
  EXPECT_NEAR(target_in_cam.y(), 0, 1e-12);
  EXPECT_NEAR(target_in_cam.z(), (target - eye).norm(), 1e-12);
  EXPECT_NEAR(cam_from_world.R().determinant(), 1, 1e-12);
}

TEST(LookAt, UpMapsToNegativeImageY) {
  // Camera on the -y axis looking at the origin with world z up.
  const Rigid3d cam_from_world = LookAt(Eigen::Vector3d(0, -5, 0), Eigen::Vector3d::Zero(),
                                        Eigen::Vector3d::UnitZ());
  const Eigen::Vector3d up_in_cam = cam_from_world.rotation * Eigen::Vector3d::UnitZ();
  EXPECT_NEAR(up_in_cam.y(), -1, 1e-12);
  // Right-handed: world +x (to the camera's right here) maps to image +x.
  const Eigen::Vector3d right_in_cam = cam_from_world.rotation * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(right_in_cam.x(), 1, 1e-12);
  // A point above the target projects above the principal point (y < 0).
  EXPECT_LT((cam_from_world * Eigen::Vector3d(0, 0, 1)).y(), 0);
}

TEST(LookAt, ParallelUpStaysFinite) {
  const Rigid3d cam_from_world = LookAt(Eigen::Vector3d(0, 0, 5), Eigen::Vector3d::Zero(),
                                        Eigen::Vector3d::UnitZ());
  EXPECT_TRUE(cam_from_world.R().allFinite());
  EXPECT_NEAR((cam_from_world * Eigen::Vector3d::Zero() - Eigen::Vector3d(0, 0, 5)).norm(), 0, 1e-12);
}

TEST(LookAt, SameEyeAndTargetThrows) {
  EXPECT_THROW(LookAt(Eigen::Vector3d::Ones(), Eigen::Vector3d::Ones(), Eigen::Vector3d::UnitZ()),
               InputError);
}

}  // namespace
}  // namespace ibmr
