// Decimation for model selection: a finely tessellated sphere brought to a face budget stays a
// closed surface of genus 0 close to the sphere, within the budget; a mesh within the budget is
// unchanged; colours follow the vertices.
#include "stages/render/mesh_decimation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>

namespace ibmr {
namespace {

// A UV sphere of radius 1: `rings` x `segments` quads split in two, poles as fans.
TriangleMesh UvSphere(int rings, int segments) {
  TriangleMesh mesh;
  mesh.vertices.emplace_back(0.f, 0.f, 1.f);
  for (int r = 1; r < rings; ++r) {
    const double theta = M_PI * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * M_PI * s / segments;
      mesh.vertices.emplace_back(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
    }
  }
  mesh.vertices.emplace_back(0.f, 0.f, -1.f);
  const int south = static_cast<int>(mesh.vertices.size()) - 1;
  const auto at = [&](int r, int s) { return 1 + (r - 1) * segments + (s % segments); };
  for (int s = 0; s < segments; ++s) mesh.faces.emplace_back(0, at(1, s), at(1, s + 1));
  for (int r = 1; r + 1 < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      mesh.faces.emplace_back(at(r, s), at(r + 1, s), at(r + 1, s + 1));
      mesh.faces.emplace_back(at(r, s), at(r + 1, s + 1), at(r, s + 1));
    }
  }
  for (int s = 0; s < segments; ++s) mesh.faces.emplace_back(south, at(rings - 1, s + 1), at(rings - 1, s));
  for (const auto& v : mesh.vertices) {
    mesh.colors.emplace_back(static_cast<uint8_t>(100 + 100 * v.z()), 50, 50);
  }
  return mesh;
}

TEST(MeshDecimation, SphereKeepsItsShapeAndTopologyWithinTheBudget) {
  const TriangleMesh sphere = UvSphere(60, 120);
  ASSERT_EQ(sphere.Validate(), "");
  const size_t budget = sphere.faces.size() / 20;
  size_t refused = 0;
  const TriangleMesh small = DecimateMesh(sphere, budget, &refused);
  EXPECT_EQ(refused, 0u);
  EXPECT_EQ(small.Validate(), "");
  EXPECT_LE(small.faces.size(), budget);
  EXPECT_GT(small.faces.size(), budget * 9 / 10);
  // Closed: every undirected edge in exactly two faces; Euler characteristic 2.
  std::map<std::pair<int, int>, int> edges;
  for (const auto& f : small.faces) {
    for (int k = 0; k < 3; ++k) {
      const int a = f[k], b = f[(k + 1) % 3];
      ++edges[{std::min(a, b), std::max(a, b)}];
    }
  }
  for (const auto& [edge, count] : edges) ASSERT_EQ(count, 2) << edge.first << "-" << edge.second;
  EXPECT_EQ(static_cast<long>(small.vertices.size()) - static_cast<long>(edges.size()) +
                static_cast<long>(small.faces.size()),
            2);
  double worst = 0;
  for (const auto& v : small.vertices) worst = std::max(worst, std::abs(static_cast<double>(v.norm()) - 1));
  EXPECT_LT(worst, 0.01) << "vertices stay on the sphere";
  ASSERT_EQ(small.colors.size(), small.vertices.size());
  for (size_t i = 0; i < small.vertices.size(); ++i) {
    EXPECT_NEAR(small.colors[i][0], 100 + 100 * small.vertices[i].z(), 1.5);
  }
}

TEST(MeshDecimation, AMeshWithinTheBudgetIsUnchanged) {
  const TriangleMesh sphere = UvSphere(8, 12);
  const TriangleMesh same = DecimateMesh(sphere, sphere.faces.size());
  EXPECT_EQ(same.faces, sphere.faces);
  EXPECT_EQ(same.vertices, sphere.vertices);
}

}  // namespace
}  // namespace ibmr
