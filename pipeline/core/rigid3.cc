// LookAt: builds cam_from_world for a camera at `eye` looking at `target`, in the computer-vision
// frame used throughout (x right, y down, z forward), as in COLMAP and OpenCV.
#include "pipeline/core/rigid3.h"

#include <cmath>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

// A unit vector not parallel to `forward`, used when `up` is (nearly) parallel to it, so that
// LookAt stays defined for a camera looking straight up or down.
Eigen::Vector3d FallbackUp(const Eigen::Vector3d& forward) {
  const Eigen::Vector3d axis = std::abs(forward.z()) < 0.9 ? Eigen::Vector3d::UnitZ()
                                                            : Eigen::Vector3d::UnitY();
  return axis;
}

}  // namespace

Rigid3d LookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target, const Eigen::Vector3d& up) {
  const Eigen::Vector3d view = target - eye;
  if (!(view.norm() > 0) || !view.allFinite()) {
    throw InputError("LookAt: eye and target must be distinct finite points");
  }
  const Eigen::Vector3d z = view.normalized();
  // x = z cross up points right when y (down) is opposite to up: x cross y = z.
  Eigen::Vector3d x = z.cross(up);
  if (!(x.norm() > 1e-9 * up.norm())) x = z.cross(FallbackUp(z));
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  Eigen::Matrix3d cam_from_world_rotation;
  cam_from_world_rotation.row(0) = x.transpose();
  cam_from_world_rotation.row(1) = y.transpose();
  cam_from_world_rotation.row(2) = z.transpose();
  return Rigid3d(cam_from_world_rotation, -(cam_from_world_rotation * eye));
}

}  // namespace ibmr
