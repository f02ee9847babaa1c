// Vertex clustering keeps a mesh within the page's face budget without breaking it apart, and
// keeps each surviving face's texture coordinates; the even subsample spreads over the input.
#include "pipeline/runner/viewer_geometry.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <set>

namespace ibmr {
namespace {

// An n x n grid of unit squares (2 n^2 faces) in the z = 0 plane, shared vertices, coloured by x.
ViewerMesh Grid(int n) {
  ViewerMesh mesh;
  for (int y = 0; y <= n; ++y) {
    for (int x = 0; x <= n; ++x) {
      mesh.vertices.emplace_back(static_cast<float>(x), static_cast<float>(y), 0.f);
      mesh.colors.emplace_back(static_cast<uint8_t>(255 * x / n), 0, 0);
    }
  }
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const int a = y * (n + 1) + x, b = a + 1, c = a + n + 1, d = c + 1;
      mesh.faces.emplace_back(a, b, d);
      mesh.faces.emplace_back(a, d, c);
    }
  }
  return mesh;
}

// The same grid with three vertices of its own per face and a UV per corner, on two pages.
ViewerMesh PerCornerGrid(int n) {
  const ViewerMesh shared = Grid(n);
  ViewerMesh mesh;
  for (size_t f = 0; f < shared.faces.size(); ++f) {
    for (int c = 0; c < 3; ++c) {
      const Eigen::Vector3f& v = shared.vertices[shared.faces[f][c]];
      mesh.vertices.push_back(v);
      mesh.uvs.emplace_back(v.x() / n, v.y() / n);
    }
    const int base = static_cast<int>(3 * f);
    mesh.faces.emplace_back(base, base + 1, base + 2);
    mesh.face_page.push_back(static_cast<int>(f % 2));
  }
  return mesh;
}

TEST(ViewerGeometry, MeshWithinTheBudgetIsUnchanged) {
  const ViewerMesh mesh = Grid(10);
  const ViewerMesh out = ClusterDecimate(mesh, mesh.faces.size());
  EXPECT_EQ(out.faces.size(), mesh.faces.size());
  EXPECT_EQ(out.vertices.size(), mesh.vertices.size());
}

TEST(ViewerGeometry, ClusteringKeepsTheBudgetAndTheShape) {
  const ViewerMesh mesh = Grid(200);  // 80,000 faces
  const ViewerMesh out = ClusterDecimate(mesh, 5000);
  EXPECT_LE(out.faces.size(), 5000u);
  EXPECT_GE(out.faces.size(), 2000u) << "the grid should be as fine as the budget allows";
  ASSERT_EQ(out.colors.size(), out.vertices.size());
  EXPECT_TRUE(out.uvs.empty());
  // Every vertex is used, and the grid still spans (about) its square.
  std::set<int> used;
  Eigen::Vector3f lo = out.vertices[0], hi = out.vertices[0];
  for (const auto& f : out.faces) used.insert({f[0], f[1], f[2]});
  for (const auto& v : out.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  EXPECT_EQ(used.size(), out.vertices.size());
  EXPECT_LT(lo.x(), 5.f);
  EXPECT_GT(hi.x(), 195.f);
  EXPECT_LT(lo.y(), 5.f);
  EXPECT_GT(hi.y(), 195.f);
  // A face's area summed over the mesh: the square's, within the cells' rounding of its border.
  double area = 0;
  for (const auto& f : out.faces) {
    area += 0.5 * (out.vertices[f[1]] - out.vertices[f[0]]).cross(out.vertices[f[2]] - out.vertices[f[0]]).norm();
  }
  EXPECT_NEAR(area, 200.0 * 200.0, 0.06 * 200.0 * 200.0);
}

TEST(ViewerGeometry, PerCornerVerticesKeepTheirUvAndPage) {
  const ViewerMesh mesh = PerCornerGrid(100);  // 20,000 faces, 60,000 corners
  const ViewerMesh out = ClusterDecimate(mesh, 2000);
  EXPECT_LE(out.faces.size(), 2000u);
  EXPECT_GE(out.faces.size(), 700u);
  ASSERT_EQ(out.uvs.size(), out.vertices.size());
  ASSERT_EQ(out.face_page.size(), out.faces.size());
  std::set<int> pages(out.face_page.begin(), out.face_page.end());
  EXPECT_EQ(pages, (std::set<int>{0, 1}));
  // Corners moved to their cell's mean, at most a cell from where their UV says they were.
  const float cell_bound = 100.f / 10.f;
  for (size_t v = 0; v < out.vertices.size(); ++v) {
    const Eigen::Vector2f was = out.uvs[v] * 100.f;
    EXPECT_LT((out.vertices[v].head<2>() - was).norm(), cell_bound) << v;
  }
}

TEST(ViewerGeometry, EvenSubsampleSpreadsOverTheInput) {
  EXPECT_EQ(EvenSubsample(10, 3), (std::vector<size_t>{0, 3, 6}));
  EXPECT_EQ(EvenSubsample(2, 5), (std::vector<size_t>{0, 1}));
  EXPECT_TRUE(EvenSubsample(0, 5).empty());
  const std::vector<size_t> many = EvenSubsample(1000000, 1000);
  ASSERT_EQ(many.size(), 1000u);
  EXPECT_EQ(many.back(), 999000u);
}

}  // namespace
}  // namespace ibmr
