// Tests for PLY I/O (round trips, the exact header written, hand-written ascii and binary files
// with other types and extra properties, corrupt files) and for the TriangleMesh helpers that
// the PLY reader and writer rely on (normals, bounds, Validate).
#include "pipeline/core/ply_io.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_ply_io_" + name); }

template <typename T>
void Put(std::string* out, T value) {
  out->append(reinterpret_cast<const char*>(&value), sizeof(T));
}

// A unit tetrahedron, faces counter-clockwise seen from outside.
TriangleMesh Tetrahedron() {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  mesh.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return mesh;
}

TEST(PlyIo, PointCloudRoundTripWithAllAttributes) {
  const std::string path = (MakeTestDir("cloud") / "dense" / "fused.ply").string();
  PointCloud cloud;
  for (int i = 0; i < 50; ++i) {
    cloud.positions.emplace_back(0.1f * i, -2.5f + i, 1e-3f * i * i);
    cloud.normals.push_back(Eigen::Vector3f(i, 1, -i).normalized());
    cloud.colors.emplace_back(i, 255 - i, 3 * i);
    cloud.confidence.push_back(0.02f * i);
  }
  cloud.comments = {"ibmr fuse 1", "second comment"};
  WritePointCloudPly(path, cloud);
  const PointCloud back = ReadPointCloudPly(path);
  EXPECT_EQ(back.positions, cloud.positions);
  EXPECT_EQ(back.normals, cloud.normals);
  EXPECT_EQ(back.colors, cloud.colors);
  EXPECT_EQ(back.confidence, cloud.confidence);
  EXPECT_EQ(back.comments, cloud.comments);
}

TEST(PlyIo, PointCloudWithPositionsOnly) {
  const std::string path = (MakeTestDir("bare") / "p.ply").string();
  PointCloud cloud;
  cloud.positions = {{1, 2, 3}, {4, 5, 6}};
  WritePointCloudPly(path, cloud);
  const std::string bytes = ReadFile(path);
  EXPECT_EQ(bytes.size(), std::string("ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
                                      "property float y\nproperty float z\nend_header\n").size() + 24);
  const PointCloud back = ReadPointCloudPly(path);
  EXPECT_EQ(back.positions, cloud.positions);
  EXPECT_TRUE(back.normals.empty());
  EXPECT_TRUE(back.colors.empty());
  EXPECT_TRUE(back.confidence.empty());
}

TEST(PlyIo, MeshRoundTripAndHeaderBytes) {
  const std::string path = (MakeTestDir("mesh") / "hull.ply").string();
  TriangleMesh mesh = Tetrahedron();
  mesh.ComputeVertexNormals();
  mesh.colors = {{10, 20, 30}, {40, 50, 60}, {70, 80, 90}, {255, 0, 128}};
  mesh.comments = {"ibmr conservative_hull 1"};
  WriteMeshPly(path, mesh);

  const std::string expected_header =
      "ply\nformat binary_little_endian 1.0\ncomment ibmr conservative_hull 1\nelement vertex 4\n"
      "property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n"
      "property float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face 4\n"
      "property list uchar int vertex_indices\nend_header\n";
  const std::string bytes = ReadFile(path);
  ASSERT_EQ(bytes.size(), expected_header.size() + 4 * 27 + 4 * 13);
  EXPECT_EQ(bytes.substr(0, expected_header.size()), expected_header);
  // The last face record: count 3, then indices 1 2 3 as int32.
  std::string last_face;
  Put<uint8_t>(&last_face, 3);
  for (int32_t i : {1, 2, 3}) Put<int32_t>(&last_face, i);
  EXPECT_EQ(bytes.substr(bytes.size() - 13), last_face);

  const TriangleMesh back = ReadMeshPly(path);
  EXPECT_EQ(back.vertices, mesh.vertices);
  EXPECT_EQ(back.normals, mesh.normals);
  EXPECT_EQ(back.colors, mesh.colors);
  EXPECT_EQ(back.faces, mesh.faces);
  EXPECT_EQ(back.comments, mesh.comments);
}

// A NaN vertex (as Poisson meshers sometimes write) goes with its faces; the rest is renumbered.
TEST(PlyIo, AMeshLosesItsNonFiniteVerticesAndTheirFaces) {
  const std::string path = (MakeTestDir("nan_vertex") / "mesh.ply").string();
  WriteFileAtomic(path,
                  "ply\nformat ascii 1.0\nelement vertex 5\n"
                  "property float x\nproperty float y\nproperty float z\n"
                  "property uchar red\nproperty uchar green\nproperty uchar blue\n"
                  "element face 3\nproperty list uchar int vertex_indices\nend_header\n"
                  "0 0 0 1 1 1\n1 0 0 2 2 2\nnan 0 0 3 3 3\n1 1 0 4 4 4\n0 1 inf 5 5 5\n"
                  "3 0 1 3\n3 0 2 3\n3 1 3 4\n");
  const TriangleMesh mesh = ReadMeshPly(path);
  ASSERT_EQ(mesh.vertices.size(), 3u);
  EXPECT_EQ(mesh.vertices[2], Eigen::Vector3f(1, 1, 0));
  EXPECT_EQ(mesh.colors[2], Color3u8(4, 4, 4));
  ASSERT_EQ(mesh.faces.size(), 1u);
  EXPECT_EQ(mesh.faces[0], Eigen::Vector3i(0, 1, 2));
  EXPECT_EQ(mesh.Validate(), "");
}

TEST(PlyIo, ReadsHandWrittenAscii) {
  const std::string path = (MakeTestDir("ascii") / "quad.ply").string();
  WriteFileAtomic(path,
                  "ply\r\n"
                  "format ascii 1.0\n"
                  "comment made by hand\n"
                  "element vertex 4\n"
                  "property double x\nproperty double y\nproperty double z\n"
                  "property float quality\n"
                  "property uchar red\nproperty uchar green\nproperty uchar blue\n"
                  "element face 1\n"
                  "property list uchar int vertex_indices\n"
                  "property list uchar float texcoord\n"
                  "end_header\n"
                  "0 0 0 0.5 255 0 0\n"
                  "1 0 0 0.5 0 255 0\n"
                  "1 1 0.5 0.5 0 0 255\n"
                  "0 1 -1e-1 0.5 1 2 3\n"
                  "4 0 1 2 3 2 0.5 0.5\n");
  const TriangleMesh mesh = ReadMeshPly(path);
  ASSERT_EQ(mesh.vertices.size(), 4u);
  EXPECT_EQ(mesh.vertices[2], Eigen::Vector3f(1, 1, 0.5f));
  EXPECT_EQ(mesh.vertices[3], Eigen::Vector3f(0, 1, -0.1f));
  ASSERT_EQ(mesh.colors.size(), 4u);
  EXPECT_EQ(mesh.colors[3], Color3u8(1, 2, 3));
  EXPECT_TRUE(mesh.normals.empty());
  // The quad is split into a fan of two triangles.
  ASSERT_EQ(mesh.faces.size(), 2u);
  EXPECT_EQ(mesh.faces[0], Eigen::Vector3i(0, 1, 2));
  EXPECT_EQ(mesh.faces[1], Eigen::Vector3i(0, 2, 3));
  EXPECT_EQ(mesh.comments, std::vector<std::string>{"made by hand"});
}

TEST(PlyIo, ReadsBinaryWithOtherTypesAndExtraProperties) {
  const std::string path = (MakeTestDir("binary") / "m.ply").string();
  std::string bytes =
      "ply\nformat binary_little_endian 1.0\nobj_info whatever\n"
      "element vertex 3\nproperty double x\nproperty double y\nproperty double z\nproperty short flags\n"
      "property float confidence\n"
      "element face 1\nproperty uchar material\nproperty list int uint vertex_indices\n"
      "element edge 1\nproperty int vertex1\nproperty int vertex2\n"
      "end_header\n";
  const double coords[3][3] = {{0.5, 1.5, 2.5}, {-1, 0, 1}, {3, 2, 1}};
  for (int i = 0; i < 3; ++i) {
    for (double c : coords[i]) Put<double>(&bytes, c);
    Put<int16_t>(&bytes, -7);
    Put<float>(&bytes, 0.25f * i);
  }
  Put<uint8_t>(&bytes, 9);
  Put<int32_t>(&bytes, 3);
  for (uint32_t i : {2u, 1u, 0u}) Put<uint32_t>(&bytes, i);
  Put<int32_t>(&bytes, 0);
  Put<int32_t>(&bytes, 1);
  WriteFileAtomic(path, bytes);

  const TriangleMesh mesh = ReadMeshPly(path);
  ASSERT_EQ(mesh.vertices.size(), 3u);
  EXPECT_EQ(mesh.vertices[0], Eigen::Vector3f(0.5f, 1.5f, 2.5f));
  EXPECT_EQ(mesh.vertices[1], Eigen::Vector3f(-1, 0, 1));
  ASSERT_EQ(mesh.faces.size(), 1u);
  EXPECT_EQ(mesh.faces[0], Eigen::Vector3i(2, 1, 0));
  const PointCloud cloud = ReadPointCloudPly(path);
  EXPECT_EQ(cloud.confidence, (std::vector<float>{0.f, 0.25f, 0.5f}));
}

std::string ReadError(const std::string& path) {
  try {
    ReadMeshPly(path);
  } catch (const IoError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected IoError reading " << path;
  return "";
}

TEST(PlyIo, CorruptFilesNameTheFile) {
  const fs::path dir = MakeTestDir("corrupt");
  const std::string path = (dir / "bad.ply").string();
  TriangleMesh mesh = Tetrahedron();
  WriteMeshPly(path, mesh);
  std::string bytes = ReadFile(path);

  WriteFileAtomic(path, bytes.substr(0, bytes.size() - 5));
  std::string message = ReadError(path);
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("face"), std::string::npos) << message;

  WriteFileAtomic(path, "not a ply at all");
  message = ReadError(path);
  EXPECT_NE(message.find(path), std::string::npos) << message;

  WriteFileAtomic(path, "ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n");
  message = ReadError(path);
  EXPECT_NE(message.find("line 2"), std::string::npos) << message;
  EXPECT_NE(message.find("binary_big_endian"), std::string::npos) << message;

  WriteFileAtomic(path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty quaternion x\nend_header\n");
  message = ReadError(path);
  EXPECT_NE(message.find("line 4"), std::string::npos) << message;
  EXPECT_NE(message.find("quaternion"), std::string::npos) << message;

  WriteFileAtomic(path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                        "0 0 0\n3 0 0 5\n");
  message = ReadError(path);
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("vertex 5"), std::string::npos) << "out-of-range index: " << message;

  WriteFileAtomic(path, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                        "property float z\nend_header\n0 0 0\n1 x 2\n");
  message = ReadError(path);
  EXPECT_NE(message.find("record 1"), std::string::npos) << message;
}

// An element without properties skipped the size guard, and the reader then looped over its
// records for ever (fusion's output read by a later stage hung at 100% CPU).
TEST(PlyIo, HugeCountOfAnElementWithoutPropertiesIsAnError) {
  const fs::path dir = MakeTestDir("huge_empty_element");
  const std::string path = (dir / "bad.ply").string();
  WriteFileAtomic(path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                        "property float z\nelement foo 99999999999999\nend_header\n0 0 0\n");
  const std::string message = ReadError(path);
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("\"foo\" claims 99999999999999"), std::string::npos) << message;
  // A few empty records within the data still read.
  WriteFileAtomic(path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                        "property float z\nelement foo 2\nend_header\n0 0 0\n");
  EXPECT_EQ(ReadPointCloudPly(path).positions.size(), 1u);
}

TEST(PlyIo, WriterRejectsInconsistentAttributes) {
  const std::string path = (MakeTestDir("inconsistent") / "p.ply").string();
  PointCloud cloud;
  cloud.positions = {{0, 0, 0}, {1, 1, 1}};
  cloud.colors = {{1, 2, 3}};
  EXPECT_THROW(WritePointCloudPly(path, cloud), IoError);
  EXPECT_FALSE(fs::exists(path));
}

TEST(TriangleMesh, NormalsPointOutwardAndAreAreaWeighted) {
  TriangleMesh mesh = Tetrahedron();
  mesh.ComputeVertexNormals();
  ASSERT_EQ(mesh.normals.size(), 4u);
  for (const Eigen::Vector3f& n : mesh.normals) EXPECT_NEAR(n.norm(), 1.f, 1e-6f);
  // Vertex 0 sees three unit right triangles of equal area: normal along -(1,1,1).
  EXPECT_LT((mesh.normals[0] + Eigen::Vector3f(1, 1, 1).normalized()).norm(), 1e-6f);
  // Vertex 3 touches faces with normals -x (area 1/2), -y (1/2) and (1,1,1)/sqrt3 (area sqrt3/2):
  // the area-weighted sum is (-1/2 + 1/2, -1/2 + 1/2, 1/2) ~ +z.
  EXPECT_LT((mesh.normals[3] - Eigen::Vector3f(0, 0, 1)).norm(), 1e-6f);
}

TEST(TriangleMesh, BoundsAndValidate) {
  TriangleMesh mesh;
  Eigen::Vector3f lo, hi;
  EXPECT_FALSE(mesh.Bounds(&lo, &hi));
  mesh = Tetrahedron();
  mesh.vertices[3] = {-2, 5, 0.5f};
  ASSERT_TRUE(mesh.Bounds(&lo, &hi));
  EXPECT_EQ(lo, Eigen::Vector3f(-2, 0, 0));
  EXPECT_EQ(hi, Eigen::Vector3f(1, 5, 0.5f));
  EXPECT_EQ(mesh.Validate(), "");
  mesh.faces[2][1] = 4;
  EXPECT_NE(mesh.Validate().find("face 2"), std::string::npos) << mesh.Validate();
  mesh = Tetrahedron();
  mesh.normals.resize(3);
  EXPECT_NE(mesh.Validate().find("normals"), std::string::npos);
}

}  // namespace
}  // namespace ibmr
