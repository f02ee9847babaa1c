// Tests of the surfels stage (seed 000 section 5): options; each potential's gradient against
// finite differences; noisy samples of a sphere and a plane converge onto the true surface with
// even spacing; the triangulation of a sampled closed surface is a closed 2-manifold (Euler
// characteristic 2) and a missing strip wider than a few spacings stays open; the outputs do not
// depend on the heap's state or the thread count; free space and the hull remove floaters; bad
// input (NaN, no normals, nothing) is handled; one adapter run.
#include "stages/surfels/surfels.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>
#include <random>
#include <set>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_surfels(StageRegistry* registry);

namespace {

// `count` points on the unit sphere, radial noise `sigma`, outward normals with a little noise.
PointCloud NoisySphere(size_t count, double sigma, uint32_t seed = 3) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0, 1);
  PointCloud cloud;
  for (size_t i = 0; i < count; ++i) {
    const Eigen::Vector3d direction = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
    cloud.positions.push_back((direction * (1 + sigma * normal(rng))).cast<float>());
    const Eigen::Vector3d n = (direction + 0.05 * Eigen::Vector3d(normal(rng), normal(rng), normal(rng))).normalized();
    cloud.normals.push_back(n.cast<float>());
    cloud.colors.emplace_back(200, 100, 50);
    cloud.confidence.push_back(1.0f);
  }
  return cloud;
}

// Points on the plane z = 0 in [-1, 1]^2 with noise `sigma` in z, normals +z; `skip` removes some.
template <typename Skip>
PointCloud NoisyPlane(size_t count, double sigma, Skip skip, uint32_t seed = 5) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(-1, 1);
  std::normal_distribution<double> normal(0, 1);
  PointCloud cloud;
  while (cloud.size() < count) {
    const Eigen::Vector3f p(uniform(rng), uniform(rng), sigma * normal(rng));
    if (skip(p)) continue;
    cloud.positions.push_back(p);
    cloud.normals.push_back(Eigen::Vector3f::UnitZ());
    cloud.colors.emplace_back(90, 90, 90);
    cloud.confidence.push_back(0.8f);
  }
  return cloud;
}

SurfelOptions FixedSpacing(double spacing) {
  SurfelOptions options;
  options.spacing = spacing;
  return options;
}

double RmsRadialError(const std::vector<Eigen::Vector3f>& points) {
  double sum = 0;
  for (const auto& p : points) sum += (p.norm() - 1) * (p.norm() - 1);
  return std::sqrt(sum / points.size());
}

// V - E + F, and whether every edge has exactly two faces (a closed 2-manifold).
int EulerCharacteristic(const TriangleMesh& mesh, bool* closed_manifold) {
  std::map<std::pair<int, int>, int> edges;
  for (const auto& f : mesh.faces) {
    for (int k = 0; k < 3; ++k) {
      const int a = f[k], b = f[(k + 1) % 3];
      ++edges[{std::min(a, b), std::max(a, b)}];
    }
  }
  *closed_manifold = true;
  for (const auto& [edge, count] : edges) *closed_manifold = *closed_manifold && count == 2;
  std::vector<char> used(mesh.vertices.size(), 0);
  for (const auto& f : mesh.faces) used[f[0]] = used[f[1]] = used[f[2]] = 1;
  const int vertices = static_cast<int>(std::count(used.begin(), used.end(), 1));
  return vertices - static_cast<int>(edges.size()) + static_cast<int>(mesh.faces.size());
}

TEST(SurfelOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(SurfelOptions().Check(&error)) << error;
}

TEST(SurfelOptions, RejectsInvalidRanges) {
  const std::vector<std::pair<std::string, std::function<void(SurfelOptions*)>>> cases = {
      {"spacing_scale", [](SurfelOptions* o) { o->spacing_scale = 0; }},
      {"spacing", [](SurfelOptions* o) { o->spacing = -2; }},
      {"iterations", [](SurfelOptions* o) { o->iterations = -1; }},
      {"grow_rounds", [](SurfelOptions* o) { o->grow_rounds = 21; }},
      {"coplanarity", [](SurfelOptions* o) { o->weights.coplanarity = -1; }},
      {"repulsion", [](SurfelOptions* o) { o->weights.repulsion = NAN; }},
      {"sigma", [](SurfelOptions* o) { o->weights.sigma = 0; }},
      {"tangential", [](SurfelOptions* o) { o->weights.tangential = 1.5; }},
      {"max_gap", [](SurfelOptions* o) { o->max_gap = 1; }},
      {"stretch_distance", [](SurfelOptions* o) { o->stretch_distance = 4.5; }},
      {"max_hole_edges", [](SurfelOptions* o) { o->max_hole_edges = -1; }},
      {"max_normal_angle_deg", [](SurfelOptions* o) { o->max_normal_angle_deg = 0; }},
      {"min_support", [](SurfelOptions* o) { o->min_support = -1; }},
      {"min_support_fraction", [](SurfelOptions* o) { o->min_support_fraction = 1.5; }},
      {"free_space_views", [](SurfelOptions* o) { o->free_space_views = 0; }},
      {"silhouette_views", [](SurfelOptions* o) { o->silhouette_views = -1; }},
      {"silhouette_color_tolerance", [](SurfelOptions* o) { o->silhouette_color_tolerance = 256; }},
      {"free_space_margin", [](SurfelOptions* o) { o->free_space_margin = 0; }},
      {"max_edge", [](SurfelOptions* o) { o->max_edge = 0.5; }},
      {"max_particles", [](SurfelOptions* o) { o->max_particles = 10; }},
      {"min_component_faces", [](SurfelOptions* o) { o->min_component_faces = -1; }},
      {"border_extension", [](SurfelOptions* o) { o->border_extension = 2.5; }},
  };
  for (const auto& [key, breaks] : cases) {
    SurfelOptions options;
    breaks(&options);
    std::string error;
    EXPECT_FALSE(options.Check(&error)) << key;
    EXPECT_EQ(error.substr(0, error.find(':')), key) << error;
  }
}

// One potential at a time (the others weighted 0): analytic gradient against central differences.
void ExpectPairGradientMatches(const ParticleWeights& weights) {
  std::mt19937 rng(11);
  std::normal_distribution<double> normal(0, 1);
  const double spacing = 0.7;
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Matrix<double, 12, 1> x;
    for (int k = 0; k < 12; ++k) x[k] = 0.5 * normal(rng);
    x.segment<3>(3).normalize();
    x.segment<3>(9).normalize();
    auto energy = [&](const Eigen::Matrix<double, 12, 1>& v) {
      return PairEnergy(v.segment<3>(0), v.segment<3>(3), v.segment<3>(6), v.segment<3>(9), spacing, weights);
    };
    PairGradient g;
    PairEnergy(x.segment<3>(0), x.segment<3>(3), x.segment<3>(6), x.segment<3>(9), spacing, weights, &g);
    Eigen::Matrix<double, 12, 1> analytic;
    analytic << g.p_i, g.n_i, g.p_j, g.n_j;
    for (int k = 0; k < 12; ++k) {
      Eigen::Matrix<double, 12, 1> plus = x, minus = x;
      plus[k] += 1e-6;
      minus[k] -= 1e-6;
      const double numeric = (energy(plus) - energy(minus)) / 2e-6;
      EXPECT_NEAR(analytic[k], numeric, 1e-5 * std::max(1.0, std::abs(numeric))) << "coordinate " << k << " trial " << trial;
    }
  }
}

ParticleWeights Only(double ParticleWeights::*member) {
  ParticleWeights w;
  w.coplanarity = w.conormality = w.cocircularity = w.repulsion = w.data = 0;
  w.*member = 1.3;
  w.repulsion_radius = 1.2;  // so that random pairs fall inside it
  return w;
}

TEST(SurfelPotentials, CoplanarityGradientMatchesFiniteDifferences) { ExpectPairGradientMatches(Only(&ParticleWeights::coplanarity)); }
TEST(SurfelPotentials, ConormalityGradientMatchesFiniteDifferences) { ExpectPairGradientMatches(Only(&ParticleWeights::conormality)); }
TEST(SurfelPotentials, CocircularityGradientMatchesFiniteDifferences) { ExpectPairGradientMatches(Only(&ParticleWeights::cocircularity)); }
TEST(SurfelPotentials, RepulsionGradientMatchesFiniteDifferences) { ExpectPairGradientMatches(Only(&ParticleWeights::repulsion)); }

TEST(SurfelPotentials, DataGradientMatchesFiniteDifferences) {
  const ParticleWeights weights = Only(&ParticleWeights::data);
  std::mt19937 rng(12);
  std::normal_distribution<double> normal(0, 1);
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Matrix<double, 6, 1> x;
    for (int k = 0; k < 6; ++k) x[k] = 0.4 * normal(rng);
    x.segment<3>(3).normalize();
    const Eigen::Vector3d q(0.1 * normal(rng), 0.1 * normal(rng), 0.1 * normal(rng));
    auto energy = [&](const Eigen::Matrix<double, 6, 1>& v) {
      return DataEnergy(v.segment<3>(0), v.segment<3>(3), q, 0.7, 0.5, weights);
    };
    Eigen::Vector3d gp = Eigen::Vector3d::Zero(), gn = Eigen::Vector3d::Zero();
    DataEnergy(x.segment<3>(0), x.segment<3>(3), q, 0.7, 0.5, weights, &gp, &gn);
    Eigen::Matrix<double, 6, 1> analytic;
    analytic << gp, gn;
    for (int k = 0; k < 6; ++k) {
      Eigen::Matrix<double, 6, 1> plus = x, minus = x;
      plus[k] += 1e-6;
      minus[k] -= 1e-6;
      const double numeric = (energy(plus) - energy(minus)) / 2e-6;
      EXPECT_NEAR(analytic[k], numeric, 1e-5 * std::max(1.0, std::abs(numeric))) << k;
    }
  }
}

TEST(SurfelPotentials, SphereAndPlaneArrangementsHaveNoShapeEnergy) {
  ParticleWeights w = Only(&ParticleWeights::cocircularity);
  const Eigen::Vector3d a = Eigen::Vector3d(1, 2, 2).normalized(), b = Eigen::Vector3d(2, 1, 2).normalized();
  EXPECT_NEAR(PairEnergy(3 * a, a, 3 * b, b, 0.5, w), 0.0, 1e-12);  // both on a sphere of radius 3
  w = Only(&ParticleWeights::coplanarity);
  EXPECT_NEAR(PairEnergy({0, 0, 0}, {0, 0, 1}, {0.3, 0.2, 0}, {0, 0, 1}, 0.5, w), 0.0, 1e-12);
  EXPECT_GT(PairEnergy({0, 0, 0}, {0, 0, 1}, {0.3, 0.2, 0.2}, {0, 0, 1}, 0.5, w), 0.01);
}

TEST(Surfels, NoisySphereConvergesToTheSurfaceWithEvenSpacing) {
  const double spacing = 0.05, sigma = 0.01;
  const PointCloud data = NoisySphere(60000, sigma);
  const PointCloud initial = ThinToSpacing(data, spacing);
  const SurfelResult result = ReconstructSurfels(data, {}, nullptr, FixedSpacing(spacing));
  const std::vector<Eigen::Vector3f>& p = result.surfels.positions;
  ASSERT_GT(p.size(), 3000u);
  EXPECT_LT(RmsRadialError(p), 0.35 * sigma) << "input noise " << sigma;
  double angle = 0;
  for (size_t i = 0; i < p.size(); ++i) angle += std::acos(std::min(1.0f, result.surfels.normals[i].dot(p[i].normalized())));
  EXPECT_LT(angle / p.size() * 180 / M_PI, 3.0);
  const double before = NearestNeighbourSpread(initial.positions), after = result.stats.spacing_spread;
  EXPECT_LT(after, 0.2) << "spread before relaxation " << before;
  EXPECT_LT(after, 0.7 * before);
  EXPECT_LT(result.stats.mean_step_last_sweep, 0.05);
  bool closed = false;
  EXPECT_EQ(EulerCharacteristic(result.mesh, &closed), 2);
  EXPECT_TRUE(closed);
  EXPECT_EQ(result.surfels.radius.size(), p.size());
}

// One stray point 6 million spacings away costs one cell, not the run (a 21-bit packed key refused
// any extent past 2 million spacings); the rest thin as before (the grid's origin moves with the
// lower corner, so the count may differ slightly).
TEST(Surfels, AStrayFarPointCostsOneCell) {
  const double spacing = 0.05;
  const PointCloud data = NoisySphere(20000, 0.01);
  PointCloud stray = data;
  stray.positions.emplace_back(0.f, 0.f, -3e5f);
  stray.normals.emplace_back(0.f, 0.f, 1.f);
  if (!stray.colors.empty()) stray.colors.push_back(stray.colors.back());
  if (!stray.confidence.empty()) stray.confidence.push_back(1.f);
  const PointCloud cells = ThinToSpacing(data, spacing), with_stray = ThinToSpacing(stray, spacing);
  EXPECT_NEAR(static_cast<double>(with_stray.size()), cells.size() + 1.0, 0.02 * cells.size());
  EXPECT_EQ(with_stray.positions.back(), Eigen::Vector3f(0.f, 0.f, -3e5f));
}

TEST(Surfels, NoisyPlaneConvergesToThePlane) {
  const double spacing = 0.05, sigma = 0.01;
  const PointCloud data = NoisyPlane(40000, sigma, [](const Eigen::Vector3f&) { return false; });
  const SurfelResult result = ReconstructSurfels(data, {}, nullptr, FixedSpacing(spacing));
  double sum = 0, tilt = 0;
  for (size_t i = 0; i < result.surfels.size(); ++i) {
    sum += result.surfels.positions[i].z() * result.surfels.positions[i].z();
    tilt += std::acos(std::min(1.0f, std::abs(result.surfels.normals[i].z())));
  }
  EXPECT_LT(std::sqrt(sum / result.surfels.size()), 0.3 * sigma);
  EXPECT_LT(tilt / result.surfels.size() * 180 / M_PI, 3.0);
  EXPECT_LT(result.stats.spacing_spread, 0.25);  // the plane's edges included

  // The discs (position, normal, radius) cover the surface: a fine grid of the plane's interior
  // (two spacings from its edges) lies within some disc, so a splat renderer leaves no pinholes.
  ASSERT_EQ(result.surfels.radius.size(), result.surfels.size());
  std::vector<std::vector<size_t>> cells(40 * 40);
  const auto cell_of = [](float v) { return std::clamp(static_cast<int>((v + 1.f) * 20.f), 0, 39); };
  for (size_t i = 0; i < result.surfels.size(); ++i) {
    cells[cell_of(result.surfels.positions[i].y()) * 40 + cell_of(result.surfels.positions[i].x())].push_back(i);
  }
  int missed = 0, probes = 0;
  for (double y = -0.9; y <= 0.9; y += 0.01) {
    for (double x = -0.9; x <= 0.9; x += 0.01, ++probes) {
      const Eigen::Vector3f q(static_cast<float>(x), static_cast<float>(y), 0.f);
      bool inside = false;
      for (int cy = std::max(0, cell_of(q.y()) - 1); cy <= std::min(39, cell_of(q.y()) + 1) && !inside; ++cy) {
        for (int cx = std::max(0, cell_of(q.x()) - 1); cx <= std::min(39, cell_of(q.x()) + 1) && !inside; ++cx) {
          for (size_t i : cells[cy * 40 + cx]) {
            const Eigen::Vector3f d = q - result.surfels.positions[i];
            const Eigen::Vector3f n = result.surfels.normals[i];
            const float along = d.dot(n);
            if ((d - along * n).norm() <= result.surfels.radius[i]) inside = true;
          }
        }
      }
      missed += inside ? 0 : 1;
    }
  }
  EXPECT_EQ(missed, 0) << "of " << probes << " probes";
}

void ExpectClosedOutwardSphere(int n) {
  SCOPED_TRACE(std::to_string(n) + " particles");
  PointCloud points;
  for (int i = 0; i < n; ++i) {  // Fibonacci sphere: even spacing ~ sqrt(4 pi / n)
    const double z = 1 - 2 * (i + 0.5) / n, r = std::sqrt(1 - z * z), phi = i * M_PI * (3 - std::sqrt(5.0));
    points.positions.emplace_back(r * std::cos(phi), r * std::sin(phi), z);
    points.normals.push_back(points.positions.back());
  }
  const double spacing = std::sqrt(4 * M_PI / n);
  const TriangleMesh mesh = TriangulateParticles(points, 3 * spacing);
  bool closed = false;
  EXPECT_EQ(EulerCharacteristic(mesh, &closed), 2);
  EXPECT_TRUE(closed);
  for (const auto& f : mesh.faces) {  // counter-clockwise seen from outside
    const Eigen::Vector3f normal = (mesh.vertices[f[1]] - mesh.vertices[f[0]]).cross(mesh.vertices[f[2]] - mesh.vertices[f[0]]);
    ASSERT_GT(normal.dot(mesh.vertices[f[0]]), 0);
  }
}

TEST(SurfelMesh, SampledSphereIsAClosedManifold) {
  ExpectClosedOutwardSphere(3000);
  // Triangulated in slabs (one front per slab, see TriangulateParticles): the cuts leave no seam.
  ExpectClosedOutwardSphere(40000);
}

// Leaves the heap fragmented: `count` small blocks allocated and every other one freed, so that what
// is allocated next lands elsewhere (as after parallel work done on the calling thread). Returns the
// blocks still held, for FreeAll.
std::vector<void*> FragmentHeap(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<void*> blocks;
  for (int i = 0; i < count; ++i) blocks.push_back(std::malloc(16 + rng() % 256));
  for (size_t i = 0; i < blocks.size(); i += 2) {
    std::free(blocks[i]);
    blocks[i] = nullptr;
  }
  return blocks;
}
void FreeAll(std::vector<void*>* blocks) {
  for (void* block : *blocks) std::free(block);
  blocks->clear();
}

// CGAL's advancing front broke ties by comparing addresses (its Delaunay handles, its queue's
// records), so the same particles gave different faces depending on the heap's state: on this
// input five of six runs differed before time-stamped handles and the queue's tie-break.
TEST(SurfelMesh, TheFacesDoNotDependOnWhereObjectsLandInMemory) {
  PointCloud points;
  const int n = 5000;
  const double spacing = std::sqrt(4 * M_PI / n);
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0, 1);
  for (int i = 0; i < n; ++i) {  // Fibonacci sphere with noise of half a spacing: holes, ties, post-processing
    const double z = 1 - 2 * (i + 0.5) / n, r = std::sqrt(1 - z * z), phi = i * M_PI * (3 - std::sqrt(5.0));
    const Eigen::Vector3f p = Eigen::Vector3f(r * std::cos(phi), r * std::sin(phi), z) +
                              0.5f * static_cast<float>(spacing) * Eigen::Vector3f(noise(rng), noise(rng), noise(rng));
    points.positions.push_back(p);
    points.normals.push_back(p.normalized());
  }
  const TriangleMesh reference = TriangulateParticles(points, 3 * spacing);
  ASSERT_GT(reference.faces.size(), 9000u);
  for (int round = 1; round <= 4; ++round) {
    std::vector<void*> blocks = FragmentHeap(5000 * round, round);
    const TriangleMesh mesh = TriangulateParticles(points, 3 * spacing);
    FreeAll(&blocks);
    ASSERT_EQ(mesh.faces.size(), reference.faces.size()) << "round " << round;
    EXPECT_TRUE(mesh.faces == reference.faces) << "round " << round;
  }
}

// The whole sequence gives the same surfels and mesh, bit for bit, with one thread or all of them.
TEST(Surfels, TheOutputsDoNotDependOnTheThreadCount) {
  const PointCloud data = NoisyPlane(40000, 0.002, [](const Eigen::Vector3f& p) { return p.head<2>().norm() < 0.3f; });
  auto run = [&](int threads) {
    std::unique_ptr<tbb::global_control> limit;
    if (threads > 0) limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
    return ReconstructSurfels(data, {}, nullptr, FixedSpacing(0.05));
  };
  const SurfelResult all = run(0);
  std::vector<void*> blocks = FragmentHeap(20000, 1);
  const SurfelResult one = run(1);
  FreeAll(&blocks);
  ASSERT_GT(all.mesh.faces.size(), 1000u);
  EXPECT_TRUE(one.surfels.positions == all.surfels.positions);
  EXPECT_TRUE(one.surfels.normals == all.surfels.normals);
  EXPECT_TRUE(one.surfels.radius == all.surfels.radius);
  EXPECT_TRUE(one.surfels.colors == all.surfels.colors);
  EXPECT_TRUE(one.surfels.confidence == all.surfels.confidence);
  EXPECT_TRUE(one.mesh.vertices == all.mesh.vertices);
  EXPECT_TRUE(one.mesh.faces == all.mesh.faces);
}

TEST(Surfels, AMissingStripWiderThanAFewSpacingsStaysOpen) {
  const double spacing = 0.05;
  const float half_width = static_cast<float>(3 * spacing);  // a strip 6 spacings wide
  const PointCloud data = NoisyPlane(40000, 0.002, [&](const Eigen::Vector3f& p) { return std::abs(p.x()) < half_width; });
  const SurfelResult result = ReconstructSurfels(data, {}, nullptr, FixedSpacing(spacing));
  for (const auto& p : result.surfels.positions) ASSERT_GT(std::abs(p.x()), 1.5 * spacing) << p.transpose();
  for (const auto& f : result.mesh.faces) {
    float lo = 1e9f, hi = -1e9f;
    for (int k = 0; k < 3; ++k) lo = std::min(lo, result.mesh.vertices[f[k]].x()), hi = std::max(hi, result.mesh.vertices[f[k]].x());
    ASSERT_FALSE(lo < 0 && hi > 0) << "a face spans the missing strip";
  }
  // A narrow crack (1.2 spacings) is closed by growth and triangulation.
  const PointCloud cracked = NoisyPlane(40000, 0.002, [&](const Eigen::Vector3f& p) { return std::abs(p.x()) < 0.6 * spacing; });
  const SurfelResult filled = ReconstructSurfels(cracked, {}, nullptr, FixedSpacing(spacing));
  size_t spanning = 0;
  for (const auto& f : filled.mesh.faces) {
    float lo = 1e9f, hi = -1e9f;
    for (int k = 0; k < 3; ++k) lo = std::min(lo, filled.mesh.vertices[f[k]].x()), hi = std::max(hi, filled.mesh.vertices[f[k]].x());
    spanning += lo < 0 && hi > 0;
  }
  EXPECT_GT(spanning, 20u);
}

// An n x n vertex grid in z = 0 (faces up), without the faces around vertex `hole` (-1: none).
TriangleMesh Grid(int n, int hole) {
  TriangleMesh mesh;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) mesh.vertices.emplace_back(x, y, 0);
  for (int y = 0; y + 1 < n; ++y) {
    for (int x = 0; x + 1 < n; ++x) {
      const int a = y * n + x, b = a + 1, c = a + n, d = c + 1;
      if (a == hole || b == hole || c == hole || d == hole) continue;
      mesh.faces.emplace_back(a, b, d);
      mesh.faces.emplace_back(a, d, c);
    }
  }
  return mesh;
}

TEST(SurfelMesh, CleaningDropsSmallPiecesAndClosesSmallHoles) {
  TriangleMesh mesh = Grid(20, 10 * 20 + 10);  // a hole of 8 boundary edges in a 722-face sheet
  const size_t grid_faces = mesh.faces.size();
  const int n = static_cast<int>(mesh.vertices.size());
  mesh.vertices.emplace_back(50, 50, 0);  // and a lone triangle
  mesh.vertices.emplace_back(51, 50, 0);
  mesh.vertices.emplace_back(50, 51, 0);
  mesh.faces.emplace_back(n, n + 1, n + 2);
  EXPECT_EQ(RemoveSmallComponents(5, &mesh), 1u);
  EXPECT_EQ(mesh.faces.size(), grid_faces);
  EXPECT_EQ(FillSmallHoles(4, &mesh), 0u);  // the hole has 8 edges: larger than allowed, stays open
  EXPECT_EQ(FillSmallHoles(8, &mesh), 1u);  // the sheet's border (76 edges) stays open
  EXPECT_EQ(mesh.faces.size(), grid_faces + 8);
  for (size_t f = grid_faces; f < mesh.faces.size(); ++f) {  // the fill faces up like the grid
    const auto& face = mesh.faces[f];
    const Eigen::Vector3f normal = (mesh.vertices[face[1]] - mesh.vertices[face[0]]).cross(mesh.vertices[face[2]] - mesh.vertices[face[0]]);
    EXPECT_GT(normal.z(), 0);
  }
  // A small patch's outer border is no hole, however few its edges: it is not capped.
  TriangleMesh patch = Grid(6, -1);  // 50 faces, border of 20 edges
  EXPECT_EQ(FillSmallHoles(24, &patch), 0u);
  EXPECT_EQ(patch.faces.size(), 50u);
}

TEST(SurfelMesh, OpenBordersMoveOutInTheTangentPlaneAndClosedOnesStay) {
  // A 10 x 10 sheet with a hole around vertex (5, 5): both the outer border and the hole's move by
  // 0.4 outward (away from the faces), in the sheet's plane, with the new faces facing up.
  TriangleMesh mesh = Grid(10, 5 * 10 + 5);
  mesh.normals.assign(mesh.vertices.size(), Eigen::Vector3f::UnitZ());
  const size_t faces = mesh.faces.size(), vertices = mesh.vertices.size();
  const size_t extended = ExtendBorders(0.4f, &mesh);
  EXPECT_EQ(extended, 36u + 8u);  // the outer border's edges and the hole's
  EXPECT_EQ(mesh.faces.size(), faces + 2 * extended);
  Eigen::Vector3f lo, hi;
  ASSERT_TRUE(mesh.Bounds(&lo, &hi));
  EXPECT_NEAR(lo.x(), -0.4f, 0.05f);  // the sheet spans [0, 9]: its sides move out by 0.4 (corners farther
  EXPECT_NEAR(hi.y(), 9.4f, 0.05f);   // along the diagonal, by 0.4 too)
  EXPECT_FLOAT_EQ(lo.z(), 0.0f);
  EXPECT_FLOAT_EQ(hi.z(), 0.0f);
  std::set<std::pair<int, int>> directed;
  for (const auto& f : mesh.faces) {
    const Eigen::Vector3f normal = (mesh.vertices[f[1]] - mesh.vertices[f[0]]).cross(mesh.vertices[f[2]] - mesh.vertices[f[0]]);
    EXPECT_GT(normal.z(), 0);  // no strip folds back over the sheet
    for (int k = 0; k < 3; ++k) EXPECT_TRUE(directed.insert({f[k], f[(k + 1) % 3]}).second) << "an edge used twice one way";
  }
  // The hole shrank: its vertices moved toward (5, 5) by 0.4 (the ring's sides lie at distance 1).
  float nearest = 1e9f;
  for (size_t i = vertices; i < mesh.vertices.size(); ++i) nearest = std::min(nearest, (mesh.vertices[i] - Eigen::Vector3f(5, 5, 0)).norm());
  EXPECT_NEAR(nearest, 0.6f, 0.05f);
  // A closed surface has no border: nothing moves.
  TriangleMesh tetra;
  tetra.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  tetra.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  EXPECT_EQ(ExtendBorders(0.4f, &tetra), 0u);
  EXPECT_EQ(tetra.vertices.size(), 4u);
}

// Two views above the plane z = 0 that saw the plane; a cluster floating at z = 0.5 is free space.
TEST(Surfels, ParticlesThatDepthMapsSeeThroughAreRemoved) {
  const double spacing = 0.05;
  PointCloud data = NoisyPlane(40000, 0.002, [](const Eigen::Vector3f&) { return false; });
  std::mt19937 rng(9);
  std::normal_distribution<float> normal(0, 0.04f);
  for (int i = 0; i < 1500; ++i) {
    data.positions.emplace_back(0.2f + normal(rng), normal(rng), 0.5f + 0.1f * normal(rng));
    data.normals.push_back(Eigen::Vector3f::UnitZ());
    data.colors.emplace_back(255, 0, 0);
    data.confidence.push_back(0.8f);
  }
  std::vector<SurfelView> views;
  for (const double x : {-0.3, 0.3}) {
    SurfelView view;
    view.camera = Camera::Pinhole(200, 200, 150, 150, 100, 100);
    view.cam_from_world = LookAt(Eigen::Vector3d(x, 0, 3), Eigen::Vector3d(x, 0, 0), Eigen::Vector3d::UnitY());
    view.depth = DepthMap(200, 200, 1, 0.f);
    const Rigid3d world_from_cam = view.cam_from_world.Inverse();
    for (int y = 0; y < 200; ++y) {
      for (int px = 0; px < 200; ++px) {
        const Eigen::Vector3d ray = world_from_cam.rotation * view.camera.CamFromImg(Eigen::Vector2d(px + 0.5, y + 0.5));
        view.depth.At(px, y) = static_cast<float>(3.0 / -ray.z() * view.camera.CamFromImg(Eigen::Vector2d(px + 0.5, y + 0.5)).z());
      }
    }
    views.push_back(view);
  }
  SurfelOptions options = FixedSpacing(spacing);
  const SurfelResult kept = ReconstructSurfels(data, {}, nullptr, options);
  size_t floating = 0;
  for (const auto& p : kept.surfels.positions) floating += p.z() > 0.2f;
  EXPECT_GT(floating, 10u) << "without depth maps the floater stays";
  const SurfelResult pruned = ReconstructSurfels(data, views, nullptr, options);
  for (const auto& p : pruned.surfels.positions) ASSERT_LT(p.z(), 0.2f) << p.transpose();
  EXPECT_GT(pruned.stats.removed_free_space, 10u);
}

// One view above the plane z = 0 whose silhouette keeps the half x < 0.
TEST(Surfels, ParticlesOnTheBackgroundOfMasksAreRemoved) {
  const PointCloud data = NoisyPlane(20000, 0.002, [](const Eigen::Vector3f&) { return false; });
  SurfelView view;
  view.camera = Camera::Pinhole(200, 200, 60, 60, 100, 100);
  view.cam_from_world = LookAt(Eigen::Vector3d(0, 0, 3), Eigen::Vector3d(0, 0, 0), Eigen::Vector3d::UnitY());
  view.mask = cv::Mat(200, 200, CV_8UC1, cv::Scalar(0));
  for (int y = 0; y < 200; ++y) {
    for (int x = 0; x < 200; ++x) {
      const Eigen::Vector3d ray = view.cam_from_world.Inverse().rotation * view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
      if (ray.x() < 0) view.mask.at<uint8_t>(y, x) = 255;  // world x < 0 where the ray meets z = 0
    }
  }
  SurfelOptions options = FixedSpacing(0.06);
  const SurfelResult all = ReconstructSurfels(data, {view}, nullptr, options);
  EXPECT_EQ(all.stats.removed_off_silhouette, 0u);
  options.silhouette_views = 1;
  const SurfelResult kept = ReconstructSurfels(data, {view}, nullptr, options);
  EXPECT_GT(kept.stats.removed_off_silhouette, all.surfels.size() / 3);
  for (const auto& p : kept.surfels.positions) ASSERT_LT(p.x(), 0.03f) << p.transpose();

  // The particles are grey (90): on a photo of black background they are floaters and go; where
  // the photo shows their own grey (a dark backdrop the mask's threshold left out) they stay.
  options.silhouette_color_tolerance = 25;
  view.image = cv::Mat(200, 200, CV_8UC3, cv::Scalar(0, 0, 0));
  const SurfelResult on_black = ReconstructSurfels(data, {view}, nullptr, options);
  EXPECT_EQ(on_black.stats.removed_off_silhouette, kept.stats.removed_off_silhouette);
  view.image.setTo(cv::Scalar(100, 80, 95));  // BGR, within 25 of grey 90 in every channel
  const SurfelResult on_backdrop = ReconstructSurfels(data, {view}, nullptr, options);
  EXPECT_EQ(on_backdrop.stats.removed_off_silhouette, 0u);
  EXPECT_EQ(on_backdrop.surfels.size(), all.surfels.size());
  view.image.setTo(cv::Scalar(90, 90, 130));  // red off by 40: not the particles' colour
  EXPECT_EQ(ReconstructSurfels(data, {view}, nullptr, options).stats.removed_off_silhouette,
            kept.stats.removed_off_silhouette);
}

TEST(Surfels, TheHullBoundsTheSurface) {
  TriangleMesh cube;  // closed cube of half-size 0.8, counter-clockwise from outside
  for (int i = 0; i < 8; ++i) cube.vertices.emplace_back(i & 1 ? 0.8f : -0.8f, i & 2 ? 0.8f : -0.8f, i & 4 ? 0.8f : -0.8f);
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : quads) {
    cube.faces.emplace_back(q[0], q[1], q[2]);
    cube.faces.emplace_back(q[0], q[2], q[3]);
  }
  bool closed = false;
  const std::vector<char> inside = InsideClosedMesh(cube, {{0, 0, 0}, {0.9f, 0, 0}, {0.7f, 0.7f, -0.7f}}, &closed);
  ASSERT_TRUE(closed);
  EXPECT_EQ(inside, (std::vector<char>{1, 0, 1}));
  const SurfelResult result = ReconstructSurfels(NoisySphere(30000, 0.005), {}, &cube, FixedSpacing(0.06));
  EXPECT_GT(result.stats.removed_outside_hull, 100u);
  for (const auto& p : result.surfels.positions) ASSERT_LE(p.cwiseAbs().maxCoeff(), 0.8f + 1e-4f) << p.transpose();
}

TEST(Surfels, BadInputIsHandledOrRefusedClearly) {
  PointCloud data = NoisySphere(20000, 0.005);
  data.positions[5] = Eigen::Vector3f(NAN, 0, 0);
  data.positions[6] = Eigen::Vector3f(0, INFINITY, 0);
  SurfelResult result = ReconstructSurfels(data, {}, nullptr, FixedSpacing(0.06));
  EXPECT_EQ(result.stats.dropped_nonfinite, 2u);
  for (const auto& p : result.surfels.positions) ASSERT_TRUE(p.allFinite());

  data.normals.clear();  // normals estimated from neighbours, turned away from the centroid
  result = ReconstructSurfels(data, {}, nullptr, FixedSpacing(0.06));
  EXPECT_TRUE(result.stats.estimated_normals);
  size_t outward = 0;
  for (size_t i = 0; i < result.surfels.size(); ++i) outward += result.surfels.normals[i].dot(result.surfels.positions[i]) > 0.9f;
  EXPECT_GT(outward, 0.97 * result.surfels.size());

  EXPECT_THROW(ReconstructSurfels(PointCloud(), {}, nullptr, FixedSpacing(0.06)), InputError);
  EXPECT_THROW(ReconstructSurfels(NoisySphere(100, 0.01), {}, nullptr, SurfelOptions()), InputError);  // no footprint
}

TEST(SurfelsStage, WritesSurfelsAndMeshAndNamesAMissingInput) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_surfels_test_" + std::to_string(::getpid()));
  fs::remove_all(root);
  const Workspace workspace(root.string());
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(320, 240, 300, 300, 160, 120);
  for (int i = 0; i < 6; ++i) {
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    const double angle = 2 * M_PI * i / 6;
    image.cam_from_world = LookAt(Eigen::Vector3d(4 * std::cos(angle), 4 * std::sin(angle), 1), Eigen::Vector3d::Zero(),
                                  Eigen::Vector3d::UnitZ());
    model.images[image.image_id] = image;
  }
  WriteSparseModelText(workspace.SparseDir(), model);
  fs::create_directories(workspace.Path("dense"));
  WritePointCloudPly(workspace.Path("dense/fused.ply"), NoisySphere(40000, 0.003));

  StageRegistry registry;
  RegisterStage_surfels(&registry);
  const Stage* stage = registry.Find("surfels");
  ASSERT_NE(stage, nullptr);
  StageContext context;
  context.workspace = workspace;
  context.role = stage->Role();
  NullProgress progress;
  context.progress = &progress;
  for (const ParamSpec& spec : stage->Parameters()) {
    if (spec.type == ParamType::kInt) context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
    if (spec.type == ParamType::kDouble) context.params.Set(spec.key, std::stod(spec.default_yaml));
    if (spec.type == ParamType::kString) context.params.Set(spec.key, spec.default_yaml);
    if (spec.type == ParamType::kBool) context.params.Set(spec.key, spec.default_yaml == "true");
  }
  context.params.Set("spacing_scale", 4.0);  // footprint 4/300 at depth ~3 -> spacing ~0.05
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  const PointCloud surfels = ReadPointCloudPly(workspace.Path("surfels/surfels.ply"));
  EXPECT_GT(surfels.size(), 2000u);
  EXPECT_EQ(surfels.radius.size(), surfels.size());
  EXPECT_EQ(surfels.normals.size(), surfels.size());
  EXPECT_EQ(surfels.confidence.size(), surfels.size());
  const TriangleMesh mesh = ReadMeshPly(workspace.Path("surfels/mesh.ply"));
  EXPECT_EQ(mesh.Validate(), "");
  EXPECT_GT(mesh.faces.size(), surfels.size());
  EXPECT_NEAR(context.metrics["spacing"].get<double>(), 4 * 3.0 / 300, 0.01);

  Params bad = context.params;
  bad.Set("max_edge", 0.1);
  ASSERT_TRUE(stage->CheckParams(bad).has_value());
  EXPECT_EQ(stage->CheckParams(bad)->key, "max_edge");
  fs::remove(workspace.Path("dense/fused.ply"));
  try {
    stage->Run(context);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("dense/fused.ply"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("run fuse"), std::string::npos) << e.what();
  }
  WritePointCloudPly(workspace.Path("dense/fused.ply"), PointCloud());
  EXPECT_THROW(stage->Run(context), InputError);

  // Points on a line make particles but no face: refused (the texture and render stages would fail
  // on an empty mesh later), and the last good mesh stays.
  PointCloud line;
  for (int i = 0; i < 2000; ++i) {
    line.positions.emplace_back(-1.f + i / 1000.f, 0.f, 0.f);
    line.normals.emplace_back(0.f, 0.f, 1.f);
  }
  WritePointCloudPly(workspace.Path("dense/fused.ply"), line);
  try {
    stage->Run(context);
    FAIL() << "a mesh without faces was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("no mesh face"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ReadMeshPly(workspace.Path("surfels/mesh.ply")).faces.size(), mesh.faces.size());
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
