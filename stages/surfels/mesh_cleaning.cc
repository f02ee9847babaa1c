// Cleaning of the particle mesh: small disconnected pieces removed (floaters that survived the
// pruning as a handful of particles), small holes closed by a fan around their centroid. The advancing front
// leaves a few small openings where particles are uneven; openings bounded by at most
// `max_edges` edges (a hole a few spacings across) are closed, larger ones stay open: a missing
// part of the data stays missing. Boundary loops that pass a vertex twice (two openings touching
// at a vertex) are left alone, so the fill never makes a vertex non-manifold.
// The open borders that remain are then moved out by the particles' disc radius (ExtendBorders):
// the mesh joins the particles' centres, while each particle stands for a disc around its centre
// (seed 000 section 5), so a border through the centres leaves the outer half of every border
// disc uncovered, a rim a few pixels wide around every silhouette of the object.
#include <Eigen/Geometry>
#include <numeric>
#include <unordered_map>

#include "stages/surfels/surfels.h"

namespace ibmr {

size_t FillSmallHoles(int max_edges, TriangleMesh* mesh) {
  // Directed boundary edges: a face's edge (a, b) with no face using (b, a). The hole's loop runs
  // the other way, b -> a, which is the orientation its filling faces take.
  std::unordered_map<uint64_t, int> directed;
  auto key = [](int a, int b) { return (static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32) | static_cast<uint32_t>(b); };
  for (const auto& f : mesh->faces) {
    for (int k = 0; k < 3; ++k) ++directed[key(f[k], f[(k + 1) % 3])];
  }
  std::unordered_map<int, int> next;     // loop successor of a boundary vertex
  std::unordered_map<int, int> starts;   // how many boundary edges start at a vertex
  for (const auto& f : mesh->faces) {
    for (int k = 0; k < 3; ++k) {
      const int a = f[k], b = f[(k + 1) % 3];
      if (directed.count(key(b, a))) continue;
      next[b] = a;
      ++starts[b];
    }
  }
  // A loop of L edges around a piece of fewer than 2 L^2 faces is that piece's outer border (a disc
  // bounded by L edges has about L^2 / 5 faces), not a hole in it: it stays open.
  const std::vector<int> piece = ConnectedPieces(*mesh);
  std::unordered_map<int, size_t> faces_of;
  std::unordered_map<int, int> piece_of_vertex;
  for (size_t i = 0; i < mesh->faces.size(); ++i) {
    ++faces_of[piece[i]];
    for (int k = 0; k < 3; ++k) piece_of_vertex[mesh->faces[i][k]] = piece[i];
  }
  std::unordered_map<int, char> visited;
  size_t filled = 0;
  for (const auto& [first, unused] : next) {
    if (visited[first]) continue;
    std::vector<int> loop;
    bool simple = true;
    int v = first;
    while (!visited[v]) {
      visited[v] = 1;
      loop.push_back(v);
      simple = simple && starts[v] == 1;
      const auto it = next.find(v);
      if (it == next.end()) {
        simple = false;
        break;
      }
      v = it->second;
      if (static_cast<int>(loop.size()) > max_edges) simple = false;
    }
    if (!simple || v != first || loop.size() < 3 || static_cast<int>(loop.size()) > max_edges) continue;
    if (faces_of[piece_of_vertex[first]] < 2 * loop.size() * loop.size()) continue;
    if (loop.size() == 3) {
      mesh->faces.emplace_back(loop[0], loop[1], loop[2]);
    } else {
      Eigen::Vector3f centre = Eigen::Vector3f::Zero(), normal = Eigen::Vector3f::Zero();
      Eigen::Vector3i color = Eigen::Vector3i::Zero();
      for (const int u : loop) {
        centre += mesh->vertices[u];
        if (!mesh->normals.empty()) normal += mesh->normals[u];
        if (!mesh->colors.empty()) color += mesh->colors[u].cast<int>();
      }
      const int c = static_cast<int>(mesh->vertices.size());
      mesh->vertices.push_back(centre / static_cast<float>(loop.size()));
      if (!mesh->normals.empty()) mesh->normals.push_back(normal.normalized());
      if (!mesh->colors.empty()) mesh->colors.push_back((color / static_cast<int>(loop.size())).cast<uint8_t>());
      for (size_t k = 0; k < loop.size(); ++k) mesh->faces.emplace_back(loop[k], loop[(k + 1) % loop.size()], c);
    }
    ++filled;
  }
  return filled;
}

size_t ExtendBorders(float distance, TriangleMesh* mesh) {
  if (distance <= 0 || mesh->faces.empty()) return 0;
  auto key = [](int a, int b) { return (static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32) | static_cast<uint32_t>(b); };
  std::unordered_map<uint64_t, int> directed;
  for (const auto& f : mesh->faces) {
    for (int k = 0; k < 3; ++k) ++directed[key(f[k], f[(k + 1) % 3])];
  }
  // Border edges (a, b): a face has a -> b and no face has b -> a. Each one's outward direction
  // lies in its face's plane, perpendicular to the edge, away from the face's third vertex; a
  // border vertex moves along the sum of its two edges' directions.
  struct Border {
    Eigen::Vector3f outward = Eigen::Vector3f::Zero();
    int leaving = 0, entering = 0;  // border edges starting / ending here
    int moved = -1;                 // index of the moved copy
  };
  std::vector<std::pair<int, int>> edges;
  std::unordered_map<int, Border> border;
  const std::vector<Eigen::Vector3f>& v = mesh->vertices;
  for (const auto& f : mesh->faces) {
    for (int k = 0; k < 3; ++k) {
      const int a = f[k], b = f[(k + 1) % 3], c = f[(k + 2) % 3];
      if (directed.count(key(b, a))) continue;
      const Eigen::Vector3f along = v[b] - v[a];
      Eigen::Vector3f out = along.cross(along.cross(v[c] - v[a]));
      if (out.dot(v[c] - v[a]) > 0) out = -out;
      if (!(out.squaredNorm() > 0) || !out.allFinite()) continue;  // degenerate face
      out.normalize();
      edges.emplace_back(a, b);
      border[a].outward += out;
      ++border[a].leaving;
      border[b].outward += out;
      ++border[b].entering;
    }
  }
  // Vertices where two openings touch (more than one border edge each way) stay where they are:
  // there "outward" has no single meaning.
  for (auto& [index, b] : border) {
    if (b.leaving != 1 || b.entering != 1) continue;
    Eigen::Vector3f out = b.outward;
    if (!mesh->normals.empty()) out -= out.dot(mesh->normals[index]) * mesh->normals[index];
    if (!(out.norm() > 1e-6f * b.outward.norm()) || !out.allFinite()) continue;
    b.moved = static_cast<int>(mesh->vertices.size());
    mesh->vertices.push_back(mesh->vertices[index] + distance * out.normalized());
    if (!mesh->normals.empty()) mesh->normals.push_back(mesh->normals[index]);
    if (!mesh->colors.empty()) mesh->colors.push_back(mesh->colors[index]);
  }
  // A quad (two faces) along each border edge whose ends both moved, oriented like the face it
  // continues (it uses the edge as b -> a).
  size_t extended = 0;
  for (const auto& [a, b] : edges) {
    const int a2 = border[a].moved, b2 = border[b].moved;
    if (a2 < 0 || b2 < 0) continue;
    mesh->faces.emplace_back(b, a, a2);
    mesh->faces.emplace_back(b, a2, b2);
    ++extended;
  }
  return extended;
}

std::vector<int> ConnectedPieces(const TriangleMesh& mesh) {
  // Union-find over vertices joined by faces.
  std::vector<int> parent(mesh.vertices.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  for (const auto& f : mesh.faces) {
    parent[find(f[1])] = find(f[0]);
    parent[find(f[2])] = find(f[0]);
  }
  std::vector<int> piece(mesh.faces.size());
  for (size_t i = 0; i < mesh.faces.size(); ++i) piece[i] = find(mesh.faces[i][0]);
  return piece;
}

size_t RemoveSmallComponents(int min_faces, TriangleMesh* mesh) {
  if (min_faces <= 1 || mesh->faces.empty()) return 0;
  const std::vector<int> piece = ConnectedPieces(*mesh);
  std::unordered_map<int, int> faces_of;
  for (const int p : piece) ++faces_of[p];
  std::vector<Eigen::Vector3i> kept;
  kept.reserve(mesh->faces.size());
  for (size_t i = 0; i < mesh->faces.size(); ++i) {
    if (faces_of[piece[i]] >= min_faces) kept.push_back(mesh->faces[i]);
  }
  const size_t removed = mesh->faces.size() - kept.size();
  mesh->faces.swap(kept);
  return removed;
}

}  // namespace ibmr
