// Plane-induced homographies of a sweep's planes (see plane_homography.h).
#include "pipeline/core/plane_homography.h"

namespace ibmr {

std::vector<Eigen::Matrix3d> PlaneHomographies(const Camera& reference, const Rigid3d& reference_from_world,
                                               const Camera& other, const Rigid3d& other_from_world,
                                               const std::vector<double>& inverse_depths) {
  const Eigen::Matrix3d k_ref_inv = reference.K().inverse();
  const Rigid3d other_from_ref = other_from_world.Compose(reference_from_world.Inverse());
  const Eigen::Matrix3d k = other.K();
  const Eigen::Matrix3d a = k * other_from_ref.R() * k_ref_inv;
  const Eigen::Vector3d b = k * other_from_ref.translation;
  const Eigen::RowVector3d c = k_ref_inv.row(2);  // n^T K^-1 with n = (0, 0, 1)
  std::vector<Eigen::Matrix3d> homographies;
  homographies.reserve(inverse_depths.size());
  for (const double w : inverse_depths) homographies.push_back(a + w * b * c);
  return homographies;
}

}  // namespace ibmr
