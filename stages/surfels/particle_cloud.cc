// Plain operations on point clouds as particle sets: selection, appending, spatial ordering,
// removal of non-finite points, projection into a view (see particle_cloud.h).
#include "stages/surfels/particle_cloud.h"

#include <algorithm>
#include <cmath>

namespace ibmr {

// Keeps the entries of `keep`; every per-point attribute follows.
PointCloud Select(const PointCloud& cloud, const std::vector<char>& keep) {
  PointCloud out;
  out.comments = cloud.comments;
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (!keep[i]) continue;
    out.positions.push_back(cloud.positions[i]);
    if (!cloud.normals.empty()) out.normals.push_back(cloud.normals[i]);
    if (!cloud.colors.empty()) out.colors.push_back(cloud.colors[i]);
    if (!cloud.confidence.empty()) out.confidence.push_back(cloud.confidence[i]);
    if (!cloud.radius.empty()) out.radius.push_back(cloud.radius[i]);
  }
  return out;
}

void Append(const PointCloud& more, PointCloud* cloud) {
  cloud->positions.insert(cloud->positions.end(), more.positions.begin(), more.positions.end());
  cloud->normals.insert(cloud->normals.end(), more.normals.begin(), more.normals.end());
  cloud->colors.insert(cloud->colors.end(), more.colors.begin(), more.colors.end());
  cloud->confidence.insert(cloud->confidence.end(), more.confidence.begin(), more.confidence.end());
}


// Reorders the points along a Morton (Z-order) curve of their positions, so that neighbours in
// space are neighbours in memory: the relaxation's neighbour lists then stay in cache.
void SortSpatially(PointCloud* cloud) {
  const size_t n = cloud->size();
  if (n < 2) return;
  Eigen::Vector3f lo = cloud->positions[0], hi = lo;
  for (const auto& p : cloud->positions) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
  const Eigen::Vector3f scale = (2097151.0f / (hi - lo).cwiseMax(Eigen::Vector3f::Constant(1e-20f)).array()).matrix();
  auto spread = [](uint64_t v) {  // 21 bits -> every third of 63 bits
    v &= 0x1FFFFF;
    v = (v | v << 32) & 0x1F00000000FFFFULL;
    v = (v | v << 16) & 0x1F0000FF0000FFULL;
    v = (v | v << 8) & 0x100F00F00F00F00FULL;
    v = (v | v << 4) & 0x10C30C30C30C30C3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
  };
  std::vector<std::pair<uint64_t, uint32_t>> keys(n);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3f q = (cloud->positions[i] - lo).cwiseProduct(scale);
    keys[i] = {spread(static_cast<uint64_t>(q.x())) | spread(static_cast<uint64_t>(q.y())) << 1 |
                   spread(static_cast<uint64_t>(q.z())) << 2,
               static_cast<uint32_t>(i)};
  }
  std::sort(keys.begin(), keys.end());
  auto permute = [&](auto& values) {
    if (values.empty()) return;
    auto copy = values;
    for (size_t i = 0; i < n; ++i) values[i] = copy[keys[i].second];
  };
  permute(cloud->positions);
  permute(cloud->normals);
  permute(cloud->colors);
  permute(cloud->confidence);
  permute(cloud->radius);
}

// Projects a world point into a view: pixel and depth; false when behind or outside the image.
bool ProjectToView(const SurfelView& view, const Eigen::Vector3f& point, Eigen::Vector2d* pixel, double* z) {
  const Eigen::Vector3d in_cam = view.cam_from_world * point.cast<double>();
  if (in_cam.z() <= 0) return false;
  *pixel = view.camera.ImgFromCam(in_cam);
  *z = in_cam.z();
  return pixel->x() >= 0 && pixel->y() >= 0 && pixel->x() < view.camera.width && pixel->y() < view.camera.height;
}

// Drops points with non-finite coordinates or normals; returns how many.
size_t DropNonFinite(PointCloud* cloud) {
  auto finite = [](const Eigen::Vector3f& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); };
  std::vector<char> keep(cloud->size(), 1);
  size_t dropped = 0;
  for (size_t i = 0; i < cloud->size(); ++i) {
    const bool ok = finite(cloud->positions[i]) && (cloud->normals.empty() || finite(cloud->normals[i])) &&
                    (cloud->confidence.empty() || std::isfinite(cloud->confidence[i]));
    keep[i] = ok;
    dropped += !ok;
  }
  if (dropped) *cloud = Select(*cloud, keep);
  return dropped;
}

// Removes the particles whose flag is set; returns how many.
size_t RemoveFlagged(const std::vector<char>& remove, PointCloud* particles) {
  std::vector<char> keep(remove.size());
  size_t removed = 0;
  for (size_t i = 0; i < remove.size(); ++i) {
    keep[i] = !remove[i];
    removed += remove[i] != 0;
  }
  if (removed) *particles = Select(*particles, keep);
  return removed;
}

}  // namespace ibmr
