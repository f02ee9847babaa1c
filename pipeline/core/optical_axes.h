// The point nearest to a set of optical axes: where a ring or arc of cameras looks. Used as the
// scene centre when no sparse points exist (unstructured lumigraph plane proxy, seed 001 [U 218],
// and the angle of a held-out view to its nearest training camera in scoring).
#pragma once

#include <Eigen/Core>
#include <vector>

namespace ibmr {

// Least-squares point nearest to all axes (centre c_i, direction v_i, normalised here): solves
// sum (I - v v^T) x = sum (I - v v^T) c. Returns false with fewer than two axes or when the axes
// are (nearly) parallel, leaving `point` untouched.
bool PointNearestToAxes(const std::vector<Eigen::Vector3d>& centers, const std::vector<Eigen::Vector3d>& directions,
                        Eigen::Vector3d* point);

}  // namespace ibmr
