// Geometry of per-pixel depth maps shared by the dense stages: the viewing ray of every pixel and
// normals estimated from depth (seed 000 lines 4352-4398: a surface point per pixel, its tangent
// plane from its neighbours).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"

namespace ibmr {

// The undistorted ray (x, y, 1) of every pixel centre of a width x height map seen by `camera`,
// row-major; the map may have another resolution than the camera (the rays are scaled to it).
std::vector<Eigen::Vector3f> PixelRays(const Camera& camera, int width, int height);

// Unit camera-frame normals (3 channels) from a z-depth map by central differences of the
// back-projected points, oriented towards the camera; 0 where a 4-neighbour has no depth or the
// depth jumps by more than `max_relative_jump` (a silhouette, not a surface). Border pixels are 0.
FloatMap NormalsFromDepth(const Camera& camera, const DepthMap& depth, float max_relative_jump = 0.05f);

}  // namespace ibmr
