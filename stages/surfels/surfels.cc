// The oriented particle system of seed 000 section 5 (lines 4454-4586): options, normals, spacing,
// initial particles, and the whole sequence of steps (see surfels.h). The relaxation is in
// particle_relaxation.cc, pruning and growth in particle_pruning.cc, the mesh in surfel_mesh.cc.
#include "stages/surfels/surfels.h"

#include <tbb/parallel_for.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "pipeline/core/errors.h"
#include "stages/surfels/particle_cloud.h"
#include "stages/surfels/particle_pruning.h"
#include "pipeline/core/point_index.h"

namespace ibmr {

namespace {

using Neighbours = std::vector<std::pair<uint32_t, float>>;
using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

std::string Range(const char* key, const std::string& range) { return std::string(key) + ": must be in " + range; }

// World radius of each surfel: 0.75 times the mean distance to its 6 nearest particles. A disc of
// radius s / sqrt(3) = 0.58 s covers a hexagonal arrangement of spacing s, but relaxed particles are
// not a lattice: oriented discs of 0.6 s left pinholes wherever the spacing is uneven (synthetic
// ring, splat_surfels held out: 0.6 -> 25.7 dB, SSIM 0.77; 0.75 -> 26.3 dB, SSIM 0.84).
constexpr double kRadiusFactor = 0.75;
std::vector<float> SurfelRadii(const std::vector<Eigen::Vector3f>& positions, double spacing) {
  std::vector<float> radii(positions.size(), static_cast<float>(kRadiusFactor * spacing));
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
      if (count) radii[i] = static_cast<float>(kRadiusFactor * std::min(sum / count, 2.0 * spacing));
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
  if (silhouette_views < 0 || silhouette_views > 1000) return fail(Range("silhouette_views", "[0, 1000]"));
  if (silhouette_color_tolerance < 0 || silhouette_color_tolerance > 255) {
    return fail(Range("silhouette_color_tolerance", "[0, 255]"));
  }
  if (!(max_edge >= 1 && max_edge <= 20)) return fail(Range("max_edge", "[1, 20]"));
  if (max_hole_edges < 0 || max_hole_edges > 1000) return fail(Range("max_hole_edges", "[0, 1000]"));
  if (min_component_faces < 0 || min_component_faces > 1000000) return fail(Range("min_component_faces", "[0, 1e6]"));
  if (!(border_extension >= 0 && border_extension <= 2)) return fail(Range("border_extension", "[0, 2]"));
  if (max_particles < 1000 || max_particles > 50000000) return fail(Range("max_particles", "[1000, 5e7]"));
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
        if (!ProjectToView(view, points->positions[i], &pixel, &z)) continue;
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
      if (!ProjectToView(view, points.positions[i], &pixel, &z)) continue;
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
  // Cells are keyed by their three 64-bit indices from the points' lower corner, so one stray point
  // far away (2 million spacings and more, which a packed 21-bit key refused) costs a cell, not the
  // run. The extent only has to fit 64 bits, which any float cloud at a sane spacing does.
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::max());
  Eigen::Vector3d hi = -lo;
  for (const auto& p : points.positions) lo = lo.cwiseMin(p.cast<double>()), hi = hi.cwiseMax(p.cast<double>());
  if (!points.positions.empty() && !(((hi - lo) / spacing).maxCoeff() < 1e15)) {
    throw InputError("surfels: the points span " + std::to_string((hi - lo).maxCoeff()) + " scene units, over 1e15 " +
                     "spacings of " + std::to_string(spacing) + "; raise surfels.spacing_scale or crop the points");
  }
  using CellKey = std::array<int64_t, 3>;
  struct CellHash {
    size_t operator()(const CellKey& k) const {
      const auto u = [](int64_t v) { return static_cast<uint64_t>(v); };  // wraps, as hashing wants
      return std::hash<uint64_t>()(u(k[0]) * 73856093u ^ u(k[1]) * 19349663u ^ u(k[2]) * 83492791u);
    }
  };
  std::unordered_map<CellKey, size_t, CellHash> cell_of;
  std::vector<Cell> cells;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d c = ((points.positions[i].cast<double>() - lo) / spacing).array().floor();
    const CellKey key = {static_cast<int64_t>(c.x()), static_cast<int64_t>(c.y()), static_cast<int64_t>(c.z())};
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
    if (options.silhouette_views > 0) {
      const std::vector<int> off = OffSilhouette(particles.positions, particles.colors, views, options.silhouette_color_tolerance);
      std::vector<char> outside(off.size());
      for (size_t i = 0; i < off.size(); ++i) outside[i] = off[i] >= options.silhouette_views;
      stats.removed_off_silhouette += RemoveFlagged(outside, &particles);
    }
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
  auto prune_unsupported = [&](bool check_data) {
    stats.removed_unsupported += RemoveFlagged(Unsupported(data_index, particles, check_data, spacing, options), &particles);
  };
  progress->Begin("surfels: relaxation rounds", static_cast<size_t>(options.grow_rounds) + 1);
  prune_free_space_and_hull();
  prune_unsupported(true);

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
    stats.grown += added.size();
    stats.mean_step_last_sweep = RelaxParticles(data, spacing, options.weights, options.iterations, &particles);
    progress->Advance(1, "grown " + std::to_string(added.size()));
  }
  progress->End();
  stats.relax_seconds = Seconds(relax_start);
  // Pruning again after growth: free space and hull, then isolated particles (data support was
  // checked before growth; grown particles have none by design).
  prune_free_space_and_hull();
  prune_unsupported(false);
  if (particles.size() < 3) throw InputError("surfels: every particle was removed (free space, hull or outliers)");

  // 6. Triangulation and the surfels' radii.
  particles.radius = SurfelRadii(particles.positions, spacing);
  stats.particles = particles.size();
  stats.spacing_spread = NearestNeighbourSpread(particles.positions);
  const Clock::time_point triangulate_start = Clock::now();
  result.mesh = TriangulateParticles(particles, options.max_edge * spacing);
  stats.small_component_faces = RemoveSmallComponents(options.min_component_faces, &result.mesh);
  stats.holes_filled = FillSmallHoles(options.max_hole_edges, &result.mesh);
  stats.border_edges_extended = ExtendBorders(static_cast<float>(options.border_extension * spacing), &result.mesh);
  stats.triangulate_seconds = Seconds(triangulate_start);
  stats.vertices = result.mesh.vertices.size();
  stats.faces = result.mesh.faces.size();
  result.surfels = std::move(particles);
  return result;
}

}  // namespace ibmr
