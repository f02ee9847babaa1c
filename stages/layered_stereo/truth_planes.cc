// Layers against ground truth (truth_planes.h).
#include "stages/layered_stereo/truth_planes.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>

namespace ibmr {

std::vector<TruthPlane> VisibleTruthPlanes(const TriangleMesh& truth, const LayerView& view, double min_fraction,
                                           const cv::Mat& estimated_depth) {
  const bool has_estimate = estimated_depth.size() == view.depth.size() && estimated_depth.type() == CV_32F;
  Eigen::Vector3f lo, hi;
  if (!truth.Bounds(&lo, &hi)) return {};
  const double scale = (hi - lo).norm();
  // Group faces by their rounded plane; sum their areas.
  std::map<std::tuple<long, long, long, long>, std::pair<WorldPlane, double>> groups;
  for (const auto& f : truth.faces) {
    const Eigen::Vector3d a = truth.vertices[f[0]].cast<double>(), b = truth.vertices[f[1]].cast<double>(),
                          c = truth.vertices[f[2]].cast<double>();
    Eigen::Vector3d n = (b - a).cross(c - a);
    const double area = 0.5 * n.norm();
    if (!(area > 0)) continue;
    n.normalize();
    const double d = n.dot(a);
    const auto key = std::make_tuple(std::lround(n.x() * 1e3), std::lround(n.y() * 1e3), std::lround(n.z() * 1e3),
                                     std::lround(d / scale * 1e3));
    auto& [plane, total] = groups[key];
    if (total == 0) plane = {n, d, 0};
    total += area;
  }
  // The 64 largest groups: planes of walls and boxes, not the facets of curved objects.
  std::vector<std::pair<double, WorldPlane>> largest;
  for (const auto& [key, value] : groups) largest.emplace_back(value.second, value.first);
  std::sort(largest.begin(), largest.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  if (largest.size() > 64) largest.resize(64);
  std::vector<size_t> pixels(largest.size(), 0), estimated(largest.size(), 0);
  size_t with_depth = 0;
  const Eigen::Matrix3d world_from_cam = view.cam_from_world.R().transpose();
  const Eigen::Vector3d centre = -(world_from_cam * view.cam_from_world.translation);
  for (int y = 0; y < view.depth.rows; ++y) {
    for (int x = 0; x < view.depth.cols; ++x) {
      const double z = view.depth.at<float>(y, x);
      if (!(z > 0)) continue;
      ++with_depth;
      const Eigen::Vector3d p = centre + world_from_cam * (z * view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)));
      for (size_t k = 0; k < largest.size(); ++k) {
        if (std::abs(largest[k].second.normal.dot(p) - largest[k].second.offset) <= 1e-3 * z) {
          ++pixels[k];
          estimated[k] += has_estimate && estimated_depth.at<float>(y, x) > 0;
          break;
        }
      }
    }
  }
  std::vector<TruthPlane> visible;
  for (size_t k = 0; k < largest.size(); ++k) {
    const double fraction = with_depth ? static_cast<double>(pixels[k]) / with_depth : 0.0;
    // Without an estimated depth map the coverage is unknown (NaN), not 0.
    const double coverage = !has_estimate ? std::numeric_limits<double>::quiet_NaN()
                            : pixels[k]   ? static_cast<double>(estimated[k]) / pixels[k]
                                          : 0.0;
    if (fraction >= min_fraction) visible.push_back({largest[k].second, fraction, coverage});
  }
  std::sort(visible.begin(), visible.end(), [](const auto& a, const auto& b) { return a.pixel_fraction > b.pixel_fraction; });
  return visible;
}

PlaneError NearestTruthPlane(const WorldPlane& found, const std::vector<TruthPlane>& truth, const Eigen::Vector3d& camera_centre) {
  PlaneError best;
  double best_score = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < truth.size(); ++k) {
    Eigen::Vector3d n = found.normal;
    double d = found.offset;
    if (n.dot(truth[k].plane.normal) < 0) n = -n, d = -d;
    const double angle = std::acos(std::clamp(n.dot(truth[k].plane.normal), -1.0, 1.0)) * 180.0 / M_PI;
    const double distance = std::abs(truth[k].plane.normal.dot(camera_centre) - truth[k].plane.offset);
    const double offset = std::abs(d - truth[k].plane.offset) / std::max(distance, 1e-12);
    const double score = angle + 100 * offset;
    if (score < best_score) {
      best_score = score;
      best = {static_cast<int>(k), angle, offset};
    }
  }
  return best;
}

}  // namespace ibmr
