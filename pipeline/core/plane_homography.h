// Planes of a sweep in a reference camera, equally spaced in inverse depth (generalized disparity
// space, seed 000 lines 5314-5345: a virtual camera and its constant-d planes, d proportional to
// 1/z), and the homographies they induce into another camera. Shared by the stages that sweep
// planes through a reference: plane_sweep (depth per pixel of a training view) and volume (colour
// and opacity per cell of a virtual camera's planes).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

// `count` planes z = const in the reference camera, from `far` (plane 0) to `near` (plane count-1)
// by equal steps of 1/z, as the stereo sweep orders them (disparity grows with the index).
struct InverseDepthPlanes {
  double near = 1.0, far = 2.0;  // 0 < near < far, scene units
  int count = 2;                 // >= 2
  double MinInverse() const { return 1.0 / far; }
  double Step() const { return (1.0 / near - 1.0 / far) / (count - 1); }
  // 1/z of plane p (p may be fractional: a sub-plane position maps linearly to 1/z).
  double InverseDepth(double p) const { return MinInverse() + p * Step(); }
  double Depth(double p) const { return 1.0 / InverseDepth(p); }
  // The (fractional) plane index of depth z.
  double IndexOf(double z) const { return (1.0 / z - MinInverse()) / Step(); }
};

// The homography of each plane 1/z = inverse_depths[p] of the reference camera (the plane z = const
// in the reference's frame) from reference pixel coordinates to the other camera's (both with the
// pixel centre at +0.5): H_p = K_o (R + t n^T / z_p) K_r^-1 with n = (0, 0, 1), (R, t) = other from
// reference. Pinhole cameras (no distortion).
std::vector<Eigen::Matrix3d> PlaneHomographies(const Camera& reference, const Rigid3d& reference_from_world,
                                               const Camera& other, const Rigid3d& other_from_world,
                                               const std::vector<double>& inverse_depths);

}  // namespace ibmr
