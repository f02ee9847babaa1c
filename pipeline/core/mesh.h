// Point clouds and triangle meshes as plain arrays (binary PLY I/O in ply_io.h). Optional
// attributes are empty vectors or have one entry per vertex.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace ibmr {

using Color3u8 = Eigen::Matrix<uint8_t, 3, 1>;

struct PointCloud {
  std::vector<Eigen::Vector3f> positions;
  std::vector<Eigen::Vector3f> normals;     // empty or one per point, unit length
  std::vector<Color3u8> colors;             // empty or one per point
  std::vector<float> confidence;            // empty or one per point (PLY property "confidence")
  std::vector<float> radius;                // empty or one per point: a surfel's world radius (PLY "radius")
  std::vector<std::string> comments;        // PLY header comments

  size_t size() const { return positions.size(); }
};

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3f> normals;     // empty or one per vertex
  std::vector<Color3u8> colors;             // empty or one per vertex
  std::vector<Eigen::Vector3i> faces;       // counter-clockwise seen from outside
  std::vector<std::string> comments;        // PLY header comments, e.g. "ibmr conservative_hull 1"

  // Recomputes area-weighted per-vertex normals from the faces.
  void ComputeVertexNormals();
  // Axis-aligned bounds; returns false when the mesh has no vertex.
  bool Bounds(Eigen::Vector3f* min, Eigen::Vector3f* max) const;
  // Empty when valid; otherwise names the first face with an index out of range, etc.
  std::string Validate() const;
  // Removes the vertices with a NaN or infinite coordinate and every face that uses one (the others
  // are renumbered); returns how many vertices went. Screened Poisson meshers now and then emit such
  // a vertex in an empty corner of their octree.
  size_t DropNonFiniteVertices();
};

}  // namespace ibmr
