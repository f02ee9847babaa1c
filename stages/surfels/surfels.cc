// The oriented particle system of seed 000 section 5 (lines 4454-4586): spacing, initial particles,
// pruning, Jacobi relaxation of the potentials, the stretching rule (see surfels.h for the steps).
#include "stages/surfels/surfels.h"

#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <unordered_map>

#include "pipeline/core/errors.h"
#include "stages/surfels/point_index.h"

namespace ibmr {

namespace {

constexpr double kNeighbourRadius = 2.5;  // spacings: potentials beyond are < 5% (sigma 1)
constexpr double kDataRadius = 2.0;       // spacings: psi_D (sigma 1) is 0.14 there
constexpr int kDataNearest = 64;          // at most this many data points per particle (the nearest)

using Neighbours = std::vector<std::pair<uint32_t, float>>;
using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

bool Finite(const Eigen::Vector3f& v) { return std::isfinite(v.x()) && std::isfinite(v.y()) && std::isfinite(v.z()); }

std::string Range(const char* key, const std::string& range) { return std::string(key) + ": must be in " + range; }

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
bool Project(const SurfelView& view, const Eigen::Vector3f& point, Eigen::Vector2d* pixel, double* z) {
  const Eigen::Vector3d in_cam = view.cam_from_world * point.cast<double>();
  if (in_cam.z() <= 0) return false;
  *pixel = view.camera.ImgFromCam(in_cam);
  *z = in_cam.z();
  return pixel->x() >= 0 && pixel->y() >= 0 && pixel->x() < view.camera.width && pixel->y() < view.camera.height;
}

// Drops points with non-finite coordinates or normals; returns how many.
size_t DropNonFinite(PointCloud* cloud) {
  std::vector<char> keep(cloud->size(), 1);
  size_t dropped = 0;
  for (size_t i = 0; i < cloud->size(); ++i) {
    const bool ok = Finite(cloud->positions[i]) && (cloud->normals.empty() || Finite(cloud->normals[i]));
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

// Particles with fewer than `min_support` data points within support_radius (nor fewer than
// `min_support_fraction` of the median particle's count: sparse clusters of fused points, floaters
// that few samples agreed on, weigh as much as the surface once thinned), or fewer than
// `min_neighbours` particles within kNeighbourRadius spacings. Grown particles need no data.
std::vector<char> Unsupported(const PointIndex& data_index, const PointCloud& particles,
                              const std::vector<char>& grown, double spacing, const SurfelOptions& options) {
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
      if (grown[i] || options.min_support == 0) continue;
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
        const Eigen::Vector3f mid = 0.5f * (particles.positions[i] + particles.positions[j]);
        index.Radius(mid, free_radius, &near);
        if (!near.empty()) continue;
        out.positions.push_back(mid);
        out.normals.push_back((particles.normals[i] + particles.normals[j]).normalized());
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

void Append(const PointCloud& more, PointCloud* cloud) {
  cloud->positions.insert(cloud->positions.end(), more.positions.begin(), more.positions.end());
  cloud->normals.insert(cloud->normals.end(), more.normals.begin(), more.normals.end());
  cloud->colors.insert(cloud->colors.end(), more.colors.begin(), more.colors.end());
  cloud->confidence.insert(cloud->confidence.end(), more.confidence.begin(), more.confidence.end());
}

// World radius of each surfel: 0.6 times the mean distance to its 6 nearest particles (a disc of
// radius s / sqrt(3) covers a hexagonal arrangement of spacing s; 0.6 leaves a little overlap).
std::vector<float> SurfelRadii(const std::vector<Eigen::Vector3f>& positions, double spacing) {
  std::vector<float> radii(positions.size(), static_cast<float>(0.6 * spacing));
  if (positions.size() < 2) return radii;
  const PointIndex index(positions);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, positions.size()), [&](const tbb::blocked_range<size_t>& range) {
    Neighbours found;
    for (size_t i = range.begin(); i < range.end(); ++i) {
      index.Nearest(positions[i], 7, &found);
      double sum = 0;
      int count = 0;
      for (const auto& [j, d2] : found) {
        if (j == i) continue;
        sum += std::sqrt(d2);
        ++count;
      }
      if (count) radii[i] = static_cast<float>(0.6 * std::min(sum / count, 2.0 * spacing));
    }
  });
  return radii;
}

}  // namespace

bool SurfelOptions::Check(std::string* error) const {
  auto fail = [&](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (!(spacing_scale > 0 && spacing_scale <= 100)) return fail(Range("spacing_scale", "(0, 100]"));
  if (!(spacing > 0 || spacing == -1)) return fail("spacing: must be > 0 (scene units) or -1 (from footprints)");
  if (iterations < 0 || iterations > 1000) return fail(Range("iterations", "[0, 1000]"));
  if (grow_rounds < 0 || grow_rounds > 20) return fail(Range("grow_rounds", "[0, 20]"));
  const std::pair<const char*, double> nonnegative[] = {
      {"coplanarity", weights.coplanarity}, {"conormality", weights.conormality},
      {"cocircularity", weights.cocircularity}, {"repulsion", weights.repulsion}, {"data_weight", weights.data}};
  for (const auto& [key, value] : nonnegative) {
    if (!(value >= 0 && value <= 1e6)) return fail(Range(key, "[0, 1e6]"));
  }
  if (!(weights.sigma > 0 && weights.sigma <= 10)) return fail(Range("sigma", "(0, 10]"));
  if (!(weights.repulsion_radius > 0 && weights.repulsion_radius <= 5)) return fail(Range("repulsion_radius", "(0, 5]"));
  if (!(weights.data_sigma > 0 && weights.data_sigma <= 10)) return fail(Range("data_sigma", "(0, 10]"));
  if (!(weights.tangential >= 0 && weights.tangential <= 1)) return fail(Range("tangential", "[0, 1]"));
  if (!(max_gap > 1 && max_gap <= 20)) return fail(Range("max_gap", "(1, 20]"));
  if (!(stretch_distance >= 1 && stretch_distance < max_gap)) return fail(Range("stretch_distance", "[1, max_gap)"));
  if (!(max_normal_angle_deg > 0 && max_normal_angle_deg <= 180)) return fail(Range("max_normal_angle_deg", "(0, 180]"));
  if (min_support < 0 || min_support > 1000) return fail(Range("min_support", "[0, 1000]"));
  if (!(support_radius > 0 && support_radius <= 20)) return fail(Range("support_radius", "(0, 20]"));
  if (!(min_support_fraction >= 0 && min_support_fraction <= 1)) return fail(Range("min_support_fraction", "[0, 1]"));
  if (min_neighbours < 0 || min_neighbours > 100) return fail(Range("min_neighbours", "[0, 100]"));
  if (free_space_views < 1 || free_space_views > 1000) return fail(Range("free_space_views", "[1, 1000]"));
  if (!(free_space_margin > 0 && free_space_margin <= 1000)) return fail(Range("free_space_margin", "(0, 1000]"));
  if (!(max_edge >= 1 && max_edge <= 20)) return fail(Range("max_edge", "[1, 20]"));
  if (max_hole_edges < 0 || max_hole_edges > 1000) return fail(Range("max_hole_edges", "[0, 1000]"));
  if (max_particles < 1000 || max_particles > 1000000000) return fail(Range("max_particles", "[1000, 1e9]"));
  return true;
}

void EstimateNormals(const std::vector<SurfelView>& views, PointCloud* points) {
  const size_t n = points->size();
  points->normals.assign(n, Eigen::Vector3f::UnitZ());
  if (n < 3) return;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : points->positions) centroid += p.cast<double>();
  centroid /= static_cast<double>(n);
  const PointIndex index(points->positions);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& range) {
    Neighbours found;
    for (size_t i = range.begin(); i < range.end(); ++i) {
      index.Nearest(points->positions[i], 12, &found);
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const auto& entry : found) mean += points->positions[entry.first].cast<double>();
      mean /= static_cast<double>(found.size());
      Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
      for (const auto& entry : found) {
        const Eigen::Vector3d d = points->positions[entry.first].cast<double>() - mean;
        covariance += d * d.transpose();
      }
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
      Eigen::Vector3d normal = solver.eigenvectors().col(0);  // smallest eigenvalue first
      Eigen::Vector3d toward = points->positions[i].cast<double>() - centroid;  // away from the centroid
      for (const SurfelView& view : views) {
        Eigen::Vector2d pixel;
        double z;
        if (!Project(view, points->positions[i], &pixel, &z)) continue;
        toward = view.cam_from_world.Inverse().translation - points->positions[i].cast<double>();
        break;
      }
      if (normal.dot(toward) < 0) normal = -normal;
      (*points).normals[i] = normal.cast<float>();
    }
  });
}

double MedianFootprint(const PointCloud& points, const std::vector<SurfelView>& views) {
  std::vector<double> footprints(points.size(), 0.0);
  tbb::parallel_for(size_t{0}, points.size(), [&](size_t i) {
    double best = 0;
    for (const SurfelView& view : views) {
      Eigen::Vector2d pixel;
      double z;
      if (!Project(view, points.positions[i], &pixel, &z)) continue;
      const double footprint = z / (0.5 * (view.camera.FocalX() + view.camera.FocalY()));
      if (best == 0 || footprint < best) best = footprint;
    }
    footprints[i] = best;
  });
  footprints.erase(std::remove(footprints.begin(), footprints.end(), 0.0), footprints.end());
  if (footprints.empty()) return 0;
  std::nth_element(footprints.begin(), footprints.begin() + footprints.size() / 2, footprints.end());
  return footprints[footprints.size() / 2];
}

PointCloud ThinToSpacing(const PointCloud& points, double spacing) {
  struct Cell {
    Eigen::Vector3d position = Eigen::Vector3d::Zero(), normal = Eigen::Vector3d::Zero(), color = Eigen::Vector3d::Zero();
    double weight = 0, confidence = 0;
    int count = 0;
  };
  std::unordered_map<int64_t, size_t> cell_of;
  std::vector<Cell> cells;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3i c = (points.positions[i].cast<double>() / spacing).array().floor().cast<int>();
    const int64_t key = (static_cast<int64_t>(c.x() & 0x1FFFFF) << 42) | (static_cast<int64_t>(c.y() & 0x1FFFFF) << 21) |
                        (c.z() & 0x1FFFFF);
    const auto [it, inserted] = cell_of.emplace(key, cells.size());
    if (inserted) cells.emplace_back();
    Cell& cell = cells[it->second];
    const double confidence = points.confidence.empty() ? 1.0 : std::max(0.0f, points.confidence[i]);
    const double w = std::max(confidence, 1e-3);
    cell.position += w * points.positions[i].cast<double>();
    if (!points.normals.empty()) cell.normal += w * points.normals[i].cast<double>();
    if (!points.colors.empty()) cell.color += w * points.colors[i].cast<double>();
    cell.weight += w;
    cell.confidence += confidence;
    ++cell.count;
  }
  PointCloud out;
  for (const Cell& cell : cells) {
    const Eigen::Vector3d normal = cell.normal.norm() > 1e-9 ? cell.normal.normalized() : Eigen::Vector3d::UnitZ();
    out.positions.push_back((cell.position / cell.weight).cast<float>());
    out.normals.push_back(normal.cast<float>());
    const Eigen::Vector3d color = points.colors.empty() ? Eigen::Vector3d(128, 128, 128) : Eigen::Vector3d(cell.color / cell.weight);
    out.colors.push_back(color.array().round().min(255).max(0).cast<uint8_t>().matrix());
    out.confidence.push_back(static_cast<float>(cell.confidence / cell.count));
  }
  return out;
}

namespace {

// Neighbour lists of every point within `radius` of `queries[i]` (the `nearest` closest of them
// when > 0), as one flat array (CSR).
struct NeighbourLists {
  std::vector<uint32_t> offsets, indices;
  void Build(const PointIndex& index, const std::vector<Eigen::Vector3f>& queries, float radius, int nearest = 0) {
    std::vector<std::vector<uint32_t>> lists(queries.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, queries.size()), [&](const tbb::blocked_range<size_t>& range) {
      Neighbours found;
      for (size_t i = range.begin(); i < range.end(); ++i) {
        if (nearest > 0) {
          index.Nearest(queries[i], nearest, &found);
        } else {
          index.Radius(queries[i], radius, &found);
        }
        lists[i].reserve(found.size());
        for (const auto& entry : found) {
          if (entry.second <= radius * radius) lists[i].push_back(entry.first);
        }
      }
    });
    offsets.assign(1, 0);
    indices.clear();
    for (const auto& list : lists) {
      indices.insert(indices.end(), list.begin(), list.end());
      offsets.push_back(static_cast<uint32_t>(indices.size()));
    }
  }
};

}  // namespace

double RelaxParticles(const PointCloud& data, double spacing, const ParticleWeights& weights, int sweeps,
                      PointCloud* particles) {
  const size_t n = particles->size();
  if (n == 0 || sweeps <= 0) return 0;
  // Candidate lists with a margin of half a spacing: data neighbours are gathered once per call,
  // particle neighbours every kListSweeps sweeps (steps are capped at max_step, and typical steps are
  // a few hundredths of a spacing); each term then checks the true distance.
  constexpr int kListSweeps = 5;
  const double max_step = 0.3 * spacing;
  const PointIndex data_index(data.positions);
  NeighbourLists data_near, particle_near;
  data_near.Build(data_index, particles->positions, static_cast<float>((kDataRadius + 0.5) * spacing), kDataNearest);
  std::vector<Eigen::Vector3f> next_positions(n), next_normals(n);
  std::vector<double> steps(n, 0.0);
  const double data_radius2 = kDataRadius * kDataRadius * spacing * spacing;
  const double pair_radius2 = kNeighbourRadius * kNeighbourRadius * spacing * spacing;
  for (int sweep = 0; sweep < sweeps; ++sweep) {
    if (sweep % kListSweeps == 0) {
      const PointIndex index(particles->positions);
      particle_near.Build(index, particles->positions, static_cast<float>((kNeighbourRadius + 0.5) * spacing));
    }
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t i = range.begin(); i < range.end(); ++i) {
        const Eigen::Vector3d p = particles->positions[i].cast<double>();
        const Eigen::Vector3d normal = particles->normals[i].cast<double>();
        PairGradient gradient;
        Curvature curvature{1e-9, 1e-9};
        for (uint32_t e = particle_near.offsets[i]; e < particle_near.offsets[i + 1]; ++e) {
          const uint32_t j = particle_near.indices[e];
          if (j == i) continue;
          const Eigen::Vector3d q = particles->positions[j].cast<double>();
          if ((q - p).squaredNorm() > pair_radius2) continue;
          PairEnergy(p, normal, q, particles->normals[j].cast<double>(), spacing, weights, &gradient, &curvature);
        }
        for (uint32_t e = data_near.offsets[i]; e < data_near.offsets[i + 1]; ++e) {
          const uint32_t k = data_near.indices[e];
          const Eigen::Vector3d q = data.positions[k].cast<double>();
          if ((q - p).squaredNorm() > data_radius2) continue;
          const double c = data.confidence.empty() ? 1.0 : std::max(0.0f, data.confidence[k]);
          DataEnergy(p, normal, q, c, spacing, weights, &gradient.p_i, &gradient.n_i, &curvature);
        }
        Eigen::Vector3d step = -gradient.p_i * spacing * spacing / curvature.position;
        if (step.norm() > max_step) step *= max_step / step.norm();
        Eigen::Vector3d turn = -(gradient.n_i - gradient.n_i.dot(normal) * normal) / curvature.normal;
        if (turn.norm() > 0.3) turn *= 0.3 / turn.norm();
        next_positions[i] = (p + step).cast<float>();
        next_normals[i] = (normal + turn).normalized().cast<float>();
        steps[i] = step.norm() / spacing;
      }
    });
    particles->positions.swap(next_positions);
    particles->normals.swap(next_normals);
  }
  return std::accumulate(steps.begin(), steps.end(), 0.0) / static_cast<double>(n);
}

std::vector<int> FreeSpaceViolations(const std::vector<Eigen::Vector3f>& positions,
                                     const std::vector<SurfelView>& views, double spacing, double margin_spacings) {
  std::vector<int> violations(positions.size(), 0);
  tbb::parallel_for(size_t{0}, positions.size(), [&](size_t i) {
    for (const SurfelView& view : views) {
      if (view.depth.Empty()) continue;
      Eigen::Vector2d pixel;
      double z;
      if (!Project(view, positions[i], &pixel, &z)) continue;
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

double NearestNeighbourSpread(const std::vector<Eigen::Vector3f>& positions) {
  if (positions.size() < 2) return 0;
  const PointIndex index(positions);
  std::vector<double> nearest(positions.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, positions.size()), [&](const tbb::blocked_range<size_t>& range) {
    Neighbours found;
    for (size_t i = range.begin(); i < range.end(); ++i) {
      index.Nearest(positions[i], 2, &found);
      nearest[i] = found.size() > 1 ? std::sqrt(found[1].second) : 0.0;
    }
  });
  const double mean = std::accumulate(nearest.begin(), nearest.end(), 0.0) / nearest.size();
  double variance = 0;
  for (const double d : nearest) variance += (d - mean) * (d - mean);
  variance /= nearest.size();
  return mean > 0 ? std::sqrt(variance) / mean : 0.0;
}

SurfelResult ReconstructSurfels(const PointCloud& input, const std::vector<SurfelView>& views, const TriangleMesh* hull,
                                const SurfelOptions& options, ProgressReporter* progress) {
  NullProgress null_progress;
  if (!progress) progress = &null_progress;
  SurfelResult result;
  SurfelStats& stats = result.stats;
  stats.input_points = input.size();
  PointCloud data = input;
  stats.dropped_nonfinite = DropNonFinite(&data);
  SortSpatially(&data);
  if (data.size() < 3) {
    throw InputError("surfels: " + std::to_string(data.size()) + " usable points (of " + std::to_string(input.size()) +
                     "); fuse needs to produce points first");
  }
  if (data.normals.empty()) {
    stats.estimated_normals = true;
    EstimateNormals(views, &data);
  }
  for (auto& normal : data.normals) normal = normal.norm() > 1e-12f ? normal.normalized() : Eigen::Vector3f::UnitZ();

  // 1. Spacing.
  stats.median_footprint = MedianFootprint(data, views);
  double spacing = options.spacing;
  if (spacing <= 0) {
    if (stats.median_footprint <= 0) {
      throw InputError("surfels: no training view sees the points, so no pixel footprint; set surfels.spacing");
    }
    spacing = options.spacing_scale * stats.median_footprint;
  }
  stats.spacing = spacing;

  // 2. Particles.
  PointCloud particles = ThinToSpacing(data, spacing);
  stats.initial_particles = particles.size();
  if (particles.size() > static_cast<size_t>(options.max_particles)) {
    throw InputError("surfels: the spacing " + std::to_string(spacing) + " makes " + std::to_string(particles.size()) +
                     " particles, more than max_particles (" + std::to_string(options.max_particles) +
                     "); raise surfels.spacing_scale or max_particles");
  }

  // 3. Pruning before relaxation, so that floaters do not pull on the surface.
  auto prune_free_space_and_hull = [&]() {
    const Clock::time_point start = Clock::now();
    // Support (views that saw a surface at the particle's depth) is not weighed against the
    // violations: on templeRing that kept floaters along the silhouettes and cost 0.5 dB held out.
    const std::vector<int> violations =
        FreeSpaceViolations(particles.positions, views, spacing, options.free_space_margin);
    std::vector<char> remove(particles.size(), 0);
    for (size_t i = 0; i < remove.size(); ++i) remove[i] = violations[i] >= options.free_space_views;
    stats.removed_free_space += RemoveFlagged(remove, &particles);
    if (hull) {
      bool closed = true;
      const std::vector<char> inside = InsideClosedMesh(*hull, particles.positions, &closed);
      stats.hull_closed = closed;
      std::vector<char> outside(inside.size());
      for (size_t i = 0; i < inside.size(); ++i) outside[i] = !inside[i];
      stats.removed_outside_hull += RemoveFlagged(outside, &particles);
    }
    stats.prune_seconds += Seconds(start);
  };
  const PointIndex data_index(data.positions);
  std::vector<char> grown(particles.size(), 0);
  auto prune_unsupported = [&]() {
    const std::vector<char> remove = Unsupported(data_index, particles, grown, spacing, options);
    std::vector<char> keep_grown;
    for (size_t i = 0; i < remove.size(); ++i) {
      if (!remove[i]) keep_grown.push_back(grown[i]);
    }
    stats.removed_unsupported += RemoveFlagged(remove, &particles);
    grown.swap(keep_grown);
  };
  progress->Begin("surfels: relaxation rounds", static_cast<size_t>(options.grow_rounds) + 1);
  prune_free_space_and_hull();
  grown.assign(particles.size(), 0);
  prune_unsupported();

  // 4-5. Relaxation, then rounds of growth and relaxation.
  const Clock::time_point relax_start = Clock::now();
  stats.mean_step_last_sweep = RelaxParticles(data, spacing, options.weights, options.iterations, &particles);
  progress->Advance(1, "relaxed");
  for (int round = 0; round < options.grow_rounds; ++round) {
    const PointCloud added = StretchCandidates(particles, spacing, options);
    if (added.size() == 0) {
      progress->Advance(1, "no gap to fill");
      continue;
    }
    Append(added, &particles);
    grown.resize(particles.size(), 1);
    stats.grown += added.size();
    stats.mean_step_last_sweep = RelaxParticles(data, spacing, options.weights, options.iterations, &particles);
    progress->Advance(1, "grown " + std::to_string(added.size()));
  }
  progress->End();
  stats.relax_seconds = Seconds(relax_start);
  // Pruning again after growth: free space and hull, then isolated particles (data support was
  // checked before growth; grown particles have none by design).
  prune_free_space_and_hull();
  grown.assign(particles.size(), 1);
  prune_unsupported();
  if (particles.size() < 3) throw InputError("surfels: every particle was removed (free space, hull or outliers)");

  // 6. Triangulation and the surfels' radii.
  particles.radius = SurfelRadii(particles.positions, spacing);
  stats.particles = particles.size();
  stats.spacing_spread = NearestNeighbourSpread(particles.positions);
  const Clock::time_point triangulate_start = Clock::now();
  result.mesh = TriangulateParticles(particles, options.max_edge * spacing);
  stats.holes_filled = FillSmallHoles(options.max_hole_edges, &result.mesh);
  stats.triangulate_seconds = Seconds(triangulate_start);
  stats.vertices = result.mesh.vertices.size();
  stats.faces = result.mesh.faces.size();
  result.surfels = std::move(particles);
  return result;
}

}  // namespace ibmr
