// Steps 1 and 2 of layers.h: sequential RANSAC of world planes on a depth map, and their robust
// refinement across views with Ceres (seed 000 lines 5705-5716: the planes of the layers).
#include <ceres/ceres.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>

#include "stages/layered_stereo/layers.h"

namespace ibmr {

namespace {

struct Sample {
  Eigen::Vector3d point;
  double depth;
};

std::vector<Sample> Samples(const LayerView& view, int step) {
  std::vector<Sample> samples;
  const Eigen::Matrix3d world_from_cam = view.cam_from_world.R().transpose();
  const Eigen::Vector3d centre = -(world_from_cam * view.cam_from_world.translation);
  for (int y = step / 2; y < view.depth.rows; y += step) {
    const float* row = view.depth.ptr<float>(y);
    for (int x = step / 2; x < view.depth.cols; x += step) {
      const double z = row[x];
      if (!(z > 0) || !std::isfinite(z)) continue;
      samples.push_back({centre + world_from_cam * (z * view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5))), z});
    }
  }
  return samples;
}

bool PlaneThrough(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c, WorldPlane* plane) {
  const Eigen::Vector3d n = (b - a).cross(c - a);
  const double norm = n.norm();
  if (!(norm > 1e-12 * (b - a).squaredNorm())) return false;
  plane->normal = n / norm;
  plane->offset = plane->normal.dot(a);
  return true;
}

// Least-squares plane through points (principal axis of least variance).
WorldPlane FitLeastSquares(const std::vector<Eigen::Vector3d>& points) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : points) scatter += (p - mean) * (p - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);
  WorldPlane plane;
  plane.normal = solver.eigenvectors().col(0).normalized();
  plane.offset = plane.normal.dot(mean);
  return plane;
}

bool OnPlane(const WorldPlane& plane, const Sample& s, double tolerance) {
  return std::abs(plane.normal.dot(s.point) - plane.offset) <= tolerance * s.depth;
}

// Point-to-plane distance divided by the sample's tolerance, for a plane (n, d) with n
// normalised inside (the parameters are 4 free numbers; the normalisation removes the gauge).
struct PlaneResidual {
  PlaneResidual(const Eigen::Vector3d& p, double scale) : point(p), inverse_scale(1.0 / scale) {}
  template <typename T>
  bool operator()(const T* const plane, T* residual) const {
    const T norm = ceres::sqrt(plane[0] * plane[0] + plane[1] * plane[1] + plane[2] * plane[2]);
    residual[0] = (plane[0] * T(point.x()) + plane[1] * T(point.y()) + plane[2] * T(point.z()) - plane[3]) / norm *
                  T(inverse_scale);
    return true;
  }
  Eigen::Vector3d point;
  double inverse_scale;
};

}  // namespace

std::vector<WorldPlane> FitPlanesRansac(const LayerView& reference, const LayeredOptions& options, unsigned seed) {
  std::vector<Sample> samples = Samples(reference, options.sample_step);
  const size_t total = samples.size();
  const size_t min_support = std::max<size_t>(3, static_cast<size_t>(options.min_layer_fraction * total));
  std::vector<WorldPlane> planes;
  std::mt19937 rng(seed);
  while (static_cast<int>(planes.size()) < options.max_layers && samples.size() >= min_support) {
    std::uniform_int_distribution<size_t> pick(0, samples.size() - 1);
    WorldPlane best;
    size_t best_support = 0;
    for (int iteration = 0; iteration < options.ransac_iterations; ++iteration) {
      // Three samples near each other (a local patch) propose planes that exist in the scene more
      // often than three samples from anywhere.
      const size_t i = pick(rng);
      size_t j = pick(rng), k = pick(rng);
      for (int tries = 0; tries < 8 && (samples[j].point - samples[i].point).norm() > 0.1 * samples[i].depth; ++tries) j = pick(rng);
      for (int tries = 0; tries < 8 && (samples[k].point - samples[i].point).norm() > 0.1 * samples[i].depth; ++tries) k = pick(rng);
      WorldPlane candidate;
      if (i == j || j == k || i == k || !PlaneThrough(samples[i].point, samples[j].point, samples[k].point, &candidate)) continue;
      size_t support = 0;
      for (size_t s = 0; s < samples.size(); s += 4) support += OnPlane(candidate, samples[s], options.plane_tolerance);
      if (support > best_support) {
        best_support = support;
        best = candidate;
      }
    }
    if (best_support == 0) break;
    // Refit to the inliers twice (the least-squares plane gathers a few more), then remove them.
    for (int round = 0; round < 2; ++round) {
      std::vector<Eigen::Vector3d> inliers;
      for (const Sample& s : samples) {
        if (OnPlane(best, s, options.plane_tolerance)) inliers.push_back(s.point);
      }
      if (inliers.size() < 3) break;
      best = FitLeastSquares(inliers);
    }
    std::vector<Sample> rest;
    size_t support = 0;
    for (const Sample& s : samples) {
      if (OnPlane(best, s, options.plane_tolerance)) {
        ++support;
      } else {
        rest.push_back(s);
      }
    }
    if (support < min_support) break;
    best.support = support;
    planes.push_back(best);
    samples.swap(rest);
  }
  return planes;
}

void RefinePlanes(const std::vector<const LayerView*>& views, const LayeredOptions& options, std::vector<WorldPlane>* planes) {
  if (views.empty()) return;
  std::vector<std::vector<Sample>> per_view;
  for (const LayerView* view : views) per_view.push_back(Samples(*view, options.sample_step * 2));
  for (WorldPlane& plane : *planes) {
    double parameters[4] = {plane.normal.x(), plane.normal.y(), plane.normal.z(), plane.offset};
    ceres::Problem problem;
    size_t residuals = 0;
    for (const auto& samples : per_view) {
      for (const Sample& s : samples) {
        // Samples within twice the tolerance take part; the Cauchy loss (scale 1 tolerance)
        // weighs down those that belong to something else.
        if (!OnPlane(plane, s, 2 * options.plane_tolerance)) continue;
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PlaneResidual, 1, 4>(
                                     new PlaneResidual(s.point, options.plane_tolerance * s.depth)),
                                 new ceres::CauchyLoss(1.0), parameters);
        ++residuals;
      }
    }
    if (residuals < 3) continue;
    ceres::Solver::Options solver;
    solver.max_num_iterations = 20;
    solver.linear_solver_type = ceres::DENSE_QR;
    solver.num_threads = 1;
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    const Eigen::Vector3d n(parameters[0], parameters[1], parameters[2]);
    if (!(n.norm() > 0) || !std::isfinite(parameters[3])) continue;
    plane.normal = n.normalized();
    plane.offset = parameters[3] / n.norm();
  }
}

}  // namespace ibmr
