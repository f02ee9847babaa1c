// Relaxation of the oriented particle system (seed 000 section 5, lines 4454-4586): Jacobi
// sweeps of preconditioned gradient steps on the energy of surfel_potentials.h (see surfels.h,
// step 4, for why this scheme and not Ceres).
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <numeric>

#include "pipeline/core/point_index.h"
#include "stages/surfels/surfels.h"

namespace ibmr {

namespace {

// Reach of the terms, in sigmas: the pair potentials beyond 2.5 sigma are < 5% of their peak (and
// repulsion reaches its own radius); psi_D is 0.14 at 2 data sigmas.
constexpr double kPairReach = 2.5;
constexpr double kDataReach = 2.0;
constexpr int kDataNearest = 64;  // at most this many data points per particle (the nearest)

using Neighbours = std::vector<std::pair<uint32_t, float>>;

// Neighbour lists of every point within `radius` of `queries[i]` (the `nearest` closest of them
// when > 0), as one flat array (CSR).
struct NeighbourLists {
  std::vector<size_t> offsets;
  std::vector<uint32_t> indices;
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
      offsets.push_back(indices.size());
    }
  }
};

// The confidence the data term counts as 1: the median of the data points' (at least 0.05; 1
// without confidences). The term weighs points relative to the cloud's own scale, so a stereo
// confidence that is calibrated differently (the margin no longer clipped at 1, the geometric
// factors of multi_depth and fuse) shifts the weight among points but not the balance between the
// data and the particles' potentials that the weights were tuned for.
double DataConfidenceUnit(const PointCloud& data) {
  if (data.confidence.empty()) return 1.0;
  std::vector<float> c(data.confidence.begin(), data.confidence.end());
  std::nth_element(c.begin(), c.begin() + c.size() / 2, c.end());
  const float median = c[c.size() / 2];
  return std::isfinite(median) ? std::max(0.05, static_cast<double>(median)) : 1.0;
}

}  // namespace

double RelaxParticles(const PointCloud& data, double spacing, const ParticleWeights& weights, int sweeps,
                      PointCloud* particles) {
  const size_t n = particles->size();
  if (n == 0 || sweeps <= 0) return 0;
  // Candidate lists with a margin of one spacing, rebuilt when the particles have moved enough to
  // use it up: the particle lists when the largest displacement since their build exceeds half the
  // margin (two particles may approach each other by twice that), the data lists when it exceeds
  // the margin. Each term then checks the true distance, so nothing within reach is
  // missed.
  const double margin = 1.0 * spacing;
  const double max_step = 0.3 * spacing;
  // Each data point's weight in the data term, once per call rather than per particle and sweep.
  std::vector<double> data_weight(data.positions.size(), 1.0);
  if (!data.confidence.empty()) {
    const double confidence_unit = DataConfidenceUnit(data);
    for (size_t k = 0; k < data_weight.size(); ++k) data_weight[k] = std::max(0.0f, data.confidence[k]) / confidence_unit;
  }
  const PointIndex data_index(data.positions);
  NeighbourLists data_near, particle_near;
  std::vector<Eigen::Vector3f> data_anchor, particle_anchor;
  auto largest_move = [&](const std::vector<Eigen::Vector3f>& anchor) {
    double largest = 0;
    for (size_t i = 0; i < n; ++i) largest = std::max<double>(largest, (particles->positions[i] - anchor[i]).norm());
    return largest;
  };
  std::vector<Eigen::Vector3f> next_positions(n), next_normals(n);
  std::vector<double> steps(n, 0.0);
  // In spacings, from the weights (2.5 and 2 at the defaults), so that a wider sigma or repulsion
  // radius is not cut off at a fixed distance.
  const double pair_reach = std::max(kPairReach * weights.sigma, weights.repulsion_radius);
  const double data_reach = kDataReach * weights.data_sigma;
  const double data_radius2 = data_reach * data_reach * spacing * spacing;
  const double pair_radius2 = pair_reach * pair_reach * spacing * spacing;
  for (int sweep = 0; sweep < sweeps; ++sweep) {
    if (data_anchor.empty() || largest_move(data_anchor) > margin) {
      data_near.Build(data_index, particles->positions, static_cast<float>(data_reach * spacing + margin), kDataNearest);
      data_anchor = particles->positions;
    }
    if (particle_anchor.empty() || 2 * largest_move(particle_anchor) > margin) {
      const PointIndex index(particles->positions);
      particle_near.Build(index, particles->positions, static_cast<float>(pair_reach * spacing + margin));
      particle_anchor = particles->positions;
    }
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t i = range.begin(); i < range.end(); ++i) {
        const Eigen::Vector3d p = particles->positions[i].cast<double>();
        const Eigen::Vector3d normal = particles->normals[i].cast<double>();
        PairGradient gradient;
        Curvature curvature{1e-9, 1e-9};
        for (size_t e = particle_near.offsets[i]; e < particle_near.offsets[i + 1]; ++e) {
          const uint32_t j = particle_near.indices[e];
          if (j == i) continue;
          const Eigen::Vector3d q = particles->positions[j].cast<double>();
          if ((q - p).squaredNorm() > pair_radius2) continue;
          PairEnergy(p, normal, q, particles->normals[j].cast<double>(), spacing, weights, &gradient, &curvature);
        }
        for (size_t e = data_near.offsets[i]; e < data_near.offsets[i + 1]; ++e) {
          const uint32_t k = data_near.indices[e];
          const Eigen::Vector3d q = data.positions[k].cast<double>();
          if ((q - p).squaredNorm() > data_radius2) continue;
          const double c = data_weight[k];
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

}  // namespace ibmr
