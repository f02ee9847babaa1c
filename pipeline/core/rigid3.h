// Rigid transforms with the direction in the name, as in COLMAP: `cam_from_world` maps a point in
// world coordinates into the camera frame, x_cam = R * x_world + t. The camera centre in the world
// is -R^T t. COLMAP's images.txt stores exactly (qw, qx, qy, qz, tx, ty, tz) of cam_from_world.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace ibmr {

struct Rigid3d {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3d() = default;
  Rigid3d(const Eigen::Quaterniond& r, const Eigen::Vector3d& t) : rotation(r.normalized()), translation(t) {}
  Rigid3d(const Eigen::Matrix3d& r, const Eigen::Vector3d& t) : rotation(Eigen::Quaterniond(r).normalized()), translation(t) {}

  Eigen::Vector3d operator*(const Eigen::Vector3d& x) const { return rotation * x + translation; }
  Rigid3d Compose(const Rigid3d& other) const {  // (this * other)(x) = this(other(x))
    return Rigid3d(rotation * other.rotation, rotation * other.translation + translation);
  }
  Rigid3d Inverse() const {
    const Eigen::Quaterniond inv = rotation.conjugate();
    return Rigid3d(inv, -(inv * translation));
  }
  Eigen::Matrix3d R() const { return rotation.toRotationMatrix(); }
  // 3x4 matrix [R | t].
  Eigen::Matrix<double, 3, 4> Matrix() const {
    Eigen::Matrix<double, 3, 4> m;
    m.leftCols<3>() = R();
    m.col(3) = translation;
    return m;
  }
};

// Camera looking from `eye` towards `target` with image-up roughly along `up` (world), in the
// computer-vision frame: x right, y down, z forward.
Rigid3d LookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target, const Eigen::Vector3d& up);

}  // namespace ibmr
