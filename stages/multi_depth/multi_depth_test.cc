// Tests of multi_depth (seed 000 lines 3847-3894, 5812-5950): options, neighbour choice, and a
// small analytic scene (a sphere partly hidden by a smaller one, 16 ring views at 160x120) whose
// true depth maps are corrupted with noise, outliers, floating blobs and holes; the consistent maps
// must match the truth within 1% on >= 90% of the pixels with true depth. One adapter run on a
// temporary workspace.
#include "stages/multi_depth/multi_depth.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <limits>
#include <random>
#include <sstream>

#include <spdlog/sinks/ostream_sink.h>
#include <spdlog/spdlog.h>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/view_agreement.h"
#include "stages/multi_depth/geometric_consistency.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_multi_depth(StageRegistry* registry);

namespace {

struct Sphere {
  Eigen::Vector3d center;
  double radius;
};

// Two spheres: the big one at the origin, a small one beside it that hides part of it.
const std::vector<Sphere> kSpheres = {{Eigen::Vector3d(0, 0, 0), 1.0}, {Eigen::Vector3d(1.5, 0.3, 0.2), 0.4}};

// True z depth of each pixel of a camera (ray casting), 0 where the ray misses.
DepthMap RenderDepth(const Camera& camera, const Rigid3d& cam_from_world) {
  DepthMap depth(camera.width, camera.height, 1, 0.f);
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  const Eigen::Vector3d origin = world_from_cam.translation;
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const Eigen::Vector3d ray_cam = camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));  // z = 1
      const Eigen::Vector3d dir = world_from_cam.rotation * ray_cam;
      double best = 1e30;
      for (const Sphere& s : kSpheres) {
        const Eigen::Vector3d oc = origin - s.center;
        const double a = dir.squaredNorm(), b = 2 * oc.dot(dir), c = oc.squaredNorm() - s.radius * s.radius;
        const double disc = b * b - 4 * a * c;
        if (disc < 0) continue;
        const double t = (-b - std::sqrt(disc)) / (2 * a);
        if (t > 0) best = std::min(best, t);
      }
      if (best < 1e30) depth.At(x, y) = static_cast<float>(best);  // t along (x, y, 1) is z
    }
  }
  return depth;
}

struct Scene {
  std::vector<Image> images;
  std::vector<DepthView> truth;
};

Scene MakeScene(int views = 16, int width = 160, int height = 120) {
  Scene scene;
  const Camera camera = Camera::Pinhole(width, height, 150, 150, width / 2.0, height / 2.0);
  for (int i = 0; i < views; ++i) {
    const double angle = 2 * M_PI * i / views;
    const Eigen::Vector3d eye(4 * std::cos(angle), 4 * std::sin(angle), 1.2);
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    image.cam_from_world = LookAt(eye, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ());
    DepthView view;
    view.name = image.name;
    view.camera = camera;
    view.cam_from_world = image.cam_from_world;
    view.depth = RenderDepth(camera, image.cam_from_world);
    scene.images.push_back(image);
    scene.truth.push_back(view);
  }
  return scene;
}

// Noise (relative sigma), outliers (uniform in [0.6, 1.4] x true), holes; a confidence map.
DepthView Corrupt(const DepthView& truth, int seed, double sigma = 0.002, double outliers = 0.08, double holes = 0.03) {
  DepthView view = truth;
  std::mt19937 rng(seed);
  std::normal_distribution<float> noise(0.f, static_cast<float>(sigma));
  std::uniform_real_distribution<float> uniform(0.f, 1.f);
  view.confidence = FloatMap(truth.depth.width, truth.depth.height, 1, 0.f);
  for (size_t i = 0; i < view.depth.data.size(); ++i) {
    float& d = view.depth.data[i];
    if (d <= 0) continue;
    const float u = uniform(rng);
    if (u < holes) {
      d = 0;
    } else if (u < holes + outliers) {
      d *= 0.6f + 0.8f * uniform(rng);
      view.confidence.data[i] = 0.3f + 0.5f * uniform(rng);
    } else {
      d *= 1 + noise(rng);
      view.confidence.data[i] = 0.5f + 0.5f * uniform(rng);
    }
  }
  return view;
}

std::vector<const DepthView*> Others(const std::vector<DepthView>& views, size_t key) {
  std::vector<const DepthView*> others;
  for (size_t i = 0; i < views.size(); ++i) {
    if (i != key) others.push_back(&views[i]);
  }
  return others;
}

TEST(MultiDepthOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(MultiDepthOptions().Check(&error)) << error;
}

TEST(MultiDepthOptions, RejectsInvalidRanges) {
  auto expect_error = [](const MultiDepthOptions& options, const std::string& key) {
    std::string error;
    EXPECT_FALSE(options.Check(&error)) << key;
    EXPECT_EQ(error.rfind(key + ":", 0), 0u) << error;
  };
  MultiDepthOptions o;
  o.depth_tolerance = 0;
  expect_error(o, "depth_tolerance");
  o = MultiDepthOptions();
  o.min_consistent_views = 0;
  expect_error(o, "min_consistent_views");
  o = MultiDepthOptions();
  o.max_violation_ratio = -1;
  expect_error(o, "max_violation_ratio");
  o = MultiDepthOptions();
  o.violation_tolerance = 0;
  expect_error(o, "violation_tolerance");
  o = MultiDepthOptions();
  o.min_confidence = 1.5;
  expect_error(o, "min_confidence");
  o = MultiDepthOptions();
  o.max_neighbors = 1;
  o.min_consistent_views = 2;
  expect_error(o, "max_neighbors");
  o = MultiDepthOptions();
  o.max_neighbors = o.min_consistent_views = 2;  // filling could never confirm a pixel
  expect_error(o, "max_neighbors");
  o.fill_from_neighbors = false;
  std::string error;
  EXPECT_TRUE(o.Check(&error)) << error;
  o = MultiDepthOptions();
  o.max_view_angle_deg = 0;
  expect_error(o, "max_view_angle_deg");
  o = MultiDepthOptions();
  o.min_baseline_ratio = 1;
  expect_error(o, "min_baseline_ratio");
  o = MultiDepthOptions();
  o.geometric_sigma = -0.01;
  expect_error(o, "geometric_sigma");
  o.geometric_sigma = 0.6;
  expect_error(o, "geometric_sigma");
  o = MultiDepthOptions();
  o.view_agreement_reference = 1.5;
  expect_error(o, "view_agreement_reference");
  o = MultiDepthOptions();
  o.geometric_sigma = o.view_agreement_reference = 0;  // both off
  EXPECT_TRUE(o.Check(&error)) << error;
}

TEST(GeometricConsistency, MeanGaussianAgreementOfTheNeighboursThatSee) {
  GeometricConsistency none(0.01f);
  EXPECT_FLOAT_EQ(none.Value(), 1.f);  // nothing contradicts
  GeometricConsistency c(0.01f);
  c.Add(0.f);
  c.Add(0.01f);    // one sigma: exp(-1/2)
  c.Add(-0.02f);   // two sigmas, either side: exp(-2)
  EXPECT_EQ(c.seen(), 3);
  EXPECT_NEAR(c.Value(), (1 + std::exp(-0.5) + std::exp(-2.0)) / 3, 1e-6);
}

// The key's median confidence among its kept samples.
float MedianConfidence(const MultiDepthResult& result) {
  std::vector<float> kept;
  for (size_t i = 0; i < result.depth.data.size(); ++i) {
    if (result.depth.data[i] > 0) kept.push_back(result.confidence.data[i]);
  }
  if (kept.empty()) return -1;
  std::nth_element(kept.begin(), kept.begin() + kept.size() / 2, kept.end());
  return kept[kept.size() / 2];
}

// A synthetic pair with a known pose error: the neighbour's depth map is exact, but its camera is
// given `shift` (scene units) farther along its optical axis than the one that rendered it, so it
// measures every key point `shift` nearer than the key's depth puts it: relative disagreement
// -shift / z (z ~ 3 to 4 here, so shift 0.012 is ~0.3%, one geometric_sigma).
MultiDepthResult PairWithPoseError(double shift, const MultiDepthOptions& options, MultiDepthStats* stats = nullptr) {
  const Scene scene = MakeScene(8, 80, 60);
  DepthView neighbour = scene.truth[1];
  neighbour.cam_from_world.translation.z() += shift;
  const MultiDepthResult result = MakeDepthConsistent(scene.truth[0], {&neighbour}, options);
  if (stats) *stats = result.stats;
  return result;
}

TEST(MultiDepth, GeometricConsistencyFallsWithAKnownPoseError) {
  MultiDepthOptions options;
  options.min_consistent_views = 1;
  options.fill_from_neighbors = false;
  options.refine_depth = false;
  options.view_agreement_reference = 0;  // the per-sample factor alone
  options.surface_window = 0;
  // No error: the geometric factor is 1, and so the confidence (confidence maps absent: 1).
  EXPECT_GT(MedianConfidence(PairWithPoseError(0.0, options)), 0.99f);
  // One sigma of disagreement at z ~ 4 (0.012 / 4 = 0.003): factor exp(-1/2) ~ 0.61, confidence
  // its square root (geometric mean with the photometric 1) ~ 0.78; at z ~ 3 lower.
  const float one_sigma = MedianConfidence(PairWithPoseError(0.012, options));
  EXPECT_GT(one_sigma, 0.6f);
  EXPECT_LT(one_sigma, 0.85f);
  // Twice the error: lower still (factor ~ exp(-2)), while still within depth_tolerance (kept).
  const float two_sigma = MedianConfidence(PairWithPoseError(0.024, options));
  EXPECT_GT(two_sigma, 0.f);
  EXPECT_LT(two_sigma, one_sigma - 0.2f);
  // Off: the pose error is invisible to the confidence.
  options.geometric_sigma = 0;
  EXPECT_GT(MedianConfidence(PairWithPoseError(0.024, options)), 0.99f);
}

// With geometric_sigma 0 (off) the confidence is the photometric one itself, not the geometric
// mean with a factor of 1 (its square root, which raised every confidence below 1: commit 91b50b2).
// The pair agrees exactly (no pose error), the key's and the neighbour's photometric confidence are
// 0.36 everywhere: their mean over the key and its one confirming view is 0.36 (0.6 when square-rooted).
TEST(MultiDepth, GeometricConsistencyOffKeepsThePhotometricConfidence) {
  const Scene scene = MakeScene(8, 80, 60);
  DepthView key = scene.truth[0], neighbour = scene.truth[1];
  key.confidence = FloatMap(key.depth.width, key.depth.height, 1, 0.36f);
  neighbour.confidence = FloatMap(neighbour.depth.width, neighbour.depth.height, 1, 0.36f);
  MultiDepthOptions options;
  options.min_consistent_views = 1;
  options.fill_from_neighbors = false;
  options.geometric_sigma = 0;
  options.view_agreement_reference = 0;
  options.surface_window = 0;
  const MultiDepthResult off = MakeDepthConsistent(key, {&neighbour}, options);
  ASSERT_GT(off.stats.kept, 500u);
  EXPECT_NEAR(MedianConfidence(off), 0.36f, 1e-4f);
  for (size_t i = 0; i < off.depth.data.size(); ++i) {
    if (off.depth.data[i] > 0) ASSERT_LE(off.confidence.data[i], 0.36f + 1e-4f) << "pixel " << i;
  }
  // On, with the same exact pair: the geometric factor is about 1, the geometric mean of 0.36 and
  // 1 is 0.6, so the two settings are told apart by this scene.
  options.geometric_sigma = 0.003;
  EXPECT_GT(MedianConfidence(MakeDepthConsistent(key, {&neighbour}, options)), 0.55f);
}

TEST(MultiDepth, ViewAgreementScalesAViewWhoseCameraIsOff) {
  MultiDepthOptions options;
  options.surface_window = 0;  // the view factor alone
  options.min_consistent_views = 1;
  options.fill_from_neighbors = false;
  options.refine_depth = false;
  MultiDepthStats clean, off;
  const float clean_confidence = MedianConfidence(PairWithPoseError(0.0, options, &clean));
  const float off_confidence = MedianConfidence(PairWithPoseError(0.024, options, &off));
  EXPECT_GT(clean.view_agreement, 0.85);  // silhouette pixels disagree across a depth edge
  EXPECT_LT(off.view_agreement, 0.5);
  EXPECT_GT(clean_confidence, 0.99f);  // at least the reference: factor 1
  // The view factor (agreement / 0.8) multiplies the per-sample geometric mean.
  options.view_agreement_reference = 0;
  const float without_view_factor = MedianConfidence(PairWithPoseError(0.024, options));
  EXPECT_NEAR(off_confidence, without_view_factor * off.view_agreement / 0.8, 0.02);
}

// Issue 67's flag on constructed captures: the ring's depth maps come from the true cameras (with
// the usual noise and outliers), but the cameras the stage is given are each turned about their
// own centre by turn_deg[i] degrees about a random axis (a wrong rotation in images.txt). Each
// view's confirmed fraction (ViewConfirmedFraction) against its SelectNeighbors, then FlagViews.
ViewFlagResult FlagRing(const std::vector<double>& turn_deg, unsigned seed, std::vector<double>* figures = nullptr) {
  Scene scene = MakeScene(static_cast<int>(turn_deg.size()), 120, 90);
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<DepthView> views;
  for (size_t i = 0; i < turn_deg.size(); ++i) {
    DepthView view = Corrupt(scene.truth[i], static_cast<int>(i) + 1);
    const Eigen::Vector3d axis(normal(rng), normal(rng), normal(rng));
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(turn_deg[i] * M_PI / 180, axis.normalized()).toRotationMatrix();
    view.cam_from_world = Rigid3d(turn * view.cam_from_world.R(), turn * view.cam_from_world.translation);
    scene.images[i].cam_from_world = view.cam_from_world;
    views.push_back(std::move(view));
  }
  std::vector<const Image*> candidates;
  for (const Image& image : scene.images) candidates.push_back(&image);
  MultiDepthOptions options;
  options.fill_from_neighbors = false;
  std::vector<ViewAgreement> agreements;
  for (size_t i = 0; i < views.size(); ++i) {
    std::vector<const DepthView*> neighbors;
    for (int index : SelectNeighbors(scene.images[i], candidates, options)) neighbors.push_back(&views[index]);
    const MultiDepthResult result = MakeDepthConsistent(views[i], neighbors, options);
    ViewAgreement agreement;
    agreement.name = views[i].name;
    agreement.has_figure = ViewConfirmedFraction(result.stats, 200, &agreement.figure);
    if (figures) figures->push_back(agreement.has_figure ? agreement.figure : -1);
    agreements.push_back(agreement);
  }
  return FlagViews(agreements, /*higher_is_better=*/true, ViewFlagOptions());
}

std::string Describe(const ViewFlagResult& r) {
  std::string s = "median " + std::to_string(r.scores.median) + " scale " + std::to_string(r.scores.scale) + ":";
  for (const ViewAgreement& v : r.views) s += " " + v.name + "=" + std::to_string(v.figure) + "(z " + std::to_string(v.z) + ")";
  return s;
}

TEST(ViewAgreementFlag, OneTurnedCameraIsFlaggedAndNoViewOfTheCleanRing) {
  std::vector<double> turns(16, 0.0);
  const ViewFlagResult clean = FlagRing(turns, 7);
  EXPECT_EQ(clean.scored, 16u);
  EXPECT_TRUE(clean.flagged.empty()) << Describe(clean);
  EXPECT_GT(clean.scores.median, 0.8) << Describe(clean);
  turns[5] = 2.0;
  const ViewFlagResult one = FlagRing(turns, 7);
  ASSERT_EQ(one.flagged.size(), 1u) << Describe(one);
  EXPECT_EQ(one.flagged[0], "v5.png");
  // Its neighbours keep their figure: the median over neighbours ignores the one bad view.
  EXPECT_GT(one.views[4].z, -1.5) << Describe(one);
  EXPECT_GT(one.views[6].z, -1.5) << Describe(one);
}

TEST(ViewAgreementFlag, NoFlagWhenEveryCameraIsEquallyOff) {
  // Every camera turned by 2 degrees (random axes): all views disagree alike; none stands out.
  const ViewFlagResult noisy = FlagRing(std::vector<double>(16, 2.0), 11);
  EXPECT_EQ(noisy.scored, 16u);
  EXPECT_LT(noisy.scores.median, 0.6) << Describe(noisy);  // they do disagree
  EXPECT_TRUE(noisy.flagged.empty()) << Describe(noisy);
}

TEST(SelectNeighbors, ClosestDirectionsFirstAndNoZeroBaseline) {
  Scene scene = MakeScene(8, 32, 24);
  Image twin = scene.images[0];  // same position as view 0 (like templeSR0001 / templeSR0011)
  twin.name = "twin.png";
  std::vector<const Image*> candidates;
  for (const Image& image : scene.images) candidates.push_back(&image);
  candidates.push_back(&twin);
  MultiDepthOptions options;
  options.max_neighbors = 4;
  options.max_view_angle_deg = 100;
  const std::vector<int> selected = SelectNeighbors(scene.images[0], candidates, options);
  ASSERT_EQ(selected.size(), 4u);
  // Ring of 8: views 1 and 7 are 45 degrees away, 2 and 6 are 90 degrees away.
  std::set<std::string> first_two = {candidates[selected[0]]->name, candidates[selected[1]]->name};
  EXPECT_EQ(first_two, (std::set<std::string>{"v1.png", "v7.png"}));
  for (int index : selected) {
    EXPECT_NE(candidates[index]->name, "twin.png");
    EXPECT_NE(candidates[index]->name, "v0.png");
  }
  options.max_view_angle_deg = 30;  // the cameras' directions differ by >= ~43 degrees
  EXPECT_TRUE(SelectNeighbors(scene.images[0], candidates, options).empty());
}

TEST(MultiDepth, CleanTruthIsKeptAlmostEverywhere) {
  const Scene scene = MakeScene();
  MultiDepthOptions options;
  options.refine_depth = false;
  options.fill_from_neighbors = false;
  const MultiDepthResult result = MakeDepthConsistent(scene.truth[0], Others(scene.truth, 0), options);
  const DepthAccuracy accuracy = CompareDepth(result.depth, scene.truth[0].depth, 1e-6);
  // The small sphere hides part of the big one in some neighbours: visibility keeps those samples;
  // only silhouette pixels (nearest-pixel look-ups across a depth edge) may be lost.
  EXPECT_GT(accuracy.FractionOfTruth(), 0.95);
  EXPECT_EQ(accuracy.within_tolerance, accuracy.estimated);
  EXPECT_LT(result.stats.violated, result.stats.input_samples / 50);
}

TEST(MultiDepth, NoisyMapsBecomeConsistentWithinOnePercent) {
  const Scene scene = MakeScene();
  std::vector<DepthView> noisy;
  for (size_t i = 0; i < scene.truth.size(); ++i) noisy.push_back(Corrupt(scene.truth[i], 100 + i));
  const MultiDepthOptions options;
  DepthAccuracy before, after;
  size_t kept_outliers = 0, outliers = 0;
  for (size_t k = 0; k < noisy.size(); ++k) {
    const MultiDepthResult result = MakeDepthConsistent(noisy[k], Others(noisy, k), options);
    const DepthMap& truth = scene.truth[k].depth;
    const DepthAccuracy b = CompareDepth(noisy[k].depth, truth, 0.01), a = CompareDepth(result.depth, truth, 0.01);
    before.truth_pixels += b.truth_pixels, before.within_tolerance += b.within_tolerance, before.estimated += b.estimated;
    after.truth_pixels += a.truth_pixels, after.within_tolerance += a.within_tolerance, after.estimated += a.estimated;
    for (size_t i = 0; i < truth.data.size(); ++i) {
      if (truth.data[i] > 0 && noisy[k].depth.data[i] > 0 && std::abs(noisy[k].depth.data[i] / truth.data[i] - 1) > 0.05) {
        ++outliers;  // kept as it was, instead of rejected or replaced by a confirmed depth
        kept_outliers += result.depth.data[i] > 0 && std::abs(result.depth.data[i] / truth.data[i] - 1) > 0.05;
      }
    }
    // Output maps: same size, normals unit where depth is kept, confidence in (0, 1].
    ASSERT_EQ(result.normals.channels, 3);
    for (int y = 0; y < truth.height; y += 7) {
      for (int x = 0; x < truth.width; x += 7) {
        if (result.depth.At(x, y) <= 0) continue;
        const Eigen::Vector3f n(result.normals.At(x, y, 0), result.normals.At(x, y, 1), result.normals.At(x, y, 2));
        EXPECT_NEAR(n.norm(), 1.f, 1e-3);
        EXPECT_LT(n.z(), 0.f);  // faces the camera
        EXPECT_GT(result.confidence.At(x, y), 0.f);
        EXPECT_LE(result.confidence.At(x, y), 1.f);
      }
    }
  }
  EXPECT_GE(after.FractionOfTruth(), 0.90) << "before: " << before.FractionOfTruth();
  EXPECT_GT(after.FractionOfEstimated(), 0.97);
  EXPECT_GT(outliers, 1000u);
  EXPECT_LT(kept_outliers, outliers / 25) << kept_outliers << " of " << outliers << " outliers kept";
}

// The surface factor: 1 on a slanted plane, down towards the floor at pixels lifted off it, never
// below the floor, ranking noisy depths by their distance to the plane; radius 0 leaves it alone.
TEST(MultiDepth, SurfaceFactorFallsOffTheLocalPlane) {
  const int w = 40, h = 30;
  DepthMap depth(w, h, 1, 0.f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) depth.At(x, y) = 1.f / (0.5f + 0.004f * x + 0.002f * y);  // a plane: 1/z affine
  FloatMap confidence(w, h, 1, 1.f);
  ApplySurfaceFactor(depth, 3, 2.0, 0.5, &confidence);
  for (float c : confidence.data) ASSERT_NEAR(c, 1.f, 1e-4);
  depth.At(20, 15) *= 1.05f;  // 5% off
  depth.At(10, 10) *= 1.01f;  // 1% off
  std::mt19937 rng(3);
  std::normal_distribution<float> noise(0.f, 0.001f);
  for (float& z : depth.data) z *= 1.f + noise(rng);
  FloatMap noisy(w, h, 1, 1.f);
  ApplySurfaceFactor(depth, 3, 2.0, 0.5, &noisy);
  for (float c : noisy.data) ASSERT_GE(c, 0.5f - 1e-6f);
  EXPECT_LT(noisy.At(20, 15), 0.51f);
  EXPECT_LT(noisy.At(10, 10), noisy.At(30, 25));
  FloatMap off(w, h, 1, 0.7f);
  ApplySurfaceFactor(depth, 0, 2.0, 0.5, &off);
  for (float c : off.data) ASSERT_EQ(c, 0.7f);
}

TEST(MultiDepth, RefinementReducesNoise) {
  const Scene scene = MakeScene();
  std::vector<DepthView> noisy;
  for (size_t i = 0; i < scene.truth.size(); ++i) noisy.push_back(Corrupt(scene.truth[i], 7 + i, 0.003, 0.0, 0.0));
  MultiDepthOptions options;
  options.depth_tolerance = 0.02;
  options.refine_depth = false;
  const MultiDepthResult raw = MakeDepthConsistent(noisy[0], Others(noisy, 0), options);
  options.refine_depth = true;
  const MultiDepthResult refined = MakeDepthConsistent(noisy[0], Others(noisy, 0), options);
  double raw_error = 0, refined_error = 0;
  size_t n = 0;
  const DepthMap& truth = scene.truth[0].depth;
  for (size_t i = 0; i < truth.data.size(); ++i) {
    if (truth.data[i] <= 0 || raw.depth.data[i] <= 0 || refined.depth.data[i] <= 0) continue;
    raw_error += std::pow(raw.depth.data[i] / truth.data[i] - 1, 2);
    refined_error += std::pow(refined.depth.data[i] / truth.data[i] - 1, 2);
    ++n;
  }
  ASSERT_GT(n, 1000u);
  EXPECT_LT(std::sqrt(refined_error / n), 0.7 * std::sqrt(raw_error / n));
}

TEST(MultiDepth, FloatingBlobInFreeSpaceIsRejected) {
  const Scene scene = MakeScene();
  std::vector<DepthView> views = scene.truth;
  // A blob at 95% of the true depth in view 8 (the small sphere is behind the big one there):
  // the neighbours see the sphere behind it.
  const size_t k = 8;
  DepthView& key = views[k];
  size_t blob = 0;
  for (int y = 50; y < 70; ++y) {
    for (int x = 70; x < 90; ++x) {
      if (key.depth.At(x, y) > 0) key.depth.At(x, y) *= 0.95f, ++blob;
    }
  }
  ASSERT_GT(blob, 300u);
  for (const bool fill : {false, true}) {
    MultiDepthOptions options;
    options.min_consistent_views = 1;
    options.fill_from_neighbors = fill;
    const MultiDepthResult result = MakeDepthConsistent(key, Others(views, k), options);
    size_t true_surface = 0;
    for (int y = 50; y < 70; ++y) {
      for (int x = 70; x < 90; ++x) {
        const float d = result.depth.At(x, y), t = scene.truth[k].depth.At(x, y);
        if (fill) {  // the blob is replaced by the surface behind it
          EXPECT_TRUE(d == 0.f || std::abs(d / t - 1) < 0.01f) << x << "," << y << ": " << d << " vs " << t;
          true_surface += d > 0;
        } else {
          EXPECT_EQ(d, 0.f) << x << "," << y;
        }
      }
    }
    EXPECT_GT(result.stats.violated, blob * 9 / 10);
    if (fill) EXPECT_GT(true_surface, blob / 4);  // from the blob's rim inwards, where other views confirm
  }
}

// The fill pass's votes stop early and keep the neighbours' depth differences for the end when
// there are at most 64 neighbours (the stage's max_neighbors range), and add them as they come
// beyond: the same depths, confidences and normals either way. Fifty neighbours that know no depth
// anywhere (they vote nothing, warp nothing) take the same views past 64.
TEST(MultiDepth, FillVotesGiveTheSameMapsWithMoreThan64Neighbours) {
  const Scene scene = MakeScene();
  std::vector<DepthView> views;
  for (size_t i = 0; i < scene.truth.size(); ++i) views.push_back(Corrupt(scene.truth[i], 100 + static_cast<int>(i)));
  const size_t k = 3;
  DepthView blank = views[5];
  blank.depth = DepthMap(blank.depth.width, blank.depth.height, 1, 0.f);
  std::vector<const DepthView*> few = Others(views, k), many = few;
  for (int i = 0; i < 50; ++i) many.push_back(&blank);
  ASSERT_LE(few.size(), 64u);
  ASSERT_GT(many.size(), 64u);
  MultiDepthOptions options;
  options.max_neighbors = 64;
  const MultiDepthResult a = MakeDepthConsistent(views[k], few, options);
  const MultiDepthResult b = MakeDepthConsistent(views[k], many, options);
  EXPECT_GT(a.stats.filled, 100u);  // the fill pass ran
  EXPECT_EQ(a.stats.filled, b.stats.filled);
  EXPECT_EQ(a.depth.data, b.depth.data);
  EXPECT_EQ(a.confidence.data, b.confidence.data);
  EXPECT_EQ(a.normals.data, b.normals.data);
}

// Neighbours whose depths lie 2% behind the key's surface: past the agreement tolerance (1%), but
// free space only when the violation tolerance is below 2%.
TEST(MultiDepth, SmallDisagreementIsNotFreeSpace) {
  const Scene scene = MakeScene();
  std::vector<DepthView> views = scene.truth;
  for (size_t i = 1; i < views.size(); ++i) {
    for (float& d : views[i].depth.data) d *= 1.02f;
  }
  size_t samples = 0;
  for (const float d : views[0].depth.data) samples += d > 0;
  MultiDepthOptions options;
  options.fill_from_neighbors = false;
  options.violation_tolerance = 0.01;
  const MultiDepthResult strict = MakeDepthConsistent(views[0], Others(views, 0), options);
  EXPECT_GT(strict.stats.violated, samples * 9 / 10);
  options.violation_tolerance = 0.03;
  const MultiDepthResult lenient = MakeDepthConsistent(views[0], Others(views, 0), options);
  EXPECT_LT(lenient.stats.violated, samples / 10);  // silhouettes: the scaled maps differ in shape there
  EXPECT_GT(lenient.stats.unconfirmed, samples * 8 / 10);  // nor do they confirm
}

TEST(MultiDepth, LowConfidenceSamplesAreDropped) {
  const Scene scene = MakeScene();
  std::vector<DepthView> views = scene.truth;
  DepthView& key = views[0];
  key.confidence = FloatMap(key.depth.width, key.depth.height, 1, 1.f);
  for (int y = 0; y < key.depth.height / 2; ++y) {
    for (int x = 0; x < key.depth.width; ++x) key.confidence.At(x, y) = 0.02f;  // "untextured" top half
  }
  const MultiDepthResult result = MakeDepthConsistent(key, Others(views, 0), MultiDepthOptions());
  for (int y = 0; y < key.depth.height / 2; ++y) {  // the low-confidence samples, not refilled
    for (int x = 0; x < key.depth.width; ++x) {
      if (key.depth.At(x, y) > 0) ASSERT_EQ(result.depth.At(x, y), 0.f);
    }
  }
  EXPECT_GT(result.stats.low_confidence, 1000u);
  EXPECT_GT(result.stats.kept, 1000u);
}

// A confidence that is not a number counts as 0: such samples are dropped as low, neither kept nor
// confirming others, and no NaN reaches the output confidence (NaN passed the clamp and every
// `< min_confidence` test).
TEST(MultiDepth, NotANumberConfidenceCountsAsZero) {
  const Scene scene = MakeScene();
  std::vector<DepthView> views = scene.truth;
  for (DepthView& view : views) {
    view.confidence = FloatMap(view.depth.width, view.depth.height, 1, std::numeric_limits<float>::quiet_NaN());
  }
  const MultiDepthResult result = MakeDepthConsistent(views[0], Others(views, 0), MultiDepthOptions());
  EXPECT_EQ(result.stats.kept, 0u);
  EXPECT_GT(result.stats.low_confidence, 1000u);
  for (const float c : result.confidence.data) ASSERT_FALSE(std::isnan(c));
}

// With min_confidence 0, samples of confidence 0 everywhere are kept (and filled in) with no weight
// to refine by: they keep their own depth, not 0/0.
TEST(MultiDepth, ZeroConfidenceEverywhereGivesFiniteDepths) {
  const Scene scene = MakeScene();
  std::vector<DepthView> views = scene.truth;
  for (DepthView& view : views) view.confidence = FloatMap(view.depth.width, view.depth.height, 1, 0.f);
  MultiDepthOptions options;
  options.min_confidence = 0;
  const MultiDepthResult result = MakeDepthConsistent(views[0], Others(views, 0), options);
  EXPECT_GT(result.stats.kept, 1000u);
  for (const float d : result.depth.data) ASSERT_TRUE(std::isfinite(d));
  const DepthAccuracy accuracy = CompareDepth(result.depth, scene.truth[0].depth, 0.01);
  EXPECT_GT(accuracy.within_tolerance, 0.995 * accuracy.estimated);  // the filled ones warped in
}

TEST(MultiDepth, CompareDepthSamplesTruthAtLowerResolution) {
  DepthMap truth(4, 4, 1, 2.f), half(2, 2, 1, 2.01f);
  half.At(1, 1) = 0;
  const DepthAccuracy a = CompareDepth(half, truth, 0.01);
  EXPECT_EQ(a.truth_pixels, 4u);
  EXPECT_EQ(a.estimated, 3u);
  EXPECT_EQ(a.within_tolerance, 3u);
}

// Writes a workspace with the scene's cameras, noisy photometric maps and true depth.
std::string MakeWorkspace(const Scene& scene, const std::string& tag) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_multi_depth_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(root);
  Workspace workspace(root.string());
  SparseModel model;
  model.cameras[1] = scene.truth[0].camera;
  for (const Image& image : scene.images) model.images[image.image_id] = image;
  WriteSparseModelText(workspace.SparseDir(), model);
  for (size_t i = 0; i < scene.truth.size(); ++i) {
    const DepthView noisy = Corrupt(scene.truth[i], 50 + i);
    WriteColmapArray(workspace.DepthMapPath(noisy.name, "photometric"), noisy.depth);
    WriteColmapArray(workspace.Path("dense/stereo/confidence_maps/" + noisy.name + ".photometric.bin"), noisy.confidence);
    WriteColmapArray(workspace.GroundTruthDepthPath(noisy.name), scene.truth[i].depth);
  }
  return root.string();
}

StageContext MakeContext(const std::string& root, const Stage& stage, NullProgress* progress) {
  StageContext context;
  context.workspace = Workspace(root);
  context.role = stage.Role();
  context.progress = progress;
  for (const ParamSpec& spec : stage.Parameters()) {
    if (spec.type == ParamType::kInt) context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
    if (spec.type == ParamType::kDouble) context.params.Set(spec.key, std::stod(spec.default_yaml));
    if (spec.type == ParamType::kBool) context.params.Set(spec.key, spec.default_yaml == "true");
  }
  return context;
}

TEST(MultiDepthStage, RunsOnAWorkspaceAndRecordsAccuracy) {
  const Scene scene = MakeScene();
  const std::string root = MakeWorkspace(scene, "adapter");
  StageRegistry registry;
  RegisterStage_multi_depth(&registry);
  const Stage* stage = registry.Find("multi_depth");
  ASSERT_NE(stage, nullptr);
  NullProgress progress;
  StageContext context = MakeContext(root, *stage, &progress);
  context.heldout_images = {"v3.png"};
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  const std::vector<std::string> outputs = stage->Outputs(context);
  EXPECT_EQ(outputs.size(), 3u * 15u + 2);  // the held-out view gets no map; fusion.cfg, view_agreement.json
  stage->Run(context);
  for (const std::string& output : outputs) EXPECT_TRUE(fs::exists(context.workspace.Path(output))) << output;
  EXPECT_FALSE(fs::exists(context.workspace.DepthMapPath("v3.png", "geometric")));
  const DepthMap depth = ReadColmapArray(context.workspace.DepthMapPath("v0.png", "geometric"));
  EXPECT_EQ(depth.width, 160);
  EXPECT_GE(context.metrics["geometric_within_1pct_of_textured"].get<double>(), 0.9) << context.metrics.dump();
  EXPECT_GT(context.metrics["kept_fraction"].get<double>(), 0.8);
  // Issue 67: every view scored, none flagged on this clean capture; the file lists them all.
  EXPECT_EQ(context.metrics["views_scored"].get<size_t>(), 15u) << context.metrics.dump();
  EXPECT_TRUE(context.metrics["views_flagged"].empty()) << context.metrics.dump();
  EXPECT_EQ(context.metrics["view_confirmed_fraction"].size(), 15u);
  EXPECT_TRUE(ReadFlaggedViews(context.workspace.ViewAgreementPath()).empty());
  const nlohmann::json agreement = nlohmann::json::parse(ReadFile(context.workspace.ViewAgreementPath()));
  EXPECT_EQ(agreement["views"].size(), 15u);
  // Bad parameter and missing input give messages naming the key / file.
  Params bad = context.params;
  bad.Set("depth_tolerance", 0.0);
  const auto error = stage->CheckParams(bad);
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ(error->key, "depth_tolerance");
  fs::remove(context.workspace.DepthMapPath("v5.png", "photometric"));
  try {
    stage->Run(context);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("v5.png.photometric.bin"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("plane_sweep"), std::string::npos) << e.what();
  }
  fs::remove_all(root);
}

// Issue 67 through the adapter: one camera of the workspace's sparse/ turned by 2 degrees (its
// depth map rendered from the true one): the record, the file and the log's warning name it.
TEST(MultiDepthStage, FlagsAViewWhoseCameraIsTurnedAndWarns) {
  Scene scene = MakeScene(16, 120, 90);
  const std::string root = MakeWorkspace(scene, "turned");
  Image& turned = scene.images[9];
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(2.0 * M_PI / 180, Eigen::Vector3d(0.6, 0.8, 0).normalized()).toRotationMatrix();
  turned.cam_from_world = Rigid3d(turn * turned.cam_from_world.R(), turn * turned.cam_from_world.translation);
  SparseModel model;
  model.cameras[1] = scene.truth[0].camera;
  for (const Image& image : scene.images) model.images[image.image_id] = image;
  WriteSparseModelText(Workspace(root).SparseDir(), model);
  StageRegistry registry;
  RegisterStage_multi_depth(&registry);
  const Stage* stage = registry.Find("multi_depth");
  NullProgress progress;
  StageContext context = MakeContext(root, *stage, &progress);
  std::ostringstream log;
  const auto previous = spdlog::default_logger();
  spdlog::set_default_logger(std::make_shared<spdlog::logger>("test", std::make_shared<spdlog::sinks::ostream_sink_mt>(log)));
  stage->Run(context);
  spdlog::set_default_logger(previous);
  EXPECT_EQ(context.metrics["views_flagged"], nlohmann::json::array({"v9.png"})) << context.metrics.dump();
  EXPECT_LT(context.metrics["view_confirmed_z"]["v9.png"].get<double>(), -3.5);
  EXPECT_EQ(ReadFlaggedViews(context.workspace.ViewAgreementPath()), std::vector<std::string>{"v9.png"});
  EXPECT_NE(log.str().find("[warning] [multi_depth] 1 view(s) disagree with the others"), std::string::npos) << log.str();
  EXPECT_NE(log.str().find("v9.png ("), std::string::npos) << log.str();
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
