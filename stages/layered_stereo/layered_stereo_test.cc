// Tests of the multi-view layered stereo (layers.h) and of the layered sprites' compositing
// (pipeline/core/layered_sprites.h): a synthetic scene of two textured planes seen by five views.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <filesystem>

#include "pipeline/core/layered_sprites.h"
#include "pipeline/core/rasterizer.h"
#include "stages/layered_stereo/layers.h"

namespace ibmr {
namespace {

constexpr int kWidth = 160, kHeight = 120;

// Background: the plane z = 4 (normal -z toward the cameras); foreground: a square on the slanted
// plane through (0, 0, 2.5) with normal (0.2, 0, -1) normalised, covering |x|, |y| < 0.5.
TriangleMesh Scene() {
  TriangleMesh mesh;
  mesh.vertices = {{-6, -6, 4}, {6, -6, 4}, {6, 6, 4}, {-6, 6, 4}};
  mesh.faces = {{0, 1, 2}, {0, 2, 3}};
  auto front_z = [](float x) { return 2.5f + 0.2f * x; };
  for (const auto& [x, y] : std::vector<std::pair<float, float>>{{-0.5f, -0.5f}, {0.5f, -0.5f}, {0.5f, 0.5f}, {-0.5f, 0.5f}}) {
    mesh.vertices.emplace_back(x, y, front_z(x));
  }
  mesh.faces.emplace_back(4, 5, 6);
  mesh.faces.emplace_back(4, 6, 7);
  return mesh;
}

WorldPlane TrueBackground() { return {Eigen::Vector3d(0, 0, 1), 4.0, 0}; }
WorldPlane TrueForeground() {
  const Eigen::Vector3d n = Eigen::Vector3d(-0.2, 0, 1).normalized();  // z - 0.2 x = 2.5
  return {n, 2.5 / Eigen::Vector3d(-0.2, 0, 1).norm(), 0};
}

// A texture with detail at several scales, a function of the world point.
cv::Vec3b Texture(const Eigen::Vector3d& p) {
  const double u = p.x() * 9.1, v = p.y() * 8.3;
  auto hash = [](int a, int b) { return static_cast<uint8_t>(((a * 73856093) ^ (b * 19349663)) >> 7); };
  const int cu = static_cast<int>(std::floor(u)), cv = static_cast<int>(std::floor(v));
  const bool front = p.z() < 3.5;
  return cv::Vec3b(hash(cu, cv), static_cast<uint8_t>(128 + 100 * std::sin(3 * u) * std::cos(2 * v)),
                   static_cast<uint8_t>(front ? 220 : 40 + hash(cv, cu) / 4));
}

LayerView View(const std::string& name, double x) {
  LayerView view;
  view.name = name;
  view.camera = Camera::Pinhole(kWidth, kHeight, 120, 120, kWidth / 2.0, kHeight / 2.0);
  view.cam_from_world = Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-x, 0, 0));  // centre (x, 0, 0), looking +z
  const RasterResult raster = Rasterize(Scene(), view.camera, view.cam_from_world);
  view.image = cv::Mat(kHeight, kWidth, CV_8UC3, cv::Scalar::all(0));
  view.depth = cv::Mat(kHeight, kWidth, CV_32F, cv::Scalar::all(0));
  for (int y = 0; y < kHeight; ++y) {
    for (int u = 0; u < kWidth; ++u) {
      const float z = raster.depth.At(u, y);
      if (!(z > 0)) continue;
      const Eigen::Vector3d p = Eigen::Vector3d(x, 0, 0) + z * view.camera.CamFromImg(Eigen::Vector2d(u + 0.5, y + 0.5));
      view.image.at<cv::Vec3b>(y, u) = Texture(p);
      view.depth.at<float>(y, u) = z;
    }
  }
  return view;
}

double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(std::abs(a.normalized().dot(b.normalized())), 0.0, 1.0)) * 180 / M_PI;
}

// The found plane nearest (in angle, then offset) to `truth`, sign-aligned.
WorldPlane Matching(const std::vector<WorldPlane>& planes, const WorldPlane& truth) {
  WorldPlane best;
  double best_score = 1e9;
  for (WorldPlane p : planes) {
    if (p.normal.dot(truth.normal) < 0) p.normal = -p.normal, p.offset = -p.offset;
    const double score = AngleDeg(p.normal, truth.normal) + 100 * std::abs(p.offset - truth.offset) / truth.offset;
    if (score < best_score) best_score = score, best = p;
  }
  return best;
}

TEST(LayeredOptions, DefaultsAreValidAndEachRangeIsChecked) {
  std::string error;
  EXPECT_TRUE(LayeredOptions().Check(&error)) << error;
  const std::vector<std::pair<std::string, std::function<void(LayeredOptions*)>>> cases = {
      {"max_layers", [](LayeredOptions* o) { o->max_layers = 0; }},
      {"plane_tolerance", [](LayeredOptions* o) { o->plane_tolerance = 0; }},
      {"min_layer_fraction", [](LayeredOptions* o) { o->min_layer_fraction = 1; }},
      {"ransac_iterations", [](LayeredOptions* o) { o->ransac_iterations = 5; }},
      {"sample_step", [](LayeredOptions* o) { o->sample_step = 0; }},
      {"edge_margin_px", [](LayeredOptions* o) { o->edge_margin_px = -1; }},
      {"edge_margin_px", [](LayeredOptions* o) { o->edge_margin_px = 65; }},
      {"max_residual", [](LayeredOptions* o) { o->max_residual = -0.1; }},
      {"depth_weight", [](LayeredOptions* o) { o->depth_weight = NAN; }},
      {"smoothness", [](LayeredOptions* o) { o->smoothness = -1; }},
      {"icm_sweeps", [](LayeredOptions* o) { o->icm_sweeps = 101; }},
      {"max_cost", [](LayeredOptions* o) { o->max_cost = 0; }},
      {"extend_px", [](LayeredOptions* o) { o->extend_px = -1; }},
      {"count_tolerance", [](LayeredOptions* o) { o->count_tolerance = 2; }},
      {"choose_count", [](LayeredOptions* o) { o->choose_count = 3; }},
      {"selection_scale", [](LayeredOptions* o) { o->selection_scale = 0; }},
      {"photometric_refinement", [](LayeredOptions* o) { o->photometric_refinement = 2; }},
      {"residual_steps", [](LayeredOptions* o) { o->residual_steps = 4; }},
      {"residual_steps", [](LayeredOptions* o) { o->residual_steps = 1; }},
      {"residual_steps", [](LayeredOptions* o) { o->residual_steps = 131; }},
  };
  for (const auto& [key, breaks] : cases) {
    LayeredOptions options;
    breaks(&options);
    EXPECT_FALSE(options.Check(&error)) << key;
    EXPECT_EQ(error.substr(0, error.find(':')), key) << error;
  }
}

class TwoPlanes : public ::testing::Test {
 protected:
  void SetUp() override {
    reference = View("ref", 0);
    for (const double x : {-0.4, -0.2, 0.2, 0.4}) neighbours.push_back(View("n" + std::to_string(x), x));
    for (const LayerView& n : neighbours) pointers.push_back(&n);
  }
  LayerView reference;
  std::vector<LayerView> neighbours;
  std::vector<const LayerView*> pointers;
};

TEST_F(TwoPlanes, BothPlanesAndTheirCountAreRecovered) {
  const LayeredResult result = ReconstructLayers(reference, pointers, LayeredOptions());
  ASSERT_GE(result.planes.size(), 2u);
  for (const WorldPlane& truth : {TrueBackground(), TrueForeground()}) {
    const WorldPlane found = Matching(result.planes, truth);
    EXPECT_LT(AngleDeg(found.normal, truth.normal), 1.0) << truth.normal.transpose();
    EXPECT_LT(std::abs(found.offset - truth.offset), 0.01 * truth.offset) << truth.offset;
  }
  EXPECT_EQ(result.curve.chosen, 2) << nlohmann::json(result.curve.rms_error).dump();
  ASSERT_EQ(result.layers.layers.size(), 2u);
  // Back to front from the reference: the background (offset 4) first.
  EXPECT_NEAR(std::abs(result.layers.layers[0].offset), 4.0, 0.04);
}

// The combined depth map keeps the outline where the assignment put it: a sprite's 1-pixel seam
// over its neighbour's pixels (there against cracks in novel views) does not push the nearer
// plane's depth out over the farther one.
TEST_F(TwoPlanes, TheCombinedDepthDoesNotGrowTheForegroundBySeams) {
  LayeredOptions options;
  options.choose_count = 0;
  const LayeredResult result = ReconstructLayers(reference, pointers, options);
  const cv::Mat depth = CombinedDepth(result.layers);
  size_t ring = 0, ring_background = 0;  // true background pixels next to the foreground
  for (int y = 1; y + 1 < kHeight; ++y) {
    for (int x = 1; x + 1 < kWidth; ++x) {
      if (reference.depth.at<float>(y, x) < 3.5f) continue;
      bool next_to_front = false;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) next_to_front |= reference.depth.at<float>(y + dy, x + dx) < 3.5f;
      if (!next_to_front) continue;
      ++ring;
      ring_background += depth.at<float>(y, x) >= 3.5f;
    }
  }
  ASSERT_GT(ring, 100u);
  EXPECT_GT(ring_background, 0.9 * ring) << ring_background << " of " << ring;
}

TEST_F(TwoPlanes, TheOcclusionBoundaryFollowsTheForegroundsOutline) {
  std::vector<WorldPlane> planes = {TrueBackground(), TrueForeground()};
  // Assignment without depth (the photo-consistency alone must find the outline).
  LayerView no_depth = reference;
  no_depth.depth = cv::Mat(reference.depth.size(), CV_32F, cv::Scalar::all(0));  // a new buffer (a MatExpr would write into the shared one)
  const cv::Mat labels = AssignPixels(no_depth, pointers, planes, LayeredOptions());
  size_t wrong = 0, total = 0, far_wrong = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const bool front = reference.depth.at<float>(y, x) < 3.5f;
      const int label = labels.at<int>(y, x);
      ++total;
      if (label != (front ? 1 : 0)) {
        ++wrong;
        // Is it within 2 pixels of the true outline?
        bool near_edge = false;
        for (int dy = -2; dy <= 2 && !near_edge; ++dy)
          for (int dx = -2; dx <= 2 && !near_edge; ++dx) {
            const int u = std::clamp(x + dx, 0, kWidth - 1), v = std::clamp(y + dy, 0, kHeight - 1);
            near_edge = (reference.depth.at<float>(v, u) < 3.5f) != front;
          }
        far_wrong += !near_edge;
      }
    }
  }
  EXPECT_LT(static_cast<double>(wrong) / total, 0.03);
  EXPECT_LT(static_cast<double>(far_wrong) / total, 0.005);
}

TEST_F(TwoPlanes, TheLayersPredictAHeldOutViewAndAlphaStaysInRange) {
  LayeredOptions options;
  options.choose_count = 0;
  const LayeredResult result = ReconstructLayers(reference, pointers, options);
  const LayerView held_out = View("held_out", 0.3);  // not among the neighbours
  const RgbaImage drawn = CompositeLayers(result.layers, held_out.camera, held_out.cam_from_world);
  double squared = 0;
  size_t covered = 0, covered_seen = 0;
  // The held-out view sees the background 9 pixels (120 * 0.3 / 4) beyond the reference's right
  // edge: no layer can hold that.
  const int seen_columns = kWidth - 10;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const float a = drawn.alpha.at<float>(y, x);
      ASSERT_GE(a, 0.f);
      ASSERT_LE(a, 1.f);
      if (a < 0.99f) continue;
      ++covered;
      covered_seen += x < seen_columns;
      const cv::Vec3f c = drawn.color.at<cv::Vec3f>(y, x);
      const cv::Vec3b t = held_out.image.at<cv::Vec3b>(y, x);
      for (int k = 0; k < 3; ++k) squared += (c[k] - t[k]) * (c[k] - t[k]) / 3;
    }
  }
  ASSERT_GT(covered, static_cast<size_t>(0.5 * kWidth * kHeight));
  const double psnr = 10 * std::log10(255.0 * 255.0 / (squared / covered));
  EXPECT_GT(psnr, 22.0);
  // The extended background covers what the foreground hides in the reference but the held-out
  // view sees (the disocclusion at the foreground's side, 5 pixels wide): no hole there.
  EXPECT_GT(covered_seen, static_cast<size_t>(0.995 * seen_columns * kHeight));
}

// Planes tilted by 1 degree and moved out by 2% return to the truth by photo-consistency alone.
TEST_F(TwoPlanes, PhotometricRefinementReturnsPerturbedPlanes) {
  std::vector<WorldPlane> planes = {TrueBackground(), TrueForeground()};
  const cv::Mat labels = AssignPixels(reference, pointers, planes, LayeredOptions());
  for (WorldPlane& p : planes) {
    p.normal = (p.normal + Eigen::Vector3d(0.015, -0.01, 0)).normalized();
    p.offset *= 1.02;
  }
  RefinePlanesPhotometric(reference, pointers, labels, LayeredOptions(), &planes);
  EXPECT_LT(AngleDeg(planes[0].normal, TrueBackground().normal), 0.1);
  EXPECT_NEAR(planes[0].offset, TrueBackground().offset, 0.001 * TrueBackground().offset);
  // The foreground square is small (48 x 48 pixels), and its outline mixes both planes' colours:
  // only pixels with 2 pixels of the plane around them count, in the reference and where they
  // land. (Counting every pixel whose own depth is not nearer, the square came back 0.55 degrees
  // off; now 0.03.)
  EXPECT_LT(AngleDeg(planes[1].normal, TrueForeground().normal), 0.1);
  EXPECT_NEAR(planes[1].offset, TrueForeground().offset, 0.001 * TrueForeground().offset);
}

// Where the depth map has no value, the residual comes from a plane sweep around the layer's
// plane: with the foreground's plane moved 1.5% too far and the reference's depth cleared, the
// layer's depth (plane + residual) returns to the true depth; without the sweep it stays 1.5% off.
TEST_F(TwoPlanes, TheResidualSweepRecoversDepthOffThePlaneWhereTheDepthMapHasNone) {
  const cv::Mat true_depth = reference.depth.clone();
  WorldPlane moved = TrueForeground();
  moved.offset *= 1.015;
  const std::vector<WorldPlane> planes = {TrueBackground(), moved};
  const cv::Mat labels = AssignPixels(reference, pointers, planes, LayeredOptions());
  reference.depth.setTo(0);
  auto median_error = [&](int steps) {
    LayeredOptions options;
    options.residual_steps = steps;
    const LayerSet set = BuildSprites(reference, pointers, planes, labels, options);
    std::vector<double> errors;
    for (size_t k = 0; k < set.layers.size(); ++k) {
      if (std::abs(set.layers[k].offset - moved.offset) > 1e-9) continue;
      for (int y = 0; y < kHeight; ++y) {
        for (int x = 0; x < kWidth; ++x) {
          const float z = true_depth.at<float>(y, x);
          if (labels.at<int>(y, x) != 1 || !(z > 0) || z > 3.5) continue;  // the foreground's own pixels
          errors.push_back(set.Depth(k, x, y) / z - 1);
        }
      }
    }
    EXPECT_GT(errors.size(), 1000u);
    if (errors.empty()) return 1.0;
    std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
    return errors[errors.size() / 2];
  };
  EXPECT_NEAR(median_error(0), 0.015, 0.002);
  EXPECT_NEAR(median_error(13), 0.0, 0.002);
}

// Two hand-made fronto-parallel layers, red at z = 4 and green at z = 2; seen from the front the
// green one is on top, seen from behind (a camera at z = 6 looking back) the red one is.
TEST(CompositeLayers, OrderIsBackToFrontForAnyDesiredView) {
  LayerSet set;
  set.camera = Camera::Pinhole(40, 40, 40, 40, 20, 20);
  set.cam_from_world = Rigid3d();
  for (const auto& [z, color] : std::vector<std::pair<double, cv::Vec4b>>{{4.0, {0, 0, 255, 255}}, {2.0, {0, 255, 0, 255}}}) {
    SpriteLayer layer;
    layer.normal = Eigen::Vector3d::UnitZ();
    layer.offset = z;
    layer.rgba = cv::Mat(40, 40, CV_8UC4, cv::Scalar(color[0], color[1], color[2], color[3]));
    set.layers.push_back(layer);
  }
  const Camera camera = Camera::Pinhole(20, 20, 10, 10, 10, 10);
  const RgbaImage front = CompositeLayers(set, camera, Rigid3d());
  EXPECT_NEAR(front.color.at<cv::Vec3f>(10, 10)[1], 255.f, 1e-3);  // green
  EXPECT_NEAR(front.color.at<cv::Vec3f>(10, 10)[2], 0.f, 1e-3);
  // From behind: rotate 180 degrees about y, centre at (0, 0, 6).
  const Eigen::Matrix3d r = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Rigid3d behind(r, -(r * Eigen::Vector3d(0, 0, 6)));
  const RgbaImage back = CompositeLayers(set, camera, behind);
  EXPECT_NEAR(back.color.at<cv::Vec3f>(10, 10)[2], 255.f, 1e-3);  // red
  EXPECT_NEAR(back.color.at<cv::Vec3f>(10, 10)[1], 0.f, 1e-3);
  // Half-transparent green in front of red: the "over" operator.
  set.layers[1].rgba.setTo(cv::Scalar(0, 255, 0, 128));
  const RgbaImage mixed = CompositeLayers(set, camera, Rigid3d());
  const float a = 128.f / 255.f;
  EXPECT_NEAR(mixed.color.at<cv::Vec3f>(10, 10)[1], a * 255.f, 0.01);
  EXPECT_NEAR(mixed.color.at<cv::Vec3f>(10, 10)[2], (1 - a) * 255.f, 0.01);
  EXPECT_NEAR(mixed.alpha.at<float>(10, 10), 1.f, 1e-5);
}

// A scratch kept across calls (as the layer count's held-out renders keep one) changes nothing,
// nor does drawing in windows of 16 rows (the smallest) instead of one: sets with more and fewer
// layers, views of other sizes (one of 4 windows, the last short), a sprite with holes, against
// fresh buffers, to the bit.
TEST(CompositeLayers, ReusedScratchAndWindowsOfRowsDrawLikeFreshBuffers) {
  LayerSet set;
  set.camera = Camera::Pinhole(40, 30, 40, 40, 20, 15);
  set.cam_from_world = Rigid3d();
  for (int k = 0; k < 3; ++k) {
    SpriteLayer layer;
    layer.normal = Eigen::Vector3d(0.1 * k, 0, 1).normalized();
    layer.offset = 2.0 + k;
    layer.rgba = cv::Mat(30, 40, CV_8UC4);
    cv::randu(layer.rgba, cv::Scalar::all(0), cv::Scalar::all(256));
    layer.rgba(cv::Rect(5 * k, 3, 10, 8)).setTo(cv::Scalar::all(0));  // a hole: alpha 0
    set.layers.push_back(layer);
  }
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const std::vector<std::pair<Camera, Rigid3d>> views = {{Camera::Pinhole(36, 28, 35, 35, 18, 14), Rigid3d()},
                                                         {Camera::Pinhole(50, 20, 40, 40, 25, 10), Rigid3d(turn, Eigen::Vector3d(0.2, 0, 0))},
                                                         {Camera::Pinhole(36, 28, 35, 35, 18, 14), Rigid3d(turn, Eigen::Vector3d(-0.1, 0.1, 0))},
                                                         {Camera::Pinhole(40, 61, 38, 38, 20, 30), Rigid3d(turn.transpose(), Eigen::Vector3d(0, 0.1, 0))}};
  CompositeScratch scratch, windows;
  windows.window_bytes = 1;  // 16 rows a window
  for (size_t round = 0; round < 2 * views.size(); ++round) {
    LayerSet subset = set;
    subset.layers.resize(1 + round % 3);
    const auto& [camera, pose] = views[round % views.size()];
    const RgbaImage fresh = CompositeLayers(subset, camera, pose);
    const RgbaImage reused = CompositeLayers(subset, camera, pose, kLayerMaxDepthStep, &scratch);
    const RgbaImage windowed = CompositeLayers(subset, camera, pose, kLayerMaxDepthStep, &windows);
    EXPECT_GT(cv::countNonZero(fresh.alpha), 0);
    EXPECT_EQ(cv::norm(fresh.color, reused.color, cv::NORM_INF), 0.0) << "round " << round;
    EXPECT_EQ(cv::norm(fresh.alpha, reused.alpha, cv::NORM_INF), 0.0) << "round " << round;
    EXPECT_EQ(cv::norm(fresh.color, windowed.color, cv::NORM_INF), 0.0) << "round " << round;
    EXPECT_EQ(cv::norm(fresh.alpha, windowed.alpha, cv::NORM_INF), 0.0) << "round " << round;
  }
}

TEST(LayerSetFiles, WrittenAndReadBackAndABrokenOneIsNamed) {
  const std::string folder = (std::filesystem::temp_directory_path() / ("ibmr_layers_" + std::to_string(::getpid()))).string();
  LayerSet set;
  set.image = "a.png";
  set.camera = Camera::Pinhole(8, 6, 10, 11, 4, 3);
  set.cam_from_world = Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX())), Eigen::Vector3d(1, 2, 3));
  SpriteLayer layer;
  layer.normal = Eigen::Vector3d(0, 0.6, 0.8);
  layer.offset = 5;
  layer.rgba = cv::Mat(6, 8, CV_8UC4, cv::Scalar(1, 2, 3, 255));
  layer.residual = cv::Mat(6, 8, CV_32F, cv::Scalar::all(0.25));
  set.layers.push_back(layer);
  WriteLayerSet(folder, set);
  const LayerSet back = ReadLayerSet(folder);
  EXPECT_EQ(back.image, "a.png");
  ASSERT_EQ(back.layers.size(), 1u);
  EXPECT_NEAR(back.layers[0].offset, 5, 1e-12);
  EXPECT_NEAR(back.layers[0].residual.at<float>(2, 3), 0.25f, 1e-7);
  EXPECT_EQ(back.layers[0].rgba.at<cv::Vec4b>(1, 1), cv::Vec4b(1, 2, 3, 255));
  EXPECT_TRUE(back.cam_from_world.rotation.isApprox(set.cam_from_world.rotation, 1e-12));
  EXPECT_NEAR(back.Depth(0, 3, 2), set.Depth(0, 3, 2), 1e-9);
  std::filesystem::remove(folder + "/layer_0.png");
  try {
    ReadLayerSet(folder);
    FAIL() << "a missing sprite must be refused";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("layer_0.png"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(folder);
}

}  // namespace
}  // namespace ibmr
