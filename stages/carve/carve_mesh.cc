// The hull mesh: external faces of the octree's cells, smoothed (Lumigraph, seed 000 lines
// 14700-14740: "The external polygons are collected and the resulting polyhedron is then smoothed
// using Taubin's polyhedral smoothing algorithm"), in OpenMesh.
//
// Containment (mesh_dilation 1, the default): the faces are those of the hull dilated by one cell
// (26-neighbourhood), and every
// vertex stays within `max_displacement` < 1 cell of its start. A point of a smoothed triangle is
// the same convex combination of moved vertices as of the original ones, so it moved less than
// one cell; the undilated hull is at least one cell away from the dilated surface, so no
// intermediate surface crosses it and the mesh still encloses the conservative hull. With
// mesh_dilation 0 the faces are the hull's own and the mesh may cut into its boundary cells by up
// to max_displacement: a closer fit to the silhouettes, no longer a guaranteed superset.
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>
#include <algorithm>
#include <unordered_map>

#include "stages/carve/carve.h"

namespace ibmr {

namespace {

using OmMesh = OpenMesh::TriMesh_ArrayKernelT<>;

// 3x3x3 maximum filter (separable), in place, on an n^3 grid (x fastest).
void Dilate26(int n, std::vector<uint8_t>* grid) {
  const size_t stride[3] = {1, static_cast<size_t>(n), static_cast<size_t>(n) * n};
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<uint8_t> out(*grid);
    for (size_t index = 0; index < grid->size(); ++index) {
      if (!(*grid)[index]) continue;
      const int coordinate = static_cast<int>((index / stride[axis]) % n);
      if (coordinate > 0) out[index - stride[axis]] = 1;
      if (coordinate + 1 < n) out[index + stride[axis]] = 1;
    }
    grid->swap(out);
  }
}

}  // namespace

TriangleMesh HullMesh(const Octree& octree, int level, const CarveOptions& options, HullMeshStats* stats) {
  HullMeshStats local_stats;
  if (!stats) stats = &local_stats;
  *stats = HullMeshStats();
  level = std::min({level, octree.MaxLevel(), options.max_mesh_level});
  const int n = 1 << level;
  const int m = n + 2 * std::max(1, options.mesh_dilation);  // padded for the dilation
  const std::vector<uint8_t> hull = DenseHull(octree, level);
  const int pad = std::max(1, options.mesh_dilation);
  std::vector<uint8_t> grid(static_cast<size_t>(m) * m * m, 0);
  for (int z = 0; z < n; ++z) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        grid[((static_cast<size_t>(z) + pad) * m + y + pad) * m + x + pad] = hull[(static_cast<size_t>(z) * n + y) * n + x];
      }
    }
  }
  for (int k = 0; k < options.mesh_dilation; ++k) Dilate26(m, &grid);
  const double cell = octree.CellSize(level);
  const Eigen::Vector3d origin = octree.origin - Eigen::Vector3d::Constant(pad * cell);
  const auto occupied = [&](int x, int y, int z) {
    return x >= 0 && y >= 0 && z >= 0 && x < m && y < m && z < m && grid[(static_cast<size_t>(z) * m + y) * m + x];
  };

  // Refused faces are expected (handled below); keep OpenMesh from printing each one.
  omerr().disable();
  OmMesh mesh;
  std::unordered_map<uint64_t, OmMesh::VertexHandle> lattice;
  const auto vertex = [&](int x, int y, int z) -> OmMesh::VertexHandle {
    const uint64_t key = (static_cast<uint64_t>(z) * (m + 1) + y) * (m + 1) + x;
    auto it = lattice.find(key);
    if (it != lattice.end()) return it->second;
    const Eigen::Vector3d p = origin + cell * Eigen::Vector3d(x, y, z);
    const auto handle = mesh.add_vertex(OmMesh::Point(p.x(), p.y(), p.z()));
    lattice.emplace(key, handle);
    return handle;
  };
  // Adds a triangle; where the voxel surface is not manifold (cells touching along an edge or at
  // a corner) OpenMesh refuses it, and the triangle gets its own copies of the vertices.
  const auto add_triangle = [&](OmMesh::VertexHandle a, OmMesh::VertexHandle b, OmMesh::VertexHandle c) {
    if (mesh.add_face(a, b, c).is_valid()) return;
    const OmMesh::VertexHandle copies[3] = {mesh.add_vertex(mesh.point(a)), mesh.add_vertex(mesh.point(b)),
                                            mesh.add_vertex(mesh.point(c))};
    stats->duplicated_vertices += 3;
    mesh.add_face(copies[0], copies[1], copies[2]);
  };
  for (int z = 0; z < m; ++z) {
    for (int y = 0; y < m; ++y) {
      for (int x = 0; x < m; ++x) {
        if (!occupied(x, y, z)) continue;
        const int cell_index[3] = {x, y, z};
        for (int axis = 0; axis < 3; ++axis) {
          for (int sign = -1; sign <= 1; sign += 2) {
            int neighbour[3] = {x, y, z};
            neighbour[axis] += sign;
            if (occupied(neighbour[0], neighbour[1], neighbour[2])) continue;
            // Face corners in the (axis+1, axis+2) plane: counter-clockwise seen from outside.
            const int b = (axis + 1) % 3, c = (axis + 2) % 3;
            const int offsets[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
            OmMesh::VertexHandle corner[4];
            for (int k = 0; k < 4; ++k) {
              int p[3] = {cell_index[0], cell_index[1], cell_index[2]};
              p[axis] += sign > 0 ? 1 : 0;
              p[b] += offsets[sign > 0 ? k : 3 - k][0];
              p[c] += offsets[sign > 0 ? k : 3 - k][1];
              corner[k] = vertex(p[0], p[1], p[2]);
            }
            add_triangle(corner[0], corner[1], corner[2]);
            add_triangle(corner[0], corner[2], corner[3]);
            ++stats->boundary_quads;
          }
        }
      }
    }
  }

  // Taubin lambda|mu smoothing with uniform umbrella weights, displacement clamped.
  std::vector<OmMesh::Point> start(mesh.n_vertices()), next(mesh.n_vertices());
  for (auto v : mesh.vertices()) start[v.idx()] = mesh.point(v);
  const double limit = options.max_displacement * cell;
  for (int iteration = 0; iteration < options.smooth_iterations; ++iteration) {
    for (const double factor : {options.smooth_lambda, options.smooth_mu}) {
      for (auto v : mesh.vertices()) {
        OmMesh::Point sum(0, 0, 0);
        int count = 0;
        for (auto neighbour : mesh.vv_range(v)) {
          sum += mesh.point(neighbour);
          ++count;
        }
        OmMesh::Point p = mesh.point(v);
        if (count > 0) p += static_cast<float>(factor) * (sum / static_cast<float>(count) - p);
        OmMesh::Point offset = p - start[v.idx()];
        const double length = offset.norm();
        if (length > limit) offset *= static_cast<float>(limit / length);
        next[v.idx()] = start[v.idx()] + offset;
      }
      for (auto v : mesh.vertices()) mesh.set_point(v, next[v.idx()]);
    }
  }

  TriangleMesh result;
  result.vertices.reserve(mesh.n_vertices());
  for (auto v : mesh.vertices()) {
    const OmMesh::Point& p = mesh.point(v);
    result.vertices.emplace_back(p[0], p[1], p[2]);
    stats->max_displacement = std::max(stats->max_displacement, static_cast<double>((p - start[v.idx()]).norm()));
  }
  result.faces.reserve(mesh.n_faces());
  for (auto f : mesh.faces()) {
    Eigen::Vector3i face;
    int k = 0;
    for (auto v : mesh.fv_range(f)) face[k++] = v.idx();
    result.faces.push_back(face);
  }
  result.ComputeVertexNormals();
  result.comments = {options.mesh_dilation >= 1 ? "ibmr conservative_hull 1" : "ibmr conservative_hull 0",
                     "ibmr octree level " + std::to_string(level) + " cell " + std::to_string(cell) +
                         ", dilated " + std::to_string(options.mesh_dilation) + " cell, Taubin " + std::to_string(options.smooth_iterations) +
                         " iterations, displacement <= " + std::to_string(options.max_displacement) + " cell"};
  return result;
}

}  // namespace ibmr
