// Vertex clustering and even subsampling for the report's viewer (see viewer_geometry.h).
#include "pipeline/runner/viewer_geometry.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <unordered_map>
#include <unordered_set>

namespace ibmr {

namespace {

// A grid cell's key: the three cell indices, 21 bits each.
using CellKey = uint64_t;

struct Clustering {
  std::vector<int> cluster_of_vertex;            // one per vertex
  std::vector<Eigen::Vector3f> cluster_mean;     // one per cluster
  std::vector<Eigen::Vector3f> cluster_color;    // one per cluster (mean colour), when colours exist
};

Clustering ClusterVertices(const ViewerMesh& mesh, const Eigen::Vector3f& origin, float cell) {
  Clustering c;
  c.cluster_of_vertex.resize(mesh.vertices.size());
  std::unordered_map<CellKey, int> cluster_of_cell;
  std::vector<int> members;
  for (size_t v = 0; v < mesh.vertices.size(); ++v) {
    const Eigen::Vector3f index = ((mesh.vertices[v] - origin) / cell).array().floor();
    const auto bits = [](float i) { return static_cast<CellKey>(std::clamp(i, 0.f, 2097151.f)); };
    const CellKey key = bits(index.x()) | bits(index.y()) << 21 | bits(index.z()) << 42;
    const auto [it, added] = cluster_of_cell.emplace(key, static_cast<int>(c.cluster_mean.size()));
    if (added) {
      c.cluster_mean.emplace_back(Eigen::Vector3f::Zero());
      if (!mesh.colors.empty()) c.cluster_color.emplace_back(Eigen::Vector3f::Zero());
      members.push_back(0);
    }
    const int k = it->second;
    c.cluster_of_vertex[v] = k;
    c.cluster_mean[k] += mesh.vertices[v];
    if (!mesh.colors.empty()) c.cluster_color[k] += mesh.colors[v].cast<float>();
    ++members[k];
  }
  for (size_t k = 0; k < c.cluster_mean.size(); ++k) {
    c.cluster_mean[k] /= static_cast<float>(members[k]);
    if (!c.cluster_color.empty()) c.cluster_color[k] /= static_cast<float>(members[k]);
  }
  return c;
}

// The faces that keep three different clusters, each triple of clusters once (in face order).
std::vector<size_t> SurvivingFaces(const ViewerMesh& mesh, const Clustering& c) {
  struct TripleHash {
    size_t operator()(const std::array<int, 3>& k) const {
      return std::hash<uint64_t>()((static_cast<uint64_t>(k[0]) * 0x9E3779B97F4A7C15ull) ^
                                   (static_cast<uint64_t>(k[1]) * 0xC2B2AE3D27D4EB4Full) ^ static_cast<uint64_t>(k[2]));
    }
  };
  std::vector<size_t> kept;
  std::unordered_set<std::array<int, 3>, TripleHash> seen;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    std::array<int, 3> k = {c.cluster_of_vertex[mesh.faces[f][0]], c.cluster_of_vertex[mesh.faces[f][1]],
                            c.cluster_of_vertex[mesh.faces[f][2]]};
    if (k[0] == k[1] || k[1] == k[2] || k[0] == k[2]) continue;
    std::sort(k.begin(), k.end());
    if (seen.insert(k).second) kept.push_back(f);
  }
  return kept;
}

// The mesh made of the faces `kept`: vertices merged into their cluster, or, with UVs, each moved
// to its cluster's mean.
ViewerMesh Rebuild(const ViewerMesh& mesh, const Clustering& c, const std::vector<size_t>& kept) {
  const bool with_uvs = !mesh.uvs.empty();
  ViewerMesh out;
  std::unordered_map<int, int> new_index;  // old vertex (per corner) or cluster (shared) -> new vertex
  for (size_t f : kept) {
    Eigen::Vector3i face;
    for (int corner = 0; corner < 3; ++corner) {
      const int vertex = mesh.faces[f][corner];
      const int cluster = c.cluster_of_vertex[vertex];
      const auto [it, added] = new_index.emplace(with_uvs ? vertex : cluster, static_cast<int>(out.vertices.size()));
      if (added) {
        out.vertices.push_back(c.cluster_mean[cluster]);
        if (with_uvs) out.uvs.push_back(mesh.uvs[vertex]);
        if (!mesh.colors.empty()) {
          out.colors.push_back(with_uvs ? mesh.colors[vertex]
                                          : Color3u8(c.cluster_color[cluster].array().round().cast<uint8_t>()));
        }
      }
      face[corner] = it->second;
    }
    out.faces.push_back(face);
    if (!mesh.face_page.empty()) out.face_page.push_back(mesh.face_page[f]);
  }
  return out;
}

}  // namespace

ViewerMesh ClusterDecimate(const ViewerMesh& mesh, size_t max_faces) {
  if (mesh.faces.size() <= max_faces || mesh.vertices.empty()) return mesh;
  Eigen::Vector3f lo = mesh.vertices[0], hi = mesh.vertices[0];
  for (const Eigen::Vector3f& v : mesh.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  const float diagonal = std::max((hi - lo).norm(), 1e-12f);
  double area = 0;
  for (const Eigen::Vector3i& f : mesh.faces) {
    area += 0.5 * (mesh.vertices[f[1]] - mesh.vertices[f[0]]).cross(mesh.vertices[f[2]] - mesh.vertices[f[0]]).norm();
  }
  // A surface on a grid of cell c has about area / c^2 cells, and twice as many faces.
  float cell = static_cast<float>(std::sqrt(2.0 * area / static_cast<double>(max_faces)));
  cell = std::max({cell * 0.8f, diagonal / 2000000.f, diagonal / std::sqrt(static_cast<float>(max_faces)) * 0.01f});
  for (;; cell *= 1.15f) {
    const Clustering clustering = ClusterVertices(mesh, lo, cell);
    const std::vector<size_t> kept = SurvivingFaces(mesh, clustering);
    // A cell as large as the mesh leaves at most a handful of faces: the loop ends there.
    if (kept.size() <= max_faces || cell > 2 * diagonal) return Rebuild(mesh, clustering, kept);
  }
}

std::vector<size_t> EvenSubsample(size_t count, size_t max_points) {
  const size_t n = std::min(count, max_points);
  std::vector<size_t> indices(n);
  for (size_t k = 0; k < n; ++k) indices[k] = static_cast<size_t>(static_cast<unsigned __int128>(k) * count / n);
  return indices;
}

}  // namespace ibmr
