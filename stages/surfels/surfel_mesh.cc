// The CGAL side of the surfels stage (kept apart: a CGAL unit is slow to compile).
// Triangulation of the particle system (seed 000 section 5, lines 4454-4586: "an efficient
// triangulation scheme which connects the particles into a continuous global surface model"):
// CGAL's advancing-front surface reconstruction (Cohen-Steiner & Da, 2004) picks, among the
// Delaunay facets of the particles, a manifold surface grown from its most plausible facets; its
// priority is the smallest radius of the facet's Delaunay spheres, and a facet with an edge longer
// than the bound is never taken, so the mesh does not span holes wider than that. Faces are then
// turned to agree with the particles' normals.
// Inside test of a closed hull: parity of ray crossings through a CGAL AABB tree of its triangles.
//
// Reproducibility: CGAL's advancing front, as its free function sets it up, depends on where its
// objects land in memory, so the same particles gave different meshes from run to run (templeRing:
// 139175 to 139212 faces; two runs with --jobs 1 agreed, as a single thread leaves the heap in the
// same state, but TBB work done on the calling thread does not). Addresses are compared in:
//  - the Delaunay triangulation's handles: which of its two cells represents a facet in the facet
//    scans (and so which way the front turns around an edge, and which of equal facets it takes
//    first), and the vertex removals of the front's post-processing (hash maps and canonical vertex
//    triples keyed by handles, which decide the new cells). Time-stamped vertices and cells (CGAL's
//    Has_timestamp, which Mesh_3 uses for the same reason) compare and hash by creation order.
//  - the front's priority queue, a std::set of (priority, pointer to a border edge's record), whose
//    ties (two border edges whose best facets share a Delaunay sphere, the constant stand-by
//    priorities) fell back to the records' addresses; std::less is specialised below for it.
// Neither changes which facets the algorithm prefers, only the order among equals. The price: a
// time-stamp comparison reads the neighbouring cell, and the front scans every facet once per piece
// of surface it starts (templeRing: 128 pieces, triangulation 4.6 s -> 7.6 s).
//
// Slabs: those scans make one front's time grow faster than its size (templeRing with its backdrop,
// 99k particles and 180 pieces: 16.5 s on one thread; 25k particles: 0.8 s). Clouds of 25k particles
// and more are cut across their longest side into slabs of ~12.5k; each slab is triangulated with
// its neighbours' particles within 3 edge bounds of it (so that both fronts see the same
// neighbourhood at a cut and mostly choose the same facets there) and keeps the facets whose
// centroid lies inside it; slabs run in parallel, each deterministic on its own, so the thread count
// changes nothing. Where two slabs still chose differently, edges with a third face lose the later
// slab's faces. templeRing: 13.2 s on one thread, 8 s on two; the mesh's open border edges
// 7650 -> 7882 (1% more), held-out photo PSNR of the surfel mesh unchanged (25.30 / 25.29 dB).
#include <CGAL/AABB_traits.h>
#include <CGAL/AABB_tree.h>
#include <CGAL/AABB_triangle_primitive.h>
#include <CGAL/Advancing_front_surface_reconstruction.h>
#include <CGAL/Delaunay_triangulation_3.h>
#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Triangulation_data_structure_3.h>
#include <tbb/parallel_for.h>

#include <algorithm>

#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <numeric>
#include <utility>

#include "stages/surfels/surfels.h"

namespace ibmr {

namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;

// A vertex or cell base with a time stamp (set by CGAL's Compact_container when the object is
// created): handles then compare and hash by creation order, not by address.
template <typename Base>
class TimeStamped : public Base {
 public:
  using Has_timestamp = CGAL::Tag_true;
  template <typename Tds2>
  struct Rebind_TDS {
    using Other = TimeStamped<typename Base::template Rebind_TDS<Tds2>::Other>;
  };
  using Base::Base;
  std::size_t time_stamp() const { return time_stamp_; }
  void set_time_stamp(const std::size_t& stamp) { time_stamp_ = stamp; }

 private:
  std::size_t time_stamp_ = std::size_t(-1);
};

// The types of CGAL::advancing_front_surface_reconstruction's free function, with time stamps.
using FrontVertexBase =
    CGAL::Advancing_front_surface_reconstruction_vertex_base_3<Kernel, TimeStamped<CGAL::Triangulation_vertex_base_3<Kernel>>>;
using FrontCellBase = CGAL::Advancing_front_surface_reconstruction_cell_base_3<
    Kernel, TimeStamped<CGAL::Delaunay_triangulation_cell_base_3<Kernel>>>;
using FrontTds = CGAL::Triangulation_data_structure_3<FrontVertexBase, FrontCellBase>;
using FrontDelaunay = CGAL::Delaunay_triangulation_3<Kernel, FrontTds>;
// An entry of the front's priority queue: (priority, the border edge's record).
using FrontQueueEntry = FrontTds::Vertex::Radius_ptr_type;

}  // namespace

}  // namespace ibmr

// The front's priority queue is a std::set<FrontQueueEntry> with the default std::less, which breaks
// ties by the record's address. Ties are broken here by the (sorted) indices of the border edge's
// two vertices instead: they stay fixed while an entry is queued (CGAL rewrites a queued record only
// for the same edge, or moves it to the neighbouring cell, which keeps its vertices), and two
// queued records for one edge do not occur (the address remains the last resort).
namespace std {
template <>
struct less<ibmr::FrontQueueEntry> {
  bool operator()(const ibmr::FrontQueueEntry& a, const ibmr::FrontQueueEntry& b) const {
    if (a.first != b.first) return a.first < b.first;
    if (a.second == b.second) return false;
    const std::pair<std::size_t, std::size_t> ka = EdgeKey(*a.second), kb = EdgeKey(*b.second);
    if (ka != kb) return ka < kb;
    return a.second < b.second;
  }
  template <typename Record>
  static std::pair<std::size_t, std::size_t> EdgeKey(const Record& record) {
    const auto& edge = record.first.first;  // (cell, i, j): the border edge in its border facet's cell
    const std::size_t u = edge.first->vertex(edge.second)->id(), v = edge.first->vertex(edge.third)->id();
    return std::minmax(u, v);
  }
};
}  // namespace std

namespace ibmr {

namespace {

// Particles per slab when the particles are triangulated in slabs (see TriangulateParticles), and
// the slabs' overlap, in edge bounds.
constexpr size_t kParticlesPerSlab = 12500;
constexpr double kSlabOverlapEdges = 3.0;

// Edge k of a face (from corner k to the next) as an undirected key: smaller index first.
std::pair<int, int> UndirectedEdge(const Eigen::Vector3i& face, int k) { return std::minmax(face[k], face[(k + 1) % 3]); }

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

// What CGAL::advancing_front_surface_reconstruction does, on the time-stamped triangulation of the
// particles `group` lists (default radius ratio bound 5 and beta 0.52): faces as particle indices.
std::vector<Eigen::Vector3i> FrontFaces(const std::vector<Eigen::Vector3f>& positions, const std::vector<uint32_t>& group,
                                        double max_edge_length) {
  std::vector<std::pair<Point, std::size_t>> points;
  points.reserve(group.size());
  for (size_t k = 0; k < group.size(); ++k) {
    const Eigen::Vector3f& p = positions[group[k]];
    points.emplace_back(Point(p.x(), p.y(), p.z()), k);
  }
  std::vector<std::array<std::size_t, 3>> facets;
  FrontDelaunay delaunay(points.begin(), points.end());
  CGAL::Advancing_front_surface_reconstruction<FrontDelaunay, EdgeBound> front(
      delaunay, EdgeBound{max_edge_length * max_edge_length});
  front.run();
  CGAL::write_triple_indices(std::back_inserter(facets), front);
  std::vector<Eigen::Vector3i> faces;
  faces.reserve(facets.size());
  for (const auto& f : facets) faces.emplace_back(static_cast<int>(group[f[0]]), static_cast<int>(group[f[1]]), static_cast<int>(group[f[2]]));
  return faces;
}

}  // namespace

TriangleMesh TriangulateParticles(const PointCloud& particles, double max_edge_length) {
  TriangleMesh mesh;
  mesh.vertices = particles.positions;
  mesh.normals = particles.normals;
  mesh.colors = particles.colors;
  if (particles.size() < 3) return mesh;
  const size_t n = particles.size();
  const int slabs = static_cast<int>(std::clamp<size_t>(n / kParticlesPerSlab, 1, 64));
  if (slabs == 1) {
    std::vector<uint32_t> all(n);
    std::iota(all.begin(), all.end(), 0u);
    mesh.faces = FrontFaces(particles.positions, all, max_edge_length);
  } else {
    // Slabs across the longest side of the particles' box, of equal counts; each is triangulated
    // with its neighbours' particles within `overlap` of it and keeps the faces whose centroid lies
    // in it, turned by its own pieces' votes (fronts orient independently).
    Eigen::Vector3f lo = particles.positions[0], hi = lo;
    for (const auto& p : particles.positions) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
    int axis = 0;
    (hi - lo).maxCoeff(&axis);
    std::vector<float> along(n);
    for (size_t i = 0; i < n; ++i) along[i] = particles.positions[i][axis];
    std::vector<float> sorted = along;
    std::sort(sorted.begin(), sorted.end());
    std::vector<float> cuts(slabs + 1);
    cuts.front() = -std::numeric_limits<float>::infinity();
    cuts.back() = std::numeric_limits<float>::infinity();
    for (int k = 1; k < slabs; ++k) cuts[k] = sorted[n * k / slabs];
    const float overlap = static_cast<float>(kSlabOverlapEdges * max_edge_length);
    std::vector<std::vector<Eigen::Vector3i>> per_slab(slabs);
    tbb::parallel_for(0, slabs, [&](int k) {
      std::vector<uint32_t> group;
      for (uint32_t i = 0; i < n; ++i) {
        if (along[i] >= cuts[k] - overlap && along[i] < cuts[k + 1] + overlap) group.push_back(i);
      }
      TriangleMesh slab;
      slab.vertices = particles.positions;
      for (const Eigen::Vector3i& f : FrontFaces(particles.positions, group, max_edge_length)) {
        const float centroid = (along[f[0]] + along[f[1]] + along[f[2]]) / 3.f;
        if (centroid >= cuts[k] && centroid < cuts[k + 1]) slab.faces.push_back(f);
      }
      if (!particles.normals.empty()) OrientPieces(particles, &slab);
      per_slab[k] = std::move(slab.faces);
    });
    // Where two slabs' fronts chose differently at a cut, an edge can end up with more than two
    // faces: the later slabs' faces on it go (in slab order), and the opening left is a hole that
    // FillSmallHoles may close.
    std::map<std::pair<int, int>, int> edge_faces;
    for (const auto& slab : per_slab) {
      for (const Eigen::Vector3i& f : slab) {
        bool fits = true;
        for (int e = 0; e < 3 && fits; ++e) {
          const auto it = edge_faces.find(UndirectedEdge(f, e));
          fits = it == edge_faces.end() || it->second < 2;
        }
        if (!fits) continue;
        for (int e = 0; e < 3; ++e) ++edge_faces[UndirectedEdge(f, e)];
        mesh.faces.push_back(f);
      }
    }
  }
  if (!particles.normals.empty()) OrientPieces(particles, &mesh);
  // A canonical order, after the orientation is settled (each face rotated to start at its smallest
  // index, then sorted), so that the faces do not depend on the order CGAL emits them in.
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
    for (int k = 0; k < 3; ++k) ++edge_faces[UndirectedEdge(f, k)];
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
