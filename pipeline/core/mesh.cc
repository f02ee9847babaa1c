// Helpers on TriangleMesh: area-weighted vertex normals, bounds, and a consistency check that
// names the first problem (used after reading a PLY and before writing one).
#include "pipeline/core/mesh.h"

#include <Eigen/Geometry>
#include <cmath>

namespace ibmr {

void TriangleMesh::ComputeVertexNormals() {
  normals.assign(vertices.size(), Eigen::Vector3f::Zero());
  const int num_vertices = static_cast<int>(vertices.size());
  for (const Eigen::Vector3i& face : faces) {
    if ((face.array() < 0).any() || (face.array() >= num_vertices).any()) continue;
    // The unnormalised cross product has length 2 * area, so summing it weights by area.
    const Eigen::Vector3f weighted = (vertices[face[1]] - vertices[face[0]]).cross(vertices[face[2]] - vertices[face[0]]);
    for (int k = 0; k < 3; ++k) normals[face[k]] += weighted;
  }
  for (Eigen::Vector3f& n : normals) {
    const float length = n.norm();
    // Isolated vertices or those on degenerate faces only get a zero normal rather than NaN.
    n = length > 0.f ? Eigen::Vector3f(n / length) : Eigen::Vector3f::Zero();
  }
}

bool TriangleMesh::Bounds(Eigen::Vector3f* min, Eigen::Vector3f* max) const {
  if (vertices.empty()) return false;
  Eigen::Vector3f lo = vertices[0], hi = vertices[0];
  for (const Eigen::Vector3f& v : vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  *min = lo;
  *max = hi;
  return true;
}

size_t TriangleMesh::DropNonFiniteVertices() {
  // Attributes of another length are left as they are, for Validate to name.
  const bool with_normals = normals.size() == vertices.size(), with_colors = colors.size() == vertices.size();
  std::vector<int> renumbered(vertices.size(), -1);
  size_t kept = 0;
  for (size_t v = 0; v < vertices.size(); ++v) {
    if (!vertices[v].allFinite()) continue;
    renumbered[v] = static_cast<int>(kept);
    vertices[kept] = vertices[v];
    if (with_normals) normals[kept] = normals[v];
    if (with_colors) colors[kept] = colors[v];
    ++kept;
  }
  const size_t dropped = vertices.size() - kept;
  if (dropped == 0) return 0;
  if (with_normals) normals.resize(kept);
  if (with_colors) colors.resize(kept);
  vertices.resize(kept);
  size_t faces_kept = 0;
  for (const Eigen::Vector3i& face : faces) {
    Eigen::Vector3i mapped;
    bool usable = true;
    for (int k = 0; k < 3 && usable; ++k) {
      const int index = face[k];
      const bool in_range = index >= 0 && static_cast<size_t>(index) < renumbered.size();
      usable = !in_range || renumbered[index] >= 0;
      mapped[k] = in_range ? renumbered[index] : index;  // out of range stays so, for Validate to name
    }
    if (usable) faces[faces_kept++] = mapped;
  }
  faces.resize(faces_kept);
  return dropped;
}

std::string TriangleMesh::Validate() const {
  const size_t n = vertices.size();
  if (!normals.empty() && normals.size() != n) {
    return "mesh has " + std::to_string(normals.size()) + " normals for " + std::to_string(n) + " vertices";
  }
  if (!colors.empty() && colors.size() != n) {
    return "mesh has " + std::to_string(colors.size()) + " colours for " + std::to_string(n) + " vertices";
  }
  for (size_t v = 0; v < n; ++v) {
    if (!vertices[v].allFinite()) return "vertex " + std::to_string(v) + " has a non-finite coordinate";
  }
  for (size_t f = 0; f < faces.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int index = faces[f][k];
      if (index < 0 || static_cast<size_t>(index) >= n) {
        return "face " + std::to_string(f) + " refers to vertex " + std::to_string(index) + " but the mesh has " +
               std::to_string(n) + " vertices";
      }
    }
  }
  return "";
}

}  // namespace ibmr
