// Tests of the texture stage's algorithm on in-memory scenes: options, visibility against a
// brute-force ray cast, the view selection's energy, a checkerboard plane textured from two
// views, seam leveling under an exposure difference, hole filling, view maps.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "stages/texture/color_leveling.h"
#include "stages/texture/face_view_maps.h"
#include "stages/texture/face_visibility.h"
#include "stages/texture/texture_atlas.h"
#include "stages/texture/texture_options.h"
#include "stages/texture/view_selection.h"

namespace ibmr {
namespace {

// An n x n grid of quads (two triangles each) on z = z0 over [-s, s]^2, normals toward +z.
TriangleMesh Grid(int n, double s, double z0, TriangleMesh mesh = TriangleMesh()) {
  const int base = static_cast<int>(mesh.vertices.size());
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      mesh.vertices.emplace_back(static_cast<float>(-s + 2 * s * i / n), static_cast<float>(-s + 2 * s * j / n), static_cast<float>(z0));
    }
  }
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = base + j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      mesh.faces.emplace_back(a, b, d);
      mesh.faces.emplace_back(a, d, c);
    }
  }
  return mesh;
}

// Checkerboard of 0.25-unit squares in the plane z = 0, BGR.
cv::Vec3b Checker(double x, double y) {
  const bool dark = (static_cast<int>(std::floor(x / 0.25)) + static_cast<int>(std::floor(y / 0.25))) % 2 != 0;
  return dark ? cv::Vec3b(40, 60, 200) : cv::Vec3b(220, 200, 30);
}

// The image of the checkerboard plane z = 0 seen by a camera (exact ray-plane intersections).
cv::Mat RenderChecker(const Camera& camera, const Rigid3d& cam_from_world, double gain = 1.0) {
  cv::Mat image(camera.height, camera.width, CV_8UC3, cv::Scalar::all(0));
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const Eigen::Vector3d ray = world_from_cam.rotation * camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
      const double t = -world_from_cam.translation.z() / ray.z();
      if (!(t > 0)) continue;
      const Eigen::Vector3d p = world_from_cam.translation + t * ray;
      const cv::Vec3b c = Checker(p.x(), p.y());
      image.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uint8_t>(c[0] * gain), cv::saturate_cast<uint8_t>(c[1] * gain),
                                            cv::saturate_cast<uint8_t>(c[2] * gain));
    }
  }
  return image;
}

Camera TestCamera() { return Camera::Pinhole(320, 240, 300, 300, 160, 120); }

TEST(TextureOptions, DefaultsAreValidAndEachRangeIsChecked) {
  std::string error;
  EXPECT_TRUE(TextureOptions().Check(&error)) << error;
  const auto fails = [](auto change, const std::string& key) {
    TextureOptions o;
    change(o);
    std::string message;
    EXPECT_FALSE(o.Check(&message)) << key;
    EXPECT_EQ(message.rfind(key, 0), 0u) << message;
  };
  fails([](TextureOptions& o) { o.smoothness = -1; }, "smoothness");
  fails([](TextureOptions& o) { o.max_iterations = 0; }, "max_iterations");
  fails([](TextureOptions& o) { o.visibility_epsilon = 0; }, "visibility_epsilon");
  fails([](TextureOptions& o) { o.min_cos_angle = 1; }, "min_cos_angle");
  fails([](TextureOptions& o) { o.gain_sigma = 0; }, "gain_sigma");
  fails([](TextureOptions& o) { o.consistency_tolerance = -0.1; }, "consistency_tolerance");
  fails([](TextureOptions& o) { o.leveling_smoothness = 0; }, "leveling_smoothness");
  fails([](TextureOptions& o) { o.max_texture_size = 32; }, "max_texture_size");
  fails([](TextureOptions& o) { o.padding = -1; }, "padding");
  fails([](TextureOptions& o) { o.hole_cell = 2; }, "hole_cell");
  fails([](TextureOptions& o) { o.view_map_grid = 1; }, "view_map_grid");
  fails([](TextureOptions& o) { o.view_map_partial_penalty = -0.1; }, "view_map_partial_penalty");
  fails([](TextureOptions& o) { o.view_map_partial_penalty = std::nan(""); }, "view_map_partial_penalty");
}

// Möller-Trumbore: distance along the ray to the triangle, or -1.
double RayTriangle(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                   const Eigen::Vector3d& c) {
  const Eigen::Vector3d e1 = b - a, e2 = c - a, p = d.cross(e2);
  const double det = e1.dot(p);
  if (std::abs(det) < 1e-12) return -1;
  const Eigen::Vector3d s = o - a;
  const double u = s.dot(p) / det;
  if (u < 0 || u > 1) return -1;
  const Eigen::Vector3d q = s.cross(e1);
  const double v = d.dot(q) / det;
  if (v < 0 || u + v > 1) return -1;
  return e2.dot(q) / det;
}

// A 16 x 16 plane with a small square in front of it: the z-buffer visibility agrees with ray
// casting from the camera to each face's sample points, and no face behind the square is seen.
TEST(FaceVisibility, AgreesWithABruteForceRayCastUnderOcclusion) {
  TriangleMesh mesh = Grid(16, 1.0, 0.0);
  const size_t plane_faces = mesh.faces.size();
  mesh = Grid(2, 0.3, 0.5, mesh);  // the occluder, 0.5 in front
  const Camera camera = TestCamera();
  const Rigid3d pose = LookAt(Eigen::Vector3d(0.3, -0.2, 3.0), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY());
  const cv::Mat image = RenderChecker(camera, pose);
  const FaceGeometry geometry = FaceGeometry::Of(mesh);
  std::vector<std::pair<int, FaceObservation>> seen;
  ObserveView(mesh, geometry, camera, pose, image, 0, TextureOptions(), &seen);
  std::vector<char> visible(mesh.faces.size(), 0), partly(mesh.faces.size(), 0);
  for (const auto& [f, o] : seen) {
    if (!o.hidden) (o.partial ? partly : visible)[f] = 1;
  }

  const Eigen::Vector3d center = pose.Inverse().translation;
  size_t agree = 0, behind_seen = 0, behind = 0, partial_faces = 0;
  for (size_t f = 0; f < plane_faces; ++f) {
    // Brute force: every sample point (vertices pulled 5% in, and the centroid) reaches the camera.
    int blocked = 0;
    for (int k = 0; k < 4; ++k) {
      Eigen::Vector3d point = geometry.centroids[f];
      if (k < 3) point += 0.95 * (mesh.vertices[mesh.faces[f][k]].cast<double>() - geometry.centroids[f]);
      const Eigen::Vector3d d = (center - point).normalized();
      for (size_t g = plane_faces; g < mesh.faces.size(); ++g) {
        const double t = RayTriangle(point, d, mesh.vertices[mesh.faces[g][0]].cast<double>(),
                                     mesh.vertices[mesh.faces[g][1]].cast<double>(), mesh.vertices[mesh.faces[g][2]].cast<double>());
        if (t > 1e-9) {
          ++blocked;
          break;
        }
      }
    }
    const bool truth = blocked == 0;
    agree += truth == static_cast<bool>(visible[f]);
    if (blocked == 4) {
      ++behind;
      behind_seen += visible[f] + partly[f];
    }
    if (blocked > 0 && blocked < 4) partial_faces += partly[f];
  }
  EXPECT_GT(behind, 4u);
  EXPECT_EQ(behind_seen, 0u) << "faces wholly behind the occluder must not be textured from this view";
  EXPECT_GE(static_cast<double>(agree) / plane_faces, 0.97) << agree << " of " << plane_faces;
  EXPECT_GT(partial_faces, 0u) << "faces at the occluder's border are seen partly";
  for (size_t g = plane_faces; g < mesh.faces.size(); ++g) EXPECT_TRUE(visible[g]) << "occluder face " << g;
}

// Random qualities over a grid: iterated conditional modes never raises the energy, and lowers it.
TEST(ViewSelection, EnergyNeverIncreasesAcrossSweeps) {
  const TriangleMesh mesh = Grid(20, 1.0, 0.0);
  const auto adjacency = FaceAdjacency(mesh);
  size_t interior = 0;
  for (const auto& a : adjacency) interior += a[0] >= 0 && a[1] >= 0 && a[2] >= 0;
  EXPECT_GT(interior, mesh.faces.size() / 2);
  std::mt19937 random(5);
  std::uniform_real_distribution<float> quality(0.f, 1.f);
  FaceObservations observations(mesh.faces.size());
  for (auto& list : observations) {
    for (int v = 0; v < 5; ++v) {
      if (random() % 4 != 0) list.push_back({v, quality(random), Eigen::Vector3f::Zero()});
    }
  }
  const ViewSelection selection = SelectViews(observations, adjacency, 0.4, 50);
  ASSERT_GE(selection.energies.size(), 2u);
  for (size_t i = 1; i < selection.energies.size(); ++i) EXPECT_LE(selection.energies[i], selection.energies[i - 1] + 1e-9);
  EXPECT_LT(selection.energies.back(), selection.energies.front());
  EXPECT_NEAR(selection.energies.back(), SelectionEnergy(observations, adjacency, selection.labels, 0.4), 1e-9);
  for (size_t f = 0; f < observations.size(); ++f) {
    if (observations[f].empty()) EXPECT_EQ(selection.labels[f], -1);
  }
}

struct TexturedScene {
  TriangleMesh mesh;
  std::vector<TextureView> views;
  std::vector<cv::Mat> images;
};

// Textures `scene` with the stage's steps; returns the leveling to inspect.
TexturedMesh TextureScene(const TexturedScene& scene, const TextureOptions& options, double* step_before, double* step_after,
                          std::vector<double>* gains_out = nullptr, ViewSelection* selection_out = nullptr) {
  const FaceGeometry geometry = FaceGeometry::Of(scene.mesh);
  FaceObservations observations(scene.mesh.faces.size());
  for (size_t v = 0; v < scene.views.size(); ++v) {
    std::vector<std::pair<int, FaceObservation>> seen;
    ObserveView(scene.mesh, geometry, scene.views[v].camera, scene.views[v].cam_from_world, scene.images[v], static_cast<int>(v), options, &seen);
    for (const auto& [f, o] : seen) {
      if (!o.partial && !o.hidden && !o.back) observations[f].push_back(o);
    }
  }
  const auto adjacency = FaceAdjacency(scene.mesh);
  const ViewSelection selection = SelectViews(observations, adjacency, options.smoothness, options.max_iterations);
  std::vector<double> gains(scene.views.size(), 1.0);
  if (options.gain_compensation) gains = SolveGains(observations, static_cast<int>(scene.views.size()), options.gain_sigma);
  TexturedMesh out;
  const AtlasLayout layout = LayoutAtlas(scene.mesh, selection.labels, adjacency, scene.views, options, &out);
  SeamLeveling leveling(scene.mesh, selection.labels);
  for (size_t v = 0; v < scene.views.size(); ++v) {
    CopyPatches(layout, static_cast<int>(v), scene.images[v], gains[v], &out);
  }
  leveling.SetColorsFromFaces(observations, gains);
  *step_before = leveling.MeanSeamStep(false);
  if (options.seam_leveling && leveling.Solve(options.leveling_smoothness)) ApplyLeveling(layout, leveling, options.padding, &out);
  *step_after = leveling.MeanSeamStep(options.seam_leveling);
  FillHoles(layout, selection.labels, observations, gains, adjacency, &out);
  if (gains_out) *gains_out = gains;
  if (selection_out) *selection_out = selection;
  return out;
}

// The atlas colour at a point inside face f (barycentric b).
cv::Vec3b AtlasColor(const TexturedMesh& t, int f, const Eigen::Vector3f& b) {
  const cv::Mat& page = t.pages[t.face_page[f]];
  const Eigen::Vector2f uv = (b[0] * t.face_uv[f].row(0) + b[1] * t.face_uv[f].row(1) + b[2] * t.face_uv[f].row(2)).transpose();
  const Eigen::Vector2f texel = TexelFromUv(uv, page.cols, page.rows);
  const int x = std::clamp(static_cast<int>(texel.x()), 0, page.cols - 1), y = std::clamp(static_cast<int>(texel.y()), 0, page.rows - 1);
  return page.at<cv::Vec3b>(y, x);
}

// Two views of a checkerboard plane, one from the left, one from the right: every face comes
// from a view that sees it, and the atlas gives the checkerboard back at points away from its
// edges.
TEST(TextureAtlas, ACheckerboardPlaneTexturedFromTwoViewsComesBack) {
  TexturedScene scene;
  scene.mesh = Grid(12, 1.0, 0.0);
  const Camera camera = TestCamera();
  for (double x : {-1.2, 1.2}) {
    scene.views.push_back({camera, LookAt(Eigen::Vector3d(x, 0.1, 2.6), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY())});
    scene.images.push_back(RenderChecker(camera, scene.views.back().cam_from_world));
  }
  double before = 0, after = 0;
  ViewSelection selection;
  const TexturedMesh t = TextureScene(scene, TextureOptions(), &before, &after, nullptr, &selection);
  EXPECT_EQ(t.Validate(), "");
  std::set<int> used(selection.labels.begin(), selection.labels.end());
  EXPECT_EQ(used.count(-1), 0u) << "every face is seen by a view";
  EXPECT_EQ(used.size(), 2u) << "both views contribute";
  std::mt19937 random(3);
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  size_t tested = 0, close = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const int f = static_cast<int>(random() % t.mesh.faces.size());
    float b1 = unit(random), b2 = unit(random);
    if (b1 + b2 > 1) b1 = 1 - b1, b2 = 1 - b2;
    const Eigen::Vector3f b(1 - b1 - b2, b1, b2);
    const Eigen::Vector3f p = b[0] * t.mesh.vertices[t.mesh.faces[f][0]] + b[1] * t.mesh.vertices[t.mesh.faces[f][1]] +
                              b[2] * t.mesh.vertices[t.mesh.faces[f][2]];
    const double fx = p.x() / 0.25 - std::floor(p.x() / 0.25), fy = p.y() / 0.25 - std::floor(p.y() / 0.25);
    if (std::min({fx, 1 - fx, fy, 1 - fy}) < 0.2) continue;  // near a checker edge: blur of resampling
    ++tested;
    const cv::Vec3b want = Checker(p.x(), p.y()), got = AtlasColor(t, f, b);
    close += std::abs(want[0] - got[0]) + std::abs(want[1] - got[1]) + std::abs(want[2] - got[2]) <= 30;
  }
  ASSERT_GT(tested, 500u);
  EXPECT_GE(static_cast<double>(close) / tested, 0.98) << close << " of " << tested;
}

// One view 35% darker: the gains bring it back, and seam leveling at least halves the colour
// step across the patch borders against no leveling.
TEST(ColorLeveling, AnExposureDifferenceIsLeveledAcrossSeams) {
  TexturedScene scene;
  scene.mesh = Grid(12, 1.0, 0.0);
  const Camera camera = TestCamera();
  const double exposure[2] = {1.0, 0.65};
  for (int v = 0; v < 2; ++v) {
    scene.views.push_back({camera, LookAt(Eigen::Vector3d(v ? 1.2 : -1.2, 0.1, 2.6), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY())});
    scene.images.push_back(RenderChecker(camera, scene.views.back().cam_from_world, exposure[v]));
  }
  const auto adjacency = FaceAdjacency(scene.mesh);
  TextureOptions raw;
  raw.gain_compensation = false;
  raw.seam_leveling = false;
  double raw_before = 0, raw_after = 0;
  ViewSelection selection;
  const double raw_atlas = SeamStepInAtlas(TextureScene(scene, raw, &raw_before, &raw_after, nullptr, &selection), selection.labels, adjacency);
  TextureOptions leveled;
  leveled.gain_compensation = false;
  double before = 0, after = 0;
  const double leveled_atlas = SeamStepInAtlas(TextureScene(scene, leveled, &before, &after, nullptr, &selection), selection.labels, adjacency);
  EXPECT_GT(raw_after, 10.0) << "the exposure difference shows at the seams";
  EXPECT_LE(after, 0.5 * raw_after) << "leveled " << after << " against " << raw_after;
  // Measured on the atlas itself, across the seam edges: the gains and the leveling together
  // (additive offsets alone cannot undo a gain on a two-colour texture: the step differs by
  // colour, and the offsets are linear along an edge).
  const double full_atlas = SeamStepInAtlas(TextureScene(scene, TextureOptions(), &before, &after, nullptr, &selection), selection.labels, adjacency);
  EXPECT_GT(raw_atlas, 10.0);
  EXPECT_LT(leveled_atlas, raw_atlas);
  EXPECT_LE(full_atlas, 0.5 * raw_atlas) << "gains and leveling " << full_atlas << ", leveling alone " << leveled_atlas << ", neither " << raw_atlas;
  std::vector<double> gains;
  TextureScene(scene, TextureOptions(), &before, &after, &gains);
  EXPECT_NEAR(gains[1] / gains[0], 1.0 / 0.65, 0.08);
  EXPECT_LE(after, 0.5 * raw_after);
}

// A face no view sees (hidden under a small square here) is filled from its neighbours'
// colours, and counted.
TEST(TextureAtlas, UnseenFacesAreFilledFromTheirNeighbours) {
  TexturedScene scene;
  scene.mesh = Grid(4, 1.0, 0.0);
  // A square 0.5 above the plane hides face 5 (x in [0, 0.5], y in [-1, -0.5]) from the camera.
  const int base = static_cast<int>(scene.mesh.vertices.size());
  for (const auto& [x, y] : std::vector<std::pair<float, float>>{{-0.05f, -0.85f}, {0.45f, -0.85f}, {-0.05f, -0.33f}, {0.45f, -0.33f}}) {
    scene.mesh.vertices.emplace_back(x, y, 0.5f);
  }
  scene.mesh.faces.emplace_back(base, base + 1, base + 3);
  scene.mesh.faces.emplace_back(base, base + 3, base + 2);
  const Camera camera = TestCamera();
  scene.views.push_back({camera, LookAt(Eigen::Vector3d(0, 0.1, 2.6), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY())});
  scene.images.push_back(cv::Mat(camera.height, camera.width, CV_8UC3, cv::Scalar(10, 100, 200)));
  double before = 0, after = 0;
  ViewSelection selection;
  const TexturedMesh t = TextureScene(scene, TextureOptions(), &before, &after, nullptr, &selection);
  EXPECT_EQ(selection.labels[5], -1);
  const cv::Vec3b c = AtlasColor(t, 5, Eigen::Vector3f::Constant(1.f / 3));
  EXPECT_NEAR(c[0], 10, 3);
  EXPECT_NEAR(c[1], 100, 3);
  EXPECT_NEAR(c[2], 200, 3);
  EXPECT_EQ(t.Validate(), "");
}

// A face wound the wrong way is seen from its back by every view: it is turned, and keeps its views.
TEST(FaceVisibility, FacesSeenFromTheirBackAreTurned) {
  TriangleMesh mesh = Grid(2, 1.0, 0.0);
  std::swap(mesh.faces[3][1], mesh.faces[3][2]);
  const Camera camera = TestCamera();
  const Rigid3d pose = LookAt(Eigen::Vector3d(0.2, 0.1, 2.6), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY());
  FaceGeometry geometry = FaceGeometry::Of(mesh);
  std::vector<std::pair<int, FaceObservation>> seen;
  ObserveView(mesh, geometry, camera, pose, RenderChecker(camera, pose), 0, TextureOptions(), &seen);
  FaceObservations observations(mesh.faces.size());
  for (const auto& [f, o] : seen) observations[f].push_back(o);
  ASSERT_EQ(observations[3].size(), 1u);
  EXPECT_TRUE(observations[3][0].back);
  EXPECT_EQ(OrientFaces(&observations, &mesh, &geometry), 1u);
  EXPECT_GT(geometry.normals[3].z(), 0.9);
  EXPECT_EQ(FaceGeometry::Of(mesh).normals[3].z(), geometry.normals[3].z());
  ASSERT_EQ(observations[3].size(), 1u);
  EXPECT_FALSE(observations[3][0].back);
}

// A view that shows a face as background (dark) while the others agree is dropped for it.
TEST(FaceVisibility, AViewDisagreeingWithTheOthersIsDropped) {
  FaceObservations observations(1);
  for (int v = 0; v < 4; ++v) observations[0].push_back({v, 1.f, Eigen::Vector3f::Constant(v == 2 ? 5.f : 150.f + v)});
  EXPECT_EQ(RemoveInconsistentViews(0.25, &observations), 1u);
  ASSERT_EQ(observations[0].size(), 3u);
  for (const FaceObservation& o : observations[0]) EXPECT_NE(o.view, 2);
}

// View maps: each face lists the views that see it; a view's own direction finds it again.
TEST(FaceViewMaps, ADirectionOfAVisibleViewBlendsThatViewAlone) {
  TexturedScene scene;
  scene.mesh = Grid(4, 1.0, 0.0);
  const Camera camera = TestCamera();
  std::vector<Eigen::Vector3d> centers;
  for (double x : {-1.5, 0.0, 1.5}) {
    centers.emplace_back(x, 0.2, 2.6);
    scene.views.push_back({camera, LookAt(centers.back(), Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitY())});
    scene.images.push_back(RenderChecker(camera, scene.views.back().cam_from_world));
  }
  const FaceGeometry geometry = FaceGeometry::Of(scene.mesh);
  FaceObservations observations(scene.mesh.faces.size());
  for (size_t v = 0; v < scene.views.size(); ++v) {
    std::vector<std::pair<int, FaceObservation>> seen;
    ObserveView(scene.mesh, geometry, camera, scene.views[v].cam_from_world, scene.images[v], static_cast<int>(v), TextureOptions(), &seen);
    for (const auto& [f, o] : seen) observations[f].push_back(o);
  }
  const ViewMaps maps = BuildViewMaps(geometry, observations, centers, {"a", "b", "c"}, 64);
  ASSERT_EQ(maps.faces.size(), scene.mesh.faces.size());
  const int f = 12;
  ASSERT_EQ(maps.faces[f].views.size(), 3u);
  for (int v = 0; v < 3; ++v) {
    const ViewBlend blend = BlendFor(maps, f, FaceFrame(geometry.normals[f]), (centers[v] - geometry.centroids[f]).normalized());
    float weight = 0;
    for (int k = 0; k < blend.count; ++k) weight += blend.views[k] == v ? blend.weights[k] : 0.f;
    EXPECT_GT(weight, 0.9f) << "view " << v;
  }
}

}  // namespace
}  // namespace ibmr
