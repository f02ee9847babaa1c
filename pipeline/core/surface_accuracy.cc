// Accuracy and completeness of a point set against a true mesh (Middlebury style; the measuring
// part of seed 000 section 6's call for ground truth). Point-to-mesh distance: uniform grid over
// the triangles and the exact point-triangle distance (Ericson, Real-Time Collision Detection 5.1.5).
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <unordered_map>

#include "pipeline/core/surface_accuracy.h"

#include "pipeline/core/rank_correlation.h"
#include "pipeline/core/sparsification.h"

namespace ibmr {

namespace {

Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                       const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + d1 / (d1 - d3) * ab;
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denom = 1 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

int64_t CellKey(int x, int y, int z) {
  return (static_cast<int64_t>(x & 0x1FFFFF) << 42) | (static_cast<int64_t>(y & 0x1FFFFF) << 21) | (z & 0x1FFFFF);
}

}  // namespace

struct MeshDistance::Grid {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Eigen::Vector3i> faces;
  Eigen::Vector3d origin;
  double cell = 1;
  std::unordered_map<int64_t, std::vector<int>> cells;
  Eigen::Vector3i Cell(const Eigen::Vector3d& p) const {
    return ((p - origin) / cell).array().floor().cast<int>();
  }
};

MeshDistance::MeshDistance(const TriangleMesh& mesh) : grid_(std::make_unique<Grid>()) {
  Grid& g = *grid_;
  for (const auto& v : mesh.vertices) g.vertices.push_back(v.cast<double>());
  g.faces = mesh.faces;
  double edge_sum = 0;
  for (const auto& f : g.faces) edge_sum += (g.vertices[f[1]] - g.vertices[f[0]]).norm();
  g.cell = g.faces.empty() ? 1.0 : std::max(2 * edge_sum / g.faces.size(), 1e-9);
  Eigen::Vector3f lo, hi;
  g.origin = mesh.Bounds(&lo, &hi) ? Eigen::Vector3d(lo.cast<double>()) : Eigen::Vector3d::Zero();
  for (int i = 0; i < static_cast<int>(g.faces.size()); ++i) {
    const auto& f = g.faces[i];
    Eigen::Vector3d a = g.vertices[f[0]].cwiseMin(g.vertices[f[1]]).cwiseMin(g.vertices[f[2]]);
    Eigen::Vector3d b = g.vertices[f[0]].cwiseMax(g.vertices[f[1]]).cwiseMax(g.vertices[f[2]]);
    const Eigen::Vector3i ca = g.Cell(a), cb = g.Cell(b);
    for (int x = ca.x(); x <= cb.x(); ++x)
      for (int y = ca.y(); y <= cb.y(); ++y)
        for (int z = ca.z(); z <= cb.z(); ++z) g.cells[CellKey(x, y, z)].push_back(i);
  }
}

MeshDistance::~MeshDistance() = default;

double MeshDistance::Distance(const Eigen::Vector3d& point, double max_distance) const {
  const Grid& g = *grid_;
  const Eigen::Vector3i c = g.Cell(point);
  const int max_ring = static_cast<int>(std::ceil(max_distance / g.cell)) + 1;
  double best = max_distance;
  for (int r = 0; r <= max_ring; ++r) {
    // Cells of the shell at Chebyshev distance r; any triangle there is at least (r - 1) cells away.
    if ((r - 1) * g.cell > best) break;
    for (int x = -r; x <= r; ++x) {
      for (int y = -r; y <= r; ++y) {
        for (int z = -r; z <= r; ++z) {
          if (std::max({std::abs(x), std::abs(y), std::abs(z)}) != r) continue;
          const auto it = g.cells.find(CellKey(c.x() + x, c.y() + y, c.z() + z));
          if (it == g.cells.end()) continue;
          for (const int f : it->second) {
            const auto& face = g.faces[f];
            const double d = (ClosestPointOnTriangle(point, g.vertices[face[0]], g.vertices[face[1]], g.vertices[face[2]]) - point).norm();
            best = std::min(best, d);
          }
        }
      }
    }
  }
  return best;
}

std::vector<Eigen::Vector3f> SampleSurface(const TriangleMesh& mesh, size_t count, uint32_t seed) {
  std::vector<double> cumulative;
  double total = 0;
  for (const auto& f : mesh.faces) {
    total += 0.5 * (mesh.vertices[f[1]] - mesh.vertices[f[0]]).cross(mesh.vertices[f[2]] - mesh.vertices[f[0]]).norm();
    cumulative.push_back(total);
  }
  std::vector<Eigen::Vector3f> samples;
  if (total <= 0) return samples;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(0, 1);
  samples.reserve(count);
  for (size_t i = 0; i < count; ++i) {
    const size_t f = std::lower_bound(cumulative.begin(), cumulative.end(), uniform(rng) * total) - cumulative.begin();
    const auto& face = mesh.faces[std::min(f, mesh.faces.size() - 1)];
    double a = uniform(rng), b = uniform(rng);
    if (a + b > 1) a = 1 - a, b = 1 - b;
    samples.push_back(mesh.vertices[face[0]] + static_cast<float>(a) * (mesh.vertices[face[1]] - mesh.vertices[face[0]]) +
                      static_cast<float>(b) * (mesh.vertices[face[2]] - mesh.vertices[face[0]]));
  }
  return samples;
}

void MarkVisible(const std::vector<Eigen::Vector3f>& samples, const Camera& camera, const Rigid3d& cam_from_world,
                 const DepthMap& true_depth, double relative_tolerance, std::vector<char>* visible) {
  visible->resize(samples.size(), 0);
  const double sx = static_cast<double>(true_depth.width) / camera.width, sy = static_cast<double>(true_depth.height) / camera.height;
  for (size_t i = 0; i < samples.size(); ++i) {
    const Eigen::Vector3d in_cam = cam_from_world * samples[i].cast<double>();
    if (in_cam.z() <= 0) continue;
    const Eigen::Vector2d p = camera.ImgFromCam(in_cam);
    const int x = static_cast<int>(std::floor(p.x() * sx)), y = static_cast<int>(std::floor(p.y() * sy));
    if (x < 0 || y < 0 || x >= true_depth.width || y >= true_depth.height) continue;
    const float d = true_depth.At(x, y);
    if (IsValidDepth(d) && std::abs(d - in_cam.z()) <= relative_tolerance * in_cam.z()) (*visible)[i] = 1;
  }
}

PointSetAccuracy EvaluatePointSet(const PointCloud& cloud, const TriangleMesh& mesh,
                                 const std::vector<Eigen::Vector3f>& surface_samples, double threshold,
                                 const std::vector<char>* visible) {
  PointSetAccuracy result;
  result.threshold = threshold;
  result.points = cloud.size();
  if (cloud.size() > 0 && !mesh.faces.empty()) {
    const MeshDistance distance(mesh);
    const double cap = 10 * threshold;  // farther points count as this far (bounds the grid search)
    std::vector<double> d(cloud.size());
    tbb::parallel_for(size_t(0), cloud.size(), [&](size_t i) { d[i] = distance.Distance(cloud.positions[i].cast<double>(), cap); });
    if (cloud.confidence.size() == cloud.size()) {
      const std::vector<double> confidence(cloud.confidence.begin(), cloud.confidence.end());
      result.confidence_error_spearman = SpearmanCorrelation(confidence, d);
      result.sparsification_auc_ratio = SparsificationAucRatio(confidence, d);
    }
    std::sort(d.begin(), d.end());
    result.accuracy_90 = d[std::min(d.size() - 1, static_cast<size_t>(0.9 * d.size()))];
    result.accuracy_median = d[d.size() / 2];
  }
  // Completeness: voxel hash of the fused points with cells of the threshold's size.
  std::unordered_map<int64_t, std::vector<int>> hash;
  auto cell_of = [&](const Eigen::Vector3f& p) { return Eigen::Vector3i((p / threshold).array().floor().cast<int>()); };
  for (int i = 0; i < static_cast<int>(cloud.size()); ++i) {
    const Eigen::Vector3i c = cell_of(cloud.positions[i]);
    hash[CellKey(c.x(), c.y(), c.z())].push_back(i);
  }
  size_t covered = 0, seen = 0, seen_covered = 0;
  for (size_t s = 0; s < surface_samples.size(); ++s) {
    const Eigen::Vector3i c = cell_of(surface_samples[s]);
    bool found = false;
    for (int x = -1; x <= 1 && !found; ++x)
      for (int y = -1; y <= 1 && !found; ++y)
        for (int z = -1; z <= 1 && !found; ++z) {
          const auto it = hash.find(CellKey(c.x() + x, c.y() + y, c.z() + z));
          if (it == hash.end()) continue;
          for (const int i : it->second) {
            if ((cloud.positions[i] - surface_samples[s]).norm() <= threshold) {
              found = true;
              break;
            }
          }
        }
    covered += found;
    if (visible && (*visible)[s]) ++seen, seen_covered += found;
  }
  result.completeness = surface_samples.empty() ? 0.0 : double(covered) / surface_samples.size();
  if (visible) result.completeness_visible = seen ? double(seen_covered) / seen : 0.0;
  return result;
}

PointSetAccuracy EvaluateMesh(const TriangleMesh& mesh, const TriangleMesh& truth, size_t samples) {
  Eigen::Vector3f lo, hi;
  PointSetAccuracy result;
  if (!truth.Bounds(&lo, &hi) || truth.faces.empty() || mesh.faces.empty()) return result;
  PointCloud on_mesh;
  on_mesh.positions = SampleSurface(mesh, samples, 7);
  if (on_mesh.positions.empty()) return result;
  return EvaluatePointSet(on_mesh, truth, SampleSurface(truth, samples), 0.01 * (hi - lo).norm());
}

SilhouetteHits ProjectOntoSilhouette(const PointCloud& cloud, const Camera& camera, const Rigid3d& cam_from_world,
                                     const cv::Mat& mask) {
  SilhouetteHits hits;
  if (mask.empty() || mask.type() != CV_8UC1) return hits;
  const double sx = static_cast<double>(mask.cols) / camera.width, sy = static_cast<double>(mask.rows) / camera.height;
  for (const Eigen::Vector3f& point : cloud.positions) {
    const Eigen::Vector3d in_cam = cam_from_world * point.cast<double>();
    if (in_cam.z() <= 0) continue;
    const Eigen::Vector2d pixel = camera.ImgFromCam(in_cam);
    const int x = static_cast<int>(std::floor(pixel.x() * sx)), y = static_cast<int>(std::floor(pixel.y() * sy));
    if (x < 0 || y < 0 || x >= mask.cols || y >= mask.rows) continue;
    ++hits.projected;
    hits.on_silhouette += mask.at<uint8_t>(y, x) != 0;
  }
  return hits;
}

}  // namespace ibmr
