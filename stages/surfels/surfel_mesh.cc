// The CGAL side of the surfels stage (kept apart: a CGAL unit is slow to compile).
// Triangulation of the particle system (seed 000 section 5, lines 4454-4586: "an efficient
// triangulation scheme which connects the particles into a continuous global surface model"):
// CGAL's advancing-front surface reconstruction (Cohen-Steiner & Da, 2004) picks, among the
// Delaunay facets of the particles, a manifold surface grown from its most plausible facets; its
// priority is the smallest radius of the facet's Delaunay spheres, and a facet with an edge longer
// than the bound is never taken, so the mesh does not span holes wider than that. Faces are then
// turned to agree with the particles' normals.
// Inside test of a closed hull: CGAL's Side_of_triangle_mesh (AABB tree, ray parity).
#include <CGAL/AABB_face_graph_triangle_primitive.h>
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/Advancing_front_surface_reconstruction.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Side_of_triangle_mesh.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/helpers.h>

#include <array>
#include <cmath>

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
  for (const auto& f : facets) {
    Eigen::Vector3i face(static_cast<int>(f[0]), static_cast<int>(f[1]), static_cast<int>(f[2]));
    if (!particles.normals.empty()) {
      const Eigen::Vector3f& a = particles.positions[face[0]];
      const Eigen::Vector3f normal = (particles.positions[face[1]] - a).cross(particles.positions[face[2]] - a);
      const Eigen::Vector3f vertex_normals =
          particles.normals[face[0]] + particles.normals[face[1]] + particles.normals[face[2]];
      if (normal.dot(vertex_normals) < 0) std::swap(face[1], face[2]);
    }
    mesh.faces.push_back(face);
  }
  return mesh;
}

std::vector<char> InsideClosedMesh(const TriangleMesh& mesh, const std::vector<Eigen::Vector3f>& points, bool* closed) {
  std::vector<char> inside(points.size(), 1);
  using SurfaceMesh = CGAL::Surface_mesh<Point>;
  SurfaceMesh surface;
  std::vector<SurfaceMesh::Vertex_index> vertices;
  vertices.reserve(mesh.vertices.size());
  for (const auto& v : mesh.vertices) vertices.push_back(surface.add_vertex(Point(v.x(), v.y(), v.z())));
  for (const auto& f : mesh.faces) surface.add_face(vertices[f[0]], vertices[f[1]], vertices[f[2]]);
  *closed = surface.number_of_faces() == mesh.faces.size() && surface.number_of_faces() > 0 && CGAL::is_closed(surface);
  if (!*closed) return inside;
  const CGAL::Side_of_triangle_mesh<SurfaceMesh, Kernel> side(surface);
  for (size_t i = 0; i < points.size(); ++i) {
    inside[i] = side(Point(points[i].x(), points[i].y(), points[i].z())) != CGAL::ON_UNBOUNDED_SIDE;
  }
  return inside;
}

}  // namespace ibmr
