// The CGAL side of the surfels stage (kept apart: a CGAL unit is slow to compile).
// Triangulation of the particle system (seed 000 section 5, lines 4454-4586: "an efficient
// triangulation scheme which connects the particles into a continuous global surface model"):
// CGAL's advancing-front surface reconstruction (Cohen-Steiner & Da, 2004) picks, among the
// Delaunay facets of the particles, a manifold surface grown from its most plausible facets; its
// priority is the smallest radius of the facet's Delaunay spheres, and a facet with an edge longer
// than the bound is never taken, so the mesh does not span holes wider than that. Faces are then
// turned to agree with the particles' normals.
// Inside test of a closed hull: parity of ray crossings through a CGAL AABB tree of its triangles.
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Advancing_front_surface_reconstruction.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <tbb/parallel_for.h>

#include <algorithm>

#include <array>
#include <cmath>
#include <map>

#include "stages/surfels/surfels.h"

namespace ibmr {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;

// Facets with an edge longer than `bound` get the infinite priority (never used).
struct EdgeBound {
  double bound_squared;
  template <typename AdvancingFront, typename CellHandle>
  double operator()(const AdvancingFront& front, CellHandle& cell, const int& index) const {
    for (int k = 1; k <= 3; ++k) {
      const Point& a = cell->vertex((index + k) % 4)->point();
      const Point& b = cell->vertex((index + k % 3 + 1) % 4)->point();
      if (CGAL::squared_distance(a, b) > bound_squared) return front.infinity();
    }
    return front.smallest_radius_delaunay_sphere(cell, index);
  }
};

// The advancing front orients each connected piece consistently; whether a piece faces out is
// decided by the majority of its faces against the particles' normals, and the whole piece
// turned if needed (turning faces one by one would break the consistency where normals are noisy).
void OrientPieces(const PointCloud& particles, TriangleMesh* mesh_pointer) {
  TriangleMesh& mesh = *mesh_pointer;
  const std::vector<int> piece = ConnectedPieces(mesh);
  std::vector<double> votes(mesh.vertices.size(), 0.0);
  for (size_t i = 0; i < mesh.faces.size(); ++i) {
    const Eigen::Vector3i& face = mesh.faces[i];
    const Eigen::Vector3f& a = mesh.vertices[face[0]];
    const Eigen::Vector3f normal = (mesh.vertices[face[1]] - a).cross(mesh.vertices[face[2]] - a);
    const Eigen::Vector3f vertex_normals = particles.normals[face[0]] + particles.normals[face[1]] + particles.normals[face[2]];
    votes[piece[i]] += normal.dot(vertex_normals) >= 0 ? 1.0 : -1.0;
  }
  for (size_t i = 0; i < mesh.faces.size(); ++i) {
    if (votes[piece[i]] < 0) std::swap(mesh.faces[i][1], mesh.faces[i][2]);
  }
}

}  // namespace

TriangleMesh TriangulateParticles(const PointCloud& particles, double max_edge_length) {
  TriangleMesh mesh;
  mesh.vertices = particles.positions;
  mesh.normals = particles.normals;
  mesh.colors = particles.colors;
  if (particles.size() < 3) return mesh;
  std::vector<Point> points;
  points.reserve(particles.size());
  for (const auto& p : particles.positions) points.emplace_back(p.x(), p.y(), p.z());
  std::vector<std::array<std::size_t, 3>> facets;
  CGAL::advancing_front_surface_reconstruction(points.begin(), points.end(), std::back_inserter(facets),
                                               EdgeBound{max_edge_length * max_edge_length});
  mesh.faces.reserve(facets.size());
  for (const auto& f : facets) mesh.faces.emplace_back(static_cast<int>(f[0]), static_cast<int>(f[1]), static_cast<int>(f[2]));
  if (!particles.normals.empty()) OrientPieces(particles, &mesh);
  // CGAL emits the facets in an order (and each piece in an orientation) that depends on where its
  // cells landed in memory, so two runs on the same particles differ. A canonical order, after the
  // orientation is settled (each face rotated to start at its smallest index, then sorted), makes
  // the mesh, and all that follows, reproducible.
  for (Eigen::Vector3i& f : mesh.faces) {
    while (f[0] > f[1] || f[0] > f[2]) f = Eigen::Vector3i(f[1], f[2], f[0]);
  }
  std::sort(mesh.faces.begin(), mesh.faces.end(), [](const Eigen::Vector3i& a, const Eigen::Vector3i& b) {
    return std::lexicographical_compare(a.data(), a.data() + 3, b.data(), b.data() + 3);
  });
  return mesh;
}

std::vector<char> InsideClosedMesh(const TriangleMesh& mesh, const std::vector<Eigen::Vector3f>& points, bool* closed) {
  std::vector<char> inside(points.size(), 1);
  // Closed: every edge has an even number of faces (a carved hull may meet itself along an edge,
  // which a halfedge structure refuses, but ray parity still holds for it). A few open edges (at
  // most 0.5%: a carved hull can have small slits) are tolerated: a ray rarely passes through them,
  // and the majority of three rays below outvotes the one that does.
  std::map<std::pair<int, int>, int> edge_faces;
  for (const auto& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) ++edge_faces[{std::min(f[k], f[(k + 1) % 3]), std::max(f[k], f[(k + 1) % 3])}];
  }
  size_t odd = 0;
  for (const auto& [edge, count] : edge_faces) odd += count % 2;
  *closed = !mesh.faces.empty() && odd <= edge_faces.size() / 200;
  if (!*closed) return inside;
  using Triangle = Kernel::Triangle_3;
  using Primitive = CGAL::AABB_triangle_primitive<Kernel, std::vector<Triangle>::const_iterator>;
  using Tree = CGAL::AABB_tree<CGAL::AABB_traits<Kernel, Primitive>>;
  std::vector<Triangle> triangles;
  triangles.reserve(mesh.faces.size());
  auto point = [&](int i) { return Point(mesh.vertices[i].x(), mesh.vertices[i].y(), mesh.vertices[i].z()); };
  for (const auto& f : mesh.faces) triangles.emplace_back(point(f[0]), point(f[1]), point(f[2]));
  Tree tree(triangles.begin(), triangles.end());
  tree.build();
  // Three rays in unrelated directions, majority of their parities: a ray grazing an edge or a
  // vertex miscounts, three rarely do at once.
  const Kernel::Vector_3 directions[3] = {{0.5377, 0.8622, -0.3413}, {-0.7161, 0.2519, 0.6509}, {0.1902, -0.6871, 0.7013}};
  tbb::parallel_for(size_t{0}, points.size(), [&](size_t i) {
    const Point origin(points[i].x(), points[i].y(), points[i].z());
    int votes = 0;
    for (const auto& direction : directions) {
      votes += tree.number_of_intersected_primitives(Kernel::Ray_3(origin, direction)) % 2;
    }
    inside[i] = votes >= 2;
  });
  return inside;
}

}  // namespace ibmr
