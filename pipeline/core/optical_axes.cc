// The point nearest to a set of optical axes (see optical_axes.h).
#include "pipeline/core/optical_axes.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>

namespace ibmr {

bool PointNearestToAxes(const std::vector<Eigen::Vector3d>& centers, const std::vector<Eigen::Vector3d>& directions,
                        Eigen::Vector3d* point) {
  if (centers.size() < 2 || directions.size() != centers.size()) return false;
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < centers.size(); ++i) {
    const Eigen::Vector3d v = directions[i].normalized();
    const Eigen::Matrix3d projector = Eigen::Matrix3d::Identity() - v * v.transpose();
    a += projector;
    b += projector * centers[i];
  }
  const Eigen::Vector3d eigenvalues = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(a).eigenvalues();
  if (eigenvalues.minCoeff() < 1e-6 * std::max(1.0, eigenvalues.maxCoeff())) return false;
  const Eigen::Vector3d solution = a.ldlt().solve(b);
  if (!solution.allFinite()) return false;
  *point = solution;
  return true;
}

}  // namespace ibmr
