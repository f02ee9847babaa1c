// Pruning and growth of the particle system (seed 000 section 5, lines 4454-4586): particles that
// depth maps see through (free space), particles without data support or neighbours, and the
// stretching rule that adds particles between neighbours across small gaps.
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "stages/surfels/particle_cloud.h"
#include "pipeline/core/point_index.h"
#include "stages/surfels/surfels.h"

namespace ibmr {

namespace {

constexpr double kNeighbourRadius = 2.5;  // spacings, as in the relaxation

using Neighbours = std::vector<std::pair<uint32_t, float>>;

}  // namespace

// Particles with fewer than `min_support` data points within support_radius (nor fewer than
// `min_support_fraction` of the median particle's count: sparse clusters of fused points, floaters
// that few samples agreed on, weigh as much as the surface once thinned), or fewer than
// `min_neighbours` particles within kNeighbourRadius spacings. Data support only when `check_data`.
std::vector<char> Unsupported(const PointIndex& data_index, const PointCloud& particles, bool check_data,
                              double spacing, const SurfelOptions& options) {
  std::vector<char> remove(particles.size(), 0);
  std::vector<int> support(particles.size(), -1);
  const PointIndex particle_index(particles.positions);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, particles.size()), [&](const tbb::blocked_range<size_t>& range) {
    Neighbours found;
    for (size_t i = range.begin(); i < range.end(); ++i) {
      particle_index.Radius(particles.positions[i], static_cast<float>(kNeighbourRadius * spacing), &found);
      if (static_cast<int>(found.size()) - 1 < options.min_neighbours) {
        remove[i] = 1;
        continue;
      }
      if (!check_data || options.min_support == 0) continue;
      data_index.Radius(particles.positions[i], static_cast<float>(options.support_radius * spacing), &found);
      support[i] = static_cast<int>(found.size());
    }
  });
  std::vector<int> counted;
  for (const int count : support) {
    if (count >= 0) counted.push_back(count);
  }
  if (counted.empty()) return remove;
  std::nth_element(counted.begin(), counted.begin() + counted.size() / 2, counted.end());
  const double limit = std::max<double>(options.min_support, options.min_support_fraction * counted[counted.size() / 2]);
  for (size_t i = 0; i < support.size(); ++i) {
    if (support[i] >= 0 && support[i] < limit) remove[i] = 1;
  }
  return remove;
}

// The stretching rule: midpoints of agreeing neighbour pairs across small gaps.
PointCloud StretchCandidates(const PointCloud& particles, double spacing, const SurfelOptions& options) {
  const PointIndex index(particles.positions);
  const double cos_limit = std::cos(options.max_normal_angle_deg * M_PI / 180.0);
  const float free_radius = static_cast<float>(0.5 * options.stretch_distance * spacing * 0.85);
  std::vector<PointCloud> per_chunk(particles.size() / 4096 + 1);
  tbb::parallel_for(size_t{0}, per_chunk.size(), [&](size_t chunk) {
    Neighbours pairs, near;
    PointCloud& out = per_chunk[chunk];
    const size_t end = std::min(particles.size(), (chunk + 1) * 4096);
    for (size_t i = chunk * 4096; i < end; ++i) {
      index.Radius(particles.positions[i], static_cast<float>(options.max_gap * spacing), &pairs);
      for (const auto& [j, d2] : pairs) {
        if (j <= i) continue;
        const double d = std::sqrt(d2) / spacing;
        if (d <= options.stretch_distance) continue;
        if (particles.normals[i].dot(particles.normals[j]) < cos_limit) continue;
        const Eigen::Vector3f normal_sum = particles.normals[i] + particles.normals[j];
        if (normal_sum.norm() < 1e-3f) continue;  // opposite normals (max_normal_angle_deg 180): no plane
        const Eigen::Vector3f mid = 0.5f * (particles.positions[i] + particles.positions[j]);
        index.Radius(mid, free_radius, &near);
        if (!near.empty()) continue;
        out.positions.push_back(mid);
        out.normals.push_back(normal_sum.normalized());
        out.colors.push_back(((particles.colors[i].cast<int>() + particles.colors[j].cast<int>()) / 2).cast<uint8_t>());
        out.confidence.push_back(std::min(particles.confidence[i], particles.confidence[j]));
      }
    }
  });
  // Several pairs can share a gap: keep candidates greedily, none within free_radius of a kept one.
  PointCloud all;
  for (const PointCloud& chunk : per_chunk) {
    all.positions.insert(all.positions.end(), chunk.positions.begin(), chunk.positions.end());
    all.normals.insert(all.normals.end(), chunk.normals.begin(), chunk.normals.end());
    all.colors.insert(all.colors.end(), chunk.colors.begin(), chunk.colors.end());
    all.confidence.insert(all.confidence.end(), chunk.confidence.begin(), chunk.confidence.end());
  }
  std::vector<char> keep(all.size(), 0);
  if (!all.positions.empty()) {
    const PointIndex candidates(all.positions);
    Neighbours near;
    for (size_t i = 0; i < all.size(); ++i) {
      candidates.Radius(all.positions[i], free_radius, &near);
      bool blocked = false;
      for (const auto& entry : near) blocked = blocked || (entry.first < i && keep[entry.first]);
      keep[i] = !blocked;
    }
  }
  return Select(all, keep);
}

std::vector<int> FreeSpaceViolations(const std::vector<Eigen::Vector3f>& positions,
                                     const std::vector<SurfelView>& views, double spacing, double margin_spacings) {
  std::vector<int> violations(positions.size(), 0);
  tbb::parallel_for(size_t{0}, positions.size(), [&](size_t i) {
    for (const SurfelView& view : views) {
      if (view.depth.Empty()) continue;
      Eigen::Vector2d pixel;
      double z;
      if (!ProjectToView(view, positions[i], &pixel, &z)) continue;
      const int x = static_cast<int>(pixel.x() * view.depth.width / view.camera.width);
      const int y = static_cast<int>(pixel.y() * view.depth.height / view.camera.height);
      if (x < 0 || y < 0 || x >= view.depth.width || y >= view.depth.height) continue;
      // The nearest pixel and its 8 neighbours must all see farther: a particle on the surface next
      // to a silhouette, whose projection lands a pixel off onto the background, is not free space.
      const double limit = z + std::max(margin_spacings * spacing, 0.005 * z);
      bool through = true;
      for (int dy = -1; dy <= 1 && through; ++dy) {
        for (int dx = -1; dx <= 1 && through; ++dx) {
          const int u = std::clamp(x + dx, 0, view.depth.width - 1), v = std::clamp(y + dy, 0, view.depth.height - 1);
          const float seen = view.depth.At(u, v);
          through = IsValidDepth(seen) && seen > limit;
        }
      }
      violations[i] += through;
    }
  });
  return violations;
}

std::vector<int> OffSilhouette(const std::vector<Eigen::Vector3f>& positions, const std::vector<Color3u8>& colors,
                               const std::vector<SurfelView>& views, int color_tolerance) {
  const bool by_colour = color_tolerance > 0 && colors.size() == positions.size();
  std::vector<int> off(positions.size(), 0);
  tbb::parallel_for(size_t{0}, positions.size(), [&](size_t i) {
    for (const SurfelView& view : views) {
      if (view.mask.empty()) continue;
      Eigen::Vector2d pixel;
      double z;
      if (!ProjectToView(view, positions[i], &pixel, &z)) continue;
      const int x = std::min(static_cast<int>(pixel.x() * view.mask.cols / view.camera.width), view.mask.cols - 1);
      const int y = std::min(static_cast<int>(pixel.y() * view.mask.rows / view.camera.height), view.mask.rows - 1);
      if (view.mask.at<uint8_t>(y, x) != 0) continue;
      if (by_colour && !view.image.empty()) {
        const cv::Vec3b bgr = view.image.at<cv::Vec3b>(y * view.image.rows / view.mask.rows, x * view.image.cols / view.mask.cols);
        const Color3u8& rgb = colors[i];
        const int difference = std::max({std::abs(bgr[2] - rgb[0]), std::abs(bgr[1] - rgb[1]), std::abs(bgr[0] - rgb[2])});
        if (difference <= color_tolerance) continue;  // the photo shows the particle's colour there
      }
      ++off[i];
    }
  });
  return off;
}

}  // namespace ibmr
