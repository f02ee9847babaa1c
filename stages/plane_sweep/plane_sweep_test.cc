// Tests of the plane_sweep stage: option checks, two-view stereo on a shifted random texture,
// multi-view sweep on a textured plane (known depth), format of the written maps and one adapter
// run on a tiny synthetic object_ring workspace (depth within 1% of the ground truth).
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/plane_sweep/plane_sweep.h"
#include "stages/plane_sweep/sweep_engine.h"

namespace fs = std::filesystem;

namespace ibmr {

void RegisterStage_synth(StageRegistry* registry);
void RegisterStage_plane_sweep(StageRegistry* registry);

namespace {

cv::Mat RandomTexture(int w, int h, int seed) {
  cv::Mat noise(h / 2, w / 2, CV_8U);
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
  cv::Mat up;
  cv::resize(noise, up, cv::Size(w, h), 0, 0, cv::INTER_LINEAR);
  return up;
}

// Every declared parameter at its declared default.
Params Defaults(const Stage& stage) {
  Params params;
  for (const ParamSpec& spec : stage.Parameters()) {
    std::string v = spec.default_yaml;
    if (v.size() >= 2 && v.front() == '"') v = v.substr(1, v.size() - 2);
    switch (spec.type) {
      case ParamType::kInt: params.Set(spec.key, int64_t{std::stoll(v)}); break;
      case ParamType::kDouble: params.Set(spec.key, std::stod(v)); break;
      case ParamType::kBool: params.Set(spec.key, v == "true"); break;
      case ParamType::kDoubleList: params.Set(spec.key, std::vector<double>{}); break;
      case ParamType::kIntList: params.Set(spec.key, std::vector<int64_t>{}); break;
      case ParamType::kStringList: params.Set(spec.key, std::vector<std::string>{}); break;
      default: params.Set(spec.key, v); break;
    }
  }
  return params;
}

TEST(PlaneSweepOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(PlaneSweepOptions().Check(&error)) << error;
}

TEST(PlaneSweepOptions, InvalidRangesNameTheKey) {
  auto key_of = [](const PlaneSweepOptions& o) {
    std::string error;
    EXPECT_FALSE(o.Check(&error));
    return error.substr(0, error.find(':'));
  };
  PlaneSweepOptions o;
  o.num_planes = 1;
  EXPECT_EQ(key_of(o), "num_planes");
  o = PlaneSweepOptions();
  o.best_k = 5;
  EXPECT_EQ(key_of(o), "best_k");
  o = PlaneSweepOptions();
  o.census_radius_x = 5;
  o.census_radius_y = 5;
  EXPECT_EQ(key_of(o), "census_radius_x");
  o = PlaneSweepOptions();
  o.sgm_paths = 6;
  EXPECT_EQ(key_of(o), "sgm_paths");
  o = PlaneSweepOptions();
  o.p2 = o.p1 - 1;
  EXPECT_EQ(key_of(o), "p2");
  o = PlaneSweepOptions();
  o.cost = MatchCost::kZncc;
  o.window_radius = 0;
  EXPECT_EQ(key_of(o), "window_radius");
  o = PlaneSweepOptions();
  o.confidence_threshold = 1.5;
  EXPECT_EQ(key_of(o), "confidence_threshold");
  o = PlaneSweepOptions();
  o.min_depth = 2;
  o.max_depth = 1;
  EXPECT_EQ(key_of(o), "max_depth");
  o = PlaneSweepOptions();
  o.near_quantile = 0.6;
  EXPECT_EQ(key_of(o), "near_quantile");
}

// A view whose sparse points are 2 on a thin pole 1 unit away and 800 on surfaces 4-10 units away
// (synth's forward-facing scene in small): the default 2% quantile puts the near bound behind the
// pole (it would be swept by no plane); LLFF's 0.1 percentile keeps it in front.
TEST(DepthBoundsFromPoints, TheNearQuantileDecidesWhetherAThinNearOccluderIsSwept) {
  SparseModel model;
  Camera camera = Camera::Pinhole(100, 100, 80, 80, 50, 50);
  camera.camera_id = 1;
  model.cameras[1] = camera;
  Image image;
  image.image_id = 1;
  image.camera_id = 1;
  image.name = "view.png";
  model.images[1] = image;  // identity pose: depth is z
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> uniform(0, 1);
  for (int i = 0; i < 802; ++i) {
    Point3D point;
    const double z = i < 2 ? 1.0 : 4.0 + 6.0 * uniform(rng);
    point.xyz = Eigen::Vector3d((uniform(rng) - 0.5) * z, (uniform(rng) - 0.5) * z, z);
    point.track.push_back({1, i});
    model.points[i + 1] = point;
  }
  double near = 0, far = 0;
  ASSERT_TRUE(DepthBoundsFromPoints(model, model.images[1], 0.1, 0.02, &near, &far));
  EXPECT_GT(near, 3.5);
  EXPECT_NEAR(far, 1.1 * 9.88, 0.3);  // the 98% quantile of 4 + 6 U(0, 1), widened by 10%
  ASSERT_TRUE(DepthBoundsFromPoints(model, model.images[1], 0.1, 0.001, &near, &far));
  EXPECT_NEAR(near, 0.9, 1e-9);
}

// Bad arguments from the C++ API are errors, not reads outside a volume of no disparities.
TEST(StereoPair, RejectsNoDisparitiesAndMismatchedImages) {
  const cv::Mat image = RandomTexture(40, 30, 4);
  EXPECT_THROW(StereoPair(image, image, 0, PlaneSweepOptions()), std::invalid_argument);
  EXPECT_THROW(StereoPair(image, image(cv::Rect(0, 0, 39, 30)), 8, PlaneSweepOptions()), std::invalid_argument);
  EXPECT_THROW(StereoPair(cv::Mat(), cv::Mat(), 8, PlaneSweepOptions()), std::invalid_argument);
}

TEST(StereoPair, RecoversAConstantShift) {
  const int w = 160, h = 120, shift = 7;
  const cv::Mat right = RandomTexture(w + shift, h, 3);
  // left(x) = right(x - shift) ... i.e. the left pixel x matches right pixel x - shift.
  const cv::Mat left = right(cv::Rect(0, 0, w, h)).clone();
  cv::Mat right_view = right(cv::Rect(shift, 0, w, h)).clone();
  for (MatchCost cost : {MatchCost::kCensus, MatchCost::kSad, MatchCost::kZncc}) {
    PlaneSweepOptions options;
    options.cost = cost;
    const StereoPairResult result = StereoPair(left, right_view, 16, options);
    ASSERT_EQ(result.disparity.size(), left.size());
    int good = 0, total = 0;
    for (int y = 4; y < h - 4; ++y)
      for (int x = 20; x < w - 4; ++x, ++total) good += std::fabs(result.disparity.at<float>(y, x) - shift) < 0.5f;
    EXPECT_GT(good, 0.95 * total) << "cost " << static_cast<int>(cost);
    EXPECT_EQ(result.unfilled_fraction, 0.0);
    EXPECT_EQ(result.evaluations, int64_t{16} * w * h);
  }
}

// A reference view of a textured fronto-parallel plane at depth 5 and two neighbours shifted by
// +-0.5 along x (128x96, focal 100); Vertical(): along y instead, and 0.065 along x (epipolar
// lines 7.4 degrees off the columns, correspondences 1.3 pixels off the reference's column).
class TexturedPlane : public ::testing::Test {
 protected:
  static constexpr int w = 128, h = 96;
  static constexpr double depth = 5.0;
  SweepView ref;
  std::vector<SweepView> neighbours;
  void SetUp() override { Build(false); }
  void Vertical() { Build(true); }
  void Build(bool vertical) {
    const Camera camera = Camera::Pinhole(w, h, 100, 100, w / 2.0, h / 2.0);
    ref = SweepView{"ref", RandomTexture(w, h, 7), camera, Rigid3d()};
    neighbours.clear();
    for (double baseline : {-0.5, 0.5}) {
      const Eigen::Vector3d t = vertical ? Eigen::Vector3d(0.13 * baseline, baseline, 0) : Eigen::Vector3d(baseline, 0, 0);
      SweepView v{"n", cv::Mat(), camera, Rigid3d(Eigen::Matrix3d::Identity(), t)};
      // Neighbour pixel = ref pixel + f * baseline / depth along the baseline: warp the texture.
      const double shift = 100 * baseline / depth;
      cv::Mat m = (cv::Mat_<double>(2, 3) << 1, 0, vertical ? 0.13 * shift : shift, 0, 1, vertical ? shift : 0);
      cv::warpAffine(ref.gray, v.gray, m, ref.gray.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
      neighbours.push_back(v);
    }
  }
};

// The sweep finds the textured plane.
TEST_F(TexturedPlane, IsFound) {
  PlaneSweepOptions options;
  options.num_planes = 48;
  options.confidence_threshold = 0;
  const PlaneSweepResult result = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  int good = 0;
  for (float z : result.depth.data) good += std::fabs(z - depth) < 0.01 * depth;
  EXPECT_GT(good, 0.9 * w * h);
  EXPECT_EQ(result.evaluations, int64_t{48} * w * h * 2);
  // Normals of a fronto-parallel plane face the camera.
  EXPECT_NEAR(result.normals.At(w / 2, h / 2, 2), -1.0, 0.05);
  for (float c : result.confidence.data) ASSERT_TRUE(c >= 0 && c <= 1);
}

// A neighbour held upside down (rolled 180 degrees about its axis, as templeRing's templeR0040 is
// against the views beside it) is matched as well as an upright one. With the box window only
// (no semi-global paths to carry a weak signal across a flat plane), codes compared in the two
// images' own raster orders put 8529 of 12288 pixels within 1% of the depth against 12229
// upright; with the half-turned neighbour's bits reversed (sweep_engine.h, ReverseCensusBits),
// 12230.
TEST_F(TexturedPlane, IsFoundFromANeighbourHeldUpsideDown) {
  PlaneSweepOptions options;
  options.num_planes = 48;
  options.confidence_threshold = 0;
  options.aggregation = CostAggregation::kBox;
  auto good_pixels = [&](const std::vector<SweepView>& views) {
    const PlaneSweepResult result = PlaneSweep(ref, views, 3.0, 10.0, options);
    int good = 0;
    for (float z : result.depth.data) good += std::fabs(z - depth) < 0.01 * depth;
    return good;
  };
  const int upright = good_pixels(neighbours);
  const Eigen::Matrix3d half_turn = Eigen::Vector3d(-1, -1, 1).asDiagonal();
  std::vector<SweepView> turned = neighbours;
  for (SweepView& v : turned) {
    cv::rotate(v.gray, v.gray, cv::ROTATE_180);
    v.cam_from_world = Rigid3d(half_turn, half_turn * v.cam_from_world.translation);
    ASSERT_TRUE(sweep::IsHalfTurned(ref.cam_from_world.R(), v.cam_from_world.R()));
  }
  const int found = good_pixels(turned);
  EXPECT_GT(upright, 0.8 * w * h);
  EXPECT_GT(found, 0.98 * upright);
}

// The census codes of an image turned 180 degrees, bits reversed, are the upright image's codes
// at the turned pixels (the clamped borders turn with the image); a quarter turn is not a half turn.
TEST(Census, ReversedBitsOfAHalfTurnedImageAreTheUprightCodes) {
  const cv::Mat image = RandomTexture(41, 29, 11);
  cv::Mat turned;
  cv::rotate(image, turned, cv::ROTATE_180);
  for (auto [rx, ry] : {std::pair{4, 3}, std::pair{1, 1}, std::pair{2, 5}}) {
    const int bits = (2 * rx + 1) * (2 * ry + 1) - 1;
    const std::vector<uint64_t> upright = sweep::CensusTransform(image, rx, ry);
    const std::vector<uint64_t> reversed = sweep::ReverseCensusBits(sweep::CensusTransform(turned, rx, ry), bits);
    for (int y = 0; y < image.rows; ++y) {
      for (int x = 0; x < image.cols; ++x) {
        ASSERT_EQ(reversed[static_cast<size_t>(image.rows - 1 - y) * image.cols + (image.cols - 1 - x)],
                  upright[static_cast<size_t>(y) * image.cols + x])
            << "radii " << rx << "," << ry << " pixel " << x << "," << y;
      }
    }
  }
  EXPECT_THROW(sweep::ReverseCensusBits({1}, 65), std::invalid_argument);
  const Eigen::Matrix3d quarter = Eigen::AngleAxisd(M_PI / 2 - 0.01, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Eigen::Matrix3d beyond = Eigen::AngleAxisd(M_PI / 2 + 0.01, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  EXPECT_FALSE(sweep::IsHalfTurned(Eigen::Matrix3d::Identity(), quarter));
  EXPECT_TRUE(sweep::IsHalfTurned(Eigen::Matrix3d::Identity(), beyond));
}

// The peak ratio lowers the confidence of an ambiguous match but does not decide whether a pixel
// has a depth: confidence_threshold compares the margin and texture factors. With the peak-ratio
// factor scaled down to nearly 0 (scale 0.01: at most 0.01 wherever the aggregated curve has a
// second local minimum) those pixels' confidences fall below the threshold, yet the depth map is
// the one of the default scale, pixel for pixel.
TEST_F(TexturedPlane, PeakRatioLowersTheConfidenceNotWhichPixelsHaveADepth) {
  PlaneSweepOptions options;
  options.num_planes = 48;
  options.confidence_threshold = 0.3;
  const PlaneSweepResult standard = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  options.peak_ratio_scale = 0.01;
  const PlaneSweepResult ambiguous = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  size_t kept = 0, below = 0;
  for (size_t i = 0; i < standard.depth.data.size(); ++i) {
    ASSERT_EQ(standard.depth.data[i], ambiguous.depth.data[i]) << "pixel " << i;
    ASSERT_LE(ambiguous.confidence.data[i], standard.confidence.data[i]) << "pixel " << i;
    kept += standard.depth.data[i] > 0;
    below += standard.depth.data[i] > 0 && ambiguous.confidence.data[i] < options.confidence_threshold;
  }
  EXPECT_GT(kept, 0.9 * w * h);
  EXPECT_GT(below, kept / 2) << "kept pixels whose confidence the peak ratio took below the threshold";
}

// Whichever way the epipolar lines run (here close to the columns), the census cost, interpolated
// along them, finds the plane at least as precisely as the bilinear cost (here more: 3119 pixels
// within 0.3% against 680; the bilinear weights blur the codes across the line too).
TEST_F(TexturedPlane, IsFoundAlongColumnsAsPreciselyAsBilinearly) {
  Vertical();
  PlaneSweepOptions options;
  options.num_planes = 48;
  options.confidence_threshold = 0;
  auto within = [&](double tolerance, const PlaneSweepResult& result) {
    int good = 0;
    for (float z : result.depth.data) good += std::fabs(z - depth) < tolerance * depth;
    return good;
  };
  const PlaneSweepResult along = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  options.census_bilinear = true;
  const PlaneSweepResult bilinear = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  EXPECT_GT(within(0.01, along), 0.95 * w * h);
  // Sub-plane precision (planes lie 2.5% apart at depth 5): within 0.5%, at least as many pixels.
  EXPECT_GT(within(0.005, along), 0.9 * w * h);
  EXPECT_GE(within(0.005, along), within(0.005, bilinear));
}

// Per-pixel depth bounds (a hull's): pixels sweep only their planes, so the work shrinks and the
// depth is still found; bounds that exclude the true depth keep it out; unbounded pixels (near 0)
// sweep every plane.
TEST_F(TexturedPlane, PixelBoundsLimitThePlanesOfEachPixel) {
  PlaneSweepOptions options;
  options.num_planes = 64;
  options.confidence_threshold = 0;
  options.depth_margin = 0.02;
  PixelDepthBounds bounds{DepthMap(w, h, 1, 4.6f), DepthMap(w, h, 1, 5.4f)};
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (x >= 96) bounds.near.At(x, y) = 0.f;  // unbounded
      if (y >= 72 && x < 96) bounds.near.At(x, y) = 6.5f, bounds.far.At(x, y) = 8.f;  // excludes the plane
    }
  }
  const PlaneSweepResult full = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  const PlaneSweepResult limited = PlaneSweep(ref, neighbours, 3.0, 10.0, options, &bounds);
  EXPECT_LT(limited.evaluations, 0.7 * full.evaluations);  // planes go in blocks of 16
  int good = 0, bounded = 0, excluded_good = 0, excluded = 0;
  for (int y = 4; y < h - 4; ++y) {
    for (int x = 4; x < w - 4; ++x) {
      const float z = limited.depth.At(x, y);
      const bool within = std::fabs(z - depth) < 0.01 * depth;
      if (y >= 72 && x < 96) {
        ++excluded;
        excluded_good += within;
        if (z > 0) EXPECT_GT(z, 6.0) << x << "," << y;  // the bounds (less margin and a plane), not the plane at 5
      } else {
        ++bounded;
        good += within;
      }
    }
  }
  EXPECT_GT(good, 0.9 * bounded);
  EXPECT_EQ(excluded_good, 0) << "of " << excluded;
}

// A memory limit below the whole image's cost volumes: the reference is swept in bands of rows.
// On a plane slanted along the rows (depth 4 at the top to 7 at the bottom, so each band holds
// other depths) the banded sweep finds the plane and agrees with the whole-image sweep almost
// everywhere, holding a fraction of its cost volumes.
TEST(PlaneSweep, BandsWithinTheMemoryLimitAgreeWithTheWholeImage) {
  const int w = 160, h = 240;
  const Camera camera = Camera::Pinhole(w, h, 150, 150, w / 2.0, h / 2.0);
  const SweepView ref{"ref", RandomTexture(w, h, 11), camera, Rigid3d()};
  // The plane n.X = d in the reference frame with 1/z linear in the row: 1/z = (n_y y_n + n_z) / d
  // for normalised image coordinate y_n; z = 4 at the top row, 7 at the bottom.
  const double yn_top = (0.5 - h / 2.0) / 150, yn_bottom = (h - 0.5 - h / 2.0) / 150;
  const double ny = (1 / 7.0 - 1 / 4.0) / (yn_bottom - yn_top), nz = 1 / 4.0 - ny * yn_top;  // with d = 1
  auto true_depth = [&](int y) { return 1.0 / (ny * (y + 0.5 - h / 2.0) / 150 + nz); };
  std::vector<SweepView> neighbours;
  const Eigen::Matrix3d k = camera.K();
  for (double baseline : {-0.4, 0.4}) {
    SweepView v{"n", cv::Mat(), camera, Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(baseline, 0, 0))};
    // The plane's homography from the reference to the neighbour, X_n = X + t: H = K (I + t n^T / d) K^-1.
    const Eigen::Matrix3d hom = k * (Eigen::Matrix3d::Identity() + Eigen::Vector3d(baseline, 0, 0) *
                                                                      Eigen::RowVector3d(0, ny, nz)) * k.inverse();
    cv::Mat m(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) m.at<double>(r, c) = hom(r, c);
    cv::warpPerspective(ref.gray, v.gray, m, ref.gray.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    neighbours.push_back(v);
  }
  PlaneSweepOptions options;
  options.num_planes = 64;
  options.confidence_threshold = 0;
  options.max_view_memory_mb = 0;
  const PlaneSweepResult whole = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  options.max_view_memory_mb = 2;
  ASSERT_GT(SweepBands(w, h, options), 2);
  const PlaneSweepResult banded = PlaneSweep(ref, neighbours, 3.0, 10.0, options);
  EXPECT_EQ(banded.bands, SweepBands(w, h, options));
  EXPECT_EQ(whole.bands, 1);
  EXPECT_LT(banded.volume_bytes, 0.75 * whole.volume_bytes);
  int good = 0, agree = 0, inner = 0;
  for (int y = 4; y < h - 4; ++y) {
    for (int x = 8; x < w - 8; ++x) {
      ++inner;
      const float z = banded.depth.At(x, y);
      // Fronto-parallel planes 2.6% apart at the far end, which smoothing turns into stairs.
      good += std::fabs(z - true_depth(y)) < 0.04 * true_depth(y);
      agree += std::fabs(z - whole.depth.At(x, y)) < 0.005 * true_depth(y);
    }
  }
  EXPECT_GT(good, 0.9 * inner);
  EXPECT_GT(agree, 0.99 * inner);
  for (float c : banded.confidence.data) ASSERT_TRUE(c >= 0 && c <= 1);
}

TEST(PlaneSweep, UntexturedImageHasLowConfidence) {
  const int w = 96, h = 72;
  const Camera camera = Camera::Pinhole(w, h, 80, 80, w / 2.0, h / 2.0);
  cv::Mat flat(h, w, CV_8U, cv::Scalar(120));
  SweepView ref{"ref", flat, camera, Rigid3d()};
  SweepView n{"n", flat.clone(), camera, Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.5, 0, 0))};
  PlaneSweepOptions options;
  options.num_planes = 32;
  const PlaneSweepResult result = PlaneSweep(ref, {n}, 2.0, 10.0, options);
  EXPECT_LT(result.valid_fraction, 0.05);
}

// Every vectorised build of the engine's loops the CPU runs (AVX2, AVX-512) gives the portable
// one's maps bit for bit: multi-view census with general homographies (rotated neighbours,
// correspondences leaving the image and falling behind a camera), and two-view stereo with every
// cost.
TEST(SweepEngine, VectorisedAndPortableBuildsAreBitIdentical) {
  std::vector<sweep::Isa> vectorised_isas;
  for (sweep::Isa isa : {sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
    if (sweep::IsaSupported(isa)) vectorised_isas.push_back(isa);
  }
  if (vectorised_isas.empty()) GTEST_SKIP() << "this CPU runs the portable build only (no AVX2)";
  const int w = 150, h = 110;
  const Camera camera = Camera::Pinhole(w, h, 120, 118, 74.3, 56.1);
  const SweepView ref{"ref", RandomTexture(w, h, 11), camera, Rigid3d()};
  std::vector<SweepView> neighbours;
  const double yaw[] = {0.05, -0.2, 0.6, 1.9};  // the last looks sideways: planes behind it
  for (int i = 0; i < 4; ++i) {
    const Eigen::Matrix3d r = Eigen::AngleAxisd(yaw[i], Eigen::Vector3d::UnitY()).toRotationMatrix() *
                              Eigen::AngleAxisd(0.03 * i, Eigen::Vector3d::UnitX()).toRotationMatrix();
    // Neighbour 1 moves mostly vertically: its census cost is interpolated along the columns.
    const Eigen::Vector3d t = i == 1 ? Eigen::Vector3d(0.1, 0.5, 0.1) : Eigen::Vector3d(0.4 * (i - 1.5), 0.05 * i, 0.1);
    neighbours.push_back({"n" + std::to_string(i), RandomTexture(w, h, 20 + i), camera, Rigid3d(r, t)});
  }
  PlaneSweepOptions options;
  options.num_planes = 37;  // not a multiple of 16: padding planes too
  options.num_neighbors = 4;
  options.best_k = 3;       // not a power of two
  options.confidence_threshold = 0;
  auto run = [&](sweep::Isa isa) {
    EXPECT_TRUE(sweep::SetIsa(isa));
    PlaneSweepResult result = PlaneSweep(ref, neighbours, 1.5, 9.0, options);
    PixelDepthBounds bounds{DepthMap(w, h, 1, 2.f), DepthMap(w, h, 1, 4.f)};
    for (int x = 0; x < w / 3; ++x)
      for (int y = 0; y < h; ++y) bounds.near.At(x, y) = 0.f;  // unbounded columns
    const PlaneSweepResult limited = PlaneSweep(ref, neighbours, 1.5, 9.0, options, &bounds);
    result.depth.data.insert(result.depth.data.end(), limited.depth.data.begin(), limited.depth.data.end());
    result.confidence.data.insert(result.confidence.data.end(), limited.confidence.data.begin(), limited.confidence.data.end());
    PlaneSweepOptions bilinear = options;
    bilinear.census_bilinear = true;
    const PlaneSweepResult four_codes = PlaneSweep(ref, neighbours, 1.5, 9.0, bilinear);
    result.depth.data.insert(result.depth.data.end(), four_codes.depth.data.begin(), four_codes.depth.data.end());
    std::vector<cv::Mat> pairs;
    for (MatchCost cost : {MatchCost::kCensus, MatchCost::kSad, MatchCost::kZncc}) {
      PlaneSweepOptions pair = options;
      pair.cost = cost;
      pairs.push_back(StereoPair(ref.gray, neighbours[0].gray, 21, pair).disparity);
    }
    return std::make_pair(std::move(result), pairs);
  };
  const auto portable = run(sweep::Isa::kPortable);
  // Homographies not affine in the plane index (the engine's general path): the same volumes.
  std::vector<sweep::Neighbour> general(2);
  cv::RNG rng(5);
  for (int i = 0; i < 2; ++i) {
    general[i].gray = neighbours[i].gray;
    for (int p = 0; p < 19; ++p) {
      Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
      m(0, 2) = rng.uniform(-20.0, 20.0), m(1, 2) = rng.uniform(-5.0, 5.0);
      if (i == 1) std::swap(m(0, 2), m(1, 2));  // moving mostly vertically
      m(0, 1) = rng.uniform(-0.1, 0.1), m(2, 0) = rng.uniform(-1e-3, 1e-3);
      general[i].homographies.push_back(m);
    }
  }
  sweep::CostVolume general_portable;
  sweep::SetIsa(sweep::Isa::kPortable);
  sweep::BuildCostVolume(ref.gray, general, sweep::EngineOptions(), &general_portable);
  size_t valid = 0;
  for (float z : portable.first.depth.data) valid += z > 0;
  EXPECT_GT(valid, size_t{1000}) << "the scene should give depth somewhere";
  for (sweep::Isa isa : vectorised_isas) {
    SCOPED_TRACE(sweep::IsaName(isa));
    const auto vectorised = run(isa);
    sweep::CostVolume general_vectorised;
    sweep::BuildCostVolume(ref.gray, general, sweep::EngineOptions(), &general_vectorised);
    EXPECT_EQ(general_portable.data, general_vectorised.data);
    EXPECT_EQ(portable.first.depth.data, vectorised.first.depth.data);
    EXPECT_EQ(portable.first.confidence.data, vectorised.first.confidence.data);
    EXPECT_EQ(portable.first.normals.data, vectorised.first.normals.data);
    for (size_t i = 0; i < portable.second.size(); ++i) {
      EXPECT_EQ(cv::norm(portable.second[i], vectorised.second[i], cv::NORM_INF), 0.0) << "two-view cost " << i;
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

// A part of the view, matched at its origin (what PlaneSweep sweeps when the matched pixels lie in
// a box: the box widened by twice the filter radius), gives the matched pixels the volume costs,
// semi-global sums' winners and certainties of the whole view: outside the part every pixel is
// unmatched and flat after the filter, and a path carries a flat curve unchanged.
TEST(SweepEngine, APartAtItsOriginMatchesLikeTheWholeView) {
  struct Case {
    int planes, window_radius, p1, p2;
    sweep::Cost cost;
  };
  // Plane counts with and without padding planes, up to 64 planes and beyond (where the builds
  // other than AVX-512 step the semi-global paths one loop each), no filter, and penalties large
  // enough for the padding planes' sums to matter. The best build the CPU runs.
  for (const Case& c : {Case{32, 1, 120, 900, sweep::Cost::kCensus}, Case{40, 0, 2000, 6000, sweep::Cost::kCensus},
                        Case{72, 1, 2000, 6000, sweep::Cost::kCensus}, Case{24, 1, 120, 900, sweep::Cost::kSad},
                        Case{24, 2, 120, 900, sweep::Cost::kZncc}}) {
    SCOPED_TRACE(std::to_string(c.planes) + " planes, radius " + std::to_string(c.window_radius) + ", cost " +
                 std::to_string(static_cast<int>(c.cost)));
    const int w = 96, h = 64, planes = c.planes;
    const cv::Mat ref = RandomTexture(w, h, 21);
    std::vector<sweep::Neighbour> neighbours(2);
    for (int i = 0; i < 2; ++i) {
      neighbours[i].gray = RandomTexture(w, h, 22 + i);
      for (int p = 0; p < planes; ++p) {  // not affine in p, not integer shifts: the general path
        Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
        m(0, 2) = (i == 0 ? -0.37 : 0.41) * p + 0.013 * p * p, m(1, 2) = 0.05 * p, m(2, 0) = 1e-4 * (i + 1);
        neighbours[i].homographies.push_back(m);
      }
    }
    const cv::Rect block(30, 20, 31, 23);  // the matched pixels
    sweep::PlaneRanges ranges;
    ranges.first.assign(static_cast<size_t>(w) * h, 1);
    ranges.last.assign(ranges.first.size(), 0);
    for (int y = block.y; y < block.br().y; ++y) {
      for (int x = block.x; x < block.br().x; ++x) {
        ranges.first[static_cast<size_t>(y) * w + x] = static_cast<uint16_t>(x % 5);  // ranges of their own too
        ranges.last[static_cast<size_t>(y) * w + x] = static_cast<uint16_t>(planes - 1 - y % 7);
      }
    }
    sweep::EngineOptions options;
    options.cost = c.cost;
    options.window_radius = c.window_radius;
    options.p1 = c.p1;
    options.p2 = c.p2;
    sweep::CostVolume whole_volume;
    sweep::Aggregated whole_sums;
    sweep::BuildCostVolume(ref, neighbours, options, &whole_volume, &ranges);
    sweep::Aggregate(whole_volume, ref, options, &whole_sums, true);
    const sweep::Winners whole = sweep::WinnerTakeAll(whole_sums, &whole_volume, sweep::CertaintyOptions{1.0});

    const int margin = 2 * options.window_radius;
    const cv::Rect part(block.x - margin, block.y - margin, block.width + 2 * margin, block.height + 2 * margin);
    const std::vector<uint64_t> census = sweep::CensusTransform(ref, options.census_radius_x, options.census_radius_y);
    sweep::PlaneRanges part_ranges;
    std::vector<uint64_t> part_census;
    for (int y = part.y; y < part.br().y; ++y) {
      const size_t begin = static_cast<size_t>(y) * w + part.x, end = begin + part.width;
      part_ranges.first.insert(part_ranges.first.end(), ranges.first.begin() + begin, ranges.first.begin() + end);
      part_ranges.last.insert(part_ranges.last.end(), ranges.last.begin() + begin, ranges.last.begin() + end);
      part_census.insert(part_census.end(), census.begin() + begin, census.begin() + end);
    }
    const cv::Mat part_gray = ref(part).clone();
    sweep::CostVolume part_volume;
    sweep::Aggregated part_sums;
    sweep::BuildCostVolume(part_gray, neighbours, options, &part_volume, &part_ranges, &part_census, part.tl());
    sweep::Aggregate(part_volume, part_gray, options, &part_sums, true);
    const sweep::Winners in_part = sweep::WinnerTakeAll(part_sums, &part_volume, sweep::CertaintyOptions{1.0});

    int with_winner = 0;
    for (int y = block.y; y < block.br().y; ++y) {
      for (int x = block.x; x < block.br().x; ++x) {
        const int px = x - part.x, py = y - part.y;
        for (int p = 0; p < planes; ++p) {
          ASSERT_EQ(whole_volume.At(x, y)[p], part_volume.At(px, py)[p]) << x << "," << y << " plane " << p;
        }
        ASSERT_EQ(whole.plane.at<float>(y, x), in_part.plane.at<float>(py, px)) << x << "," << y;
        ASSERT_EQ(whole.confidence.at<float>(y, x), in_part.confidence.at<float>(py, px)) << x << "," << y;
        with_winner += whole.plane.at<float>(y, x) >= 0;
      }
    }
    EXPECT_EQ(with_winner, block.area());
    // Without the origin the part's pixels would be projected as the whole view's top-left ones.
    sweep::CostVolume misplaced;
    sweep::BuildCostVolume(part_gray, neighbours, options, &misplaced, &part_ranges, &part_census);
    EXPECT_NE(misplaced.data, part_volume.data);
  }
}

// A neighbour whose plane p shifts the image by (0.37 p - 3, 0.11 p): sub-pixel steps along both
// axes, so every plane reads codes between pixels.
sweep::Neighbour ShiftingNeighbour(const cv::Mat& gray, int planes) {
  sweep::Neighbour neighbour;
  neighbour.gray = gray;
  for (int p = 0; p < planes; ++p) {
    Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
    m(0, 2) = 0.37 * p - 3, m(1, 2) = 0.11 * p;
    neighbour.homographies.push_back(m);
  }
  return neighbour;
}

// The box mean of entry d at (x, y) over the window of radius r clipped to w x h, of the costs
// `cost(x, y, d)`, rounded by the engine's fixed-point reciprocal.
template <class CostAt>
uint16_t ClippedBoxMean(const CostAt& cost, int w, int h, int x, int y, int r, int d) {
  const int x0 = std::max(0, x - r), x1 = std::min(w - 1, x + r);
  const int y0 = std::max(0, y - r), y1 = std::min(h - 1, y + r);
  const uint32_t area = static_cast<uint32_t>((x1 - x0 + 1) * (y1 - y0 + 1));
  uint32_t sum = 0;
  for (int yy = y0; yy <= y1; ++yy)
    for (int xx = x0; xx <= x1; ++xx) sum += cost(xx, yy, d);
  return static_cast<uint16_t>((sum * ((1u << 16) / area + 1)) >> 16);
}

// The box aggregation (in place, in bands of rows that share their edge rows) against its
// definition: the mean of the unfiltered costs over the window clipped to the image, rounded by
// the engine's fixed-point reciprocal. Tall enough for several bands, radii up to 3.
TEST(SweepEngine, BoxAggregationIsTheClippedWindowMean) {
  const int w = 37, h = 141, planes = 20;
  cv::Mat ref(h, w, CV_8UC1), other(h, w, CV_8UC1);
  cv::RNG rng(4);
  rng.fill(ref, cv::RNG::UNIFORM, 0, 256);
  rng.fill(other, cv::RNG::UNIFORM, 0, 256);
  const sweep::Neighbour neighbour = ShiftingNeighbour(other, planes);
  for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
    if (!sweep::SetIsa(isa)) continue;
    SCOPED_TRACE(sweep::IsaName(isa));
    sweep::EngineOptions options;
    options.window_radius = 0;
    sweep::CostVolume raw;
    sweep::BuildCostVolume(ref, {neighbour}, options, &raw);
    for (int r : {1, 2, 3}) {  // 1 and 2 sum each window directly, 3 keeps running sums
      options.window_radius = r;
      sweep::CostVolume box;
      sweep::BuildCostVolume(ref, {neighbour}, options, &box);
      const auto raw_cost = [&](int x, int y, int d) { return raw.At(x, y)[d]; };
      size_t differ = 0;
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
          for (int d = 0; d < planes; ++d) differ += box.At(x, y)[d] != ClippedBoxMean(raw_cost, w, h, x, y, r, d);
      EXPECT_EQ(differ, 0u) << "radius " << r;
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

// A w x h grey image of independent uniform values.
cv::Mat UniformNoise(int w, int h, cv::RNG* rng) {
  cv::Mat gray(h, w, CV_8UC1);
  rng->fill(gray, cv::RNG::UNIFORM, 0, 256);
  return gray;
}

// A w x h volume of `planes` uniformly random costs in [0, kMaxCost] (padding planes too).
sweep::CostVolume RandomCostVolume(int w, int h, int planes, cv::RNG* rng) {
  sweep::CostVolume volume;
  volume.width = w, volume.height = h, volume.planes = planes, volume.stride = (planes + 15) / 16 * 16;
  volume.data.resize(static_cast<size_t>(w) * h * volume.stride);
  for (uint16_t& c : volume.data) c = static_cast<uint16_t>(rng->uniform(0, static_cast<int>(sweep::kMaxCost) + 1));
  return volume;
}

// With plane ranges that leave pixels unmatched, the volume stores only the pixels within the box
// window of a matched one; every pixel, stored or not, reads the costs of the definition: the raw
// costs limited to the pixel's range (the mean of its in-range costs outside it, kMaxCost on the
// padding planes; kOutsideCost everywhere for an unmatched pixel), then the clipped box mean.
TEST(SweepEngine, FarUnmatchedPixelsAreLeftOutWithoutChangingACost) {
  const int w = 37, h = 141, planes = 20;
  cv::RNG rng(6);
  const cv::Mat ref = UniformNoise(w, h, &rng);
  const sweep::Neighbour neighbour = ShiftingNeighbour(UniformNoise(w, h, &rng), planes);
  // Matched: two blobs and a scattering of single pixels, each with a range of its own.
  sweep::PlaneRanges ranges;
  ranges.first.assign(static_cast<size_t>(w) * h, 1);
  ranges.last.assign(ranges.first.size(), 0);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool blob = (x - 10) * (x - 10) + (y - 30) * (y - 30) < 64 || (x > 25 && y > 90 && y < 110);
      if (!blob && rng.uniform(0, 300) != 0) continue;
      const size_t i = static_cast<size_t>(y) * w + x;
      ranges.first[i] = static_cast<uint16_t>(rng.uniform(0, planes / 2));
      ranges.last[i] = static_cast<uint16_t>(rng.uniform(ranges.first[i], planes + 3));  // past the last plane too
    }
  }
  for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
    if (!sweep::SetIsa(isa)) continue;
    sweep::EngineOptions options;
    options.window_radius = 0;
    sweep::CostVolume raw;
    sweep::BuildCostVolume(ref, {neighbour}, options, &raw);
    const int n = raw.stride;
    // The costs limited to each pixel's range.
    std::vector<uint16_t> limited(static_cast<size_t>(w) * h * n);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        uint16_t* c = limited.data() + i * n;
        const int first = ranges.first[i], last = std::min<int>(ranges.last[i], planes - 1);
        if (first > last) {
          std::fill(c, c + n, static_cast<uint16_t>(600));  // kOutsideCost
          continue;
        }
        uint32_t sum = 0;
        for (int d = first; d <= last; ++d) sum += raw.At(x, y)[d];
        for (int d = 0; d < n; ++d) {
          c[d] = d >= planes ? sweep::kMaxCost
                 : d < first || d > last ? static_cast<uint16_t>(sum / (last - first + 1))
                                         : raw.At(x, y)[d];
        }
      }
    }
    for (int r : {0, 1, 2, 3}) {
      SCOPED_TRACE(std::string(sweep::IsaName(isa)) + ", radius " + std::to_string(r));
      options.window_radius = r;
      sweep::CostVolume volume;
      sweep::BuildCostVolume(ref, {neighbour}, options, &volume, &ranges);
      const auto limited_cost = [&](int x, int y, int d) { return limited[(static_cast<size_t>(y) * w + x) * n + d]; };
      size_t stored = 0, differ = 0;
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          stored += volume.Stored(static_cast<size_t>(y) * w + x);
          for (int d = 0; d < n; ++d) differ += volume.At(x, y)[d] != ClippedBoxMean(limited_cost, w, h, x, y, r, d);
        }
      }
      EXPECT_EQ(differ, 0u);
      EXPECT_LT(stored, static_cast<size_t>(w) * h / 2);  // most pixels are far from a matched one
      EXPECT_EQ(volume.data.size(), stored * n);
      // Without semi-global passes the aggregate is the volume itself, pixel-indexed.
      sweep::EngineOptions box_only = options;
      box_only.semi_global = false;
      sweep::Aggregated aggregated;
      sweep::Aggregate(volume, ref, box_only, &aggregated);
      size_t sums_differ = 0;
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
          for (int d = 0; d < n; ++d) sums_differ += aggregated.Sum(static_cast<size_t>(y) * w + x, d) != volume.At(x, y)[d];
      EXPECT_EQ(sums_differ, 0u);
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

// The semi-global sums by their definition, path by path in plain integers (Hirschmueller, PAMI
// 2008): L_r(p, d) = C(p, d) + min(L_r(p-r, d), L_r(p-r, d-1) + P1, L_r(p-r, d+1) + P1,
// min_k L_r(p-r, k) + P2) - min_k L_r(p-r, k), with L_r = C where the path enters the image and P2
// divided by 1 + |grey step from p-r to p| / gamma (at least P1 + 1). Over every entry of the
// stride, as the engine steps them; the sums wrap as 16-bit integers.
std::vector<uint16_t> SemiGlobalSumsByDefinition(const sweep::CostVolume& v, const cv::Mat& gray, const sweep::EngineOptions& o) {
  const int w = v.width, h = v.height, n = v.stride;
  std::vector<std::array<int, 2>> directions = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
  if (o.paths == 8) directions.insert(directions.end(), {{1, 1}, {-1, -1}, {-1, 1}, {1, -1}});
  std::vector<uint16_t> sums(static_cast<size_t>(w) * h * n, 0);
  std::vector<int> l(sums.size());
  for (const auto& [dx, dy] : directions) {
    for (int yi = 0; yi < h; ++yi) {
      const int y = dy >= 0 ? yi : h - 1 - yi;
      for (int xi = 0; xi < w; ++xi) {
        const int x = dx >= 0 ? xi : w - 1 - xi;
        const int xp = x - dx, yp = y - dy;
        const size_t at = (static_cast<size_t>(y) * w + x) * n;
        const uint16_t* c = v.At(x, y);
        if (xp < 0 || xp >= w || yp < 0 || yp >= h) {
          for (int d = 0; d < n; ++d) l[at + d] = c[d];
        } else {
          const int* prev = l.data() + (static_cast<size_t>(yp) * w + xp) * n;
          const int step = std::abs(gray.at<uint8_t>(y, x) - gray.at<uint8_t>(yp, xp));
          const double divided = o.p2_gamma <= 0 ? o.p2 : o.p2 / (1.0 + step / o.p2_gamma);
          const int p2 = static_cast<int16_t>(std::max<double>(o.p1 + 1, divided));
          const int low = *std::min_element(prev, prev + n);
          for (int d = 0; d < n; ++d) {
            int best = std::min(prev[d], low + p2);
            if (d > 0) best = std::min(best, prev[d - 1] + o.p1);
            if (d + 1 < n) best = std::min(best, prev[d + 1] + o.p1);
            l[at + d] = c[d] + best - low;
          }
        }
        for (int d = 0; d < n; ++d) sums[at + d] = static_cast<uint16_t>(sums[at + d] + l[at + d]);
      }
    }
  }
  return sums;
}

// Every build's semi-global sums, with the paths stepped together (few planes, and many in the
// AVX-512 build) or one loop per path (many planes in the others), are those of the definition, in
// one buffer (the backward pass adding into the forward pass's sums) and in two (the passes at
// once).
TEST(SweepEngine, SemiGlobalSumsFollowTheDefinition) {
  const int w = 23, h = 17;
  cv::RNG rng(8);
  const cv::Mat gray = UniformNoise(w, h, &rng);
  for (int planes : {21, 100, 128}) {
    const sweep::CostVolume volume = RandomCostVolume(w, h, planes, &rng);
    for (int paths : {4, 8}) {
      sweep::EngineOptions options;
      options.paths = paths;
      const std::vector<uint16_t> expected = SemiGlobalSumsByDefinition(volume, gray, options);
      for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
        if (!sweep::SetIsa(isa)) continue;
        SCOPED_TRACE(std::string(sweep::IsaName(isa)) + ", planes " + std::to_string(planes) + ", paths " +
                     std::to_string(paths));
        for (bool one_buffer : {false, true}) {
          sweep::Aggregated got;
          sweep::Aggregate(volume, gray, options, &got, one_buffer);
          size_t differ = 0;
          for (size_t pixel = 0; pixel < static_cast<size_t>(w) * h; ++pixel)
            for (int d = 0; d < planes; ++d) differ += got.Sum(pixel, d) != expected[pixel * volume.stride + d];
          EXPECT_EQ(differ, 0u) << (one_buffer ? "one buffer" : "two buffers");
        }
      }
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

// Pixels marked unmatched (an empty plane range) carry the paths like any other, but their sums are
// not kept and they get no winner: the matched pixels' sums and winners are those of the same
// volume with every pixel matched, on every build, in one buffer and two.
TEST(SweepEngine, UnmatchedPixelsLeaveTheMatchedSumsAndHaveNoWinner) {
  const int w = 23, h = 17;
  cv::RNG rng(5);
  const cv::Mat gray = UniformNoise(w, h, &rng);
  for (int planes : {21, 100}) {
    const sweep::CostVolume all = RandomCostVolume(w, h, planes, &rng);
    sweep::CostVolume some = all;
    some.unmatched.resize(static_cast<size_t>(w) * h);
    size_t unmatched = 0;
    for (uint8_t& u : some.unmatched) unmatched += u = rng.uniform(0, 10) < 3;
    ASSERT_GT(unmatched, 0u);
    for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
      if (!sweep::SetIsa(isa)) continue;
      for (bool one_buffer : {false, true}) {
        SCOPED_TRACE(std::string(sweep::IsaName(isa)) + ", planes " + std::to_string(planes) +
                     (one_buffer ? ", one buffer" : ""));
        sweep::EngineOptions options;
        sweep::Aggregated expected, got;
        sweep::Aggregate(all, gray, options, &expected, one_buffer);
        sweep::Aggregate(some, gray, options, &got, one_buffer);
        size_t differ = 0;
        for (size_t pixel = 0; pixel < static_cast<size_t>(w) * h; ++pixel) {
          if (!some.Matched(pixel)) continue;
          for (int d = 0; d < planes; ++d) differ += got.Sum(pixel, d) != expected.Sum(pixel, d);
        }
        EXPECT_EQ(differ, 0u);
        const sweep::Winners want = sweep::WinnerTakeAll(expected, &all, sweep::CertaintyOptions{3.0});
        const sweep::Winners have = sweep::WinnerTakeAll(got, &some, sweep::CertaintyOptions{3.0});
        for (int y = 0; y < h; ++y) {
          for (int x = 0; x < w; ++x) {
            const size_t pixel = static_cast<size_t>(y) * w + x;
            if (some.Matched(pixel)) {
              EXPECT_EQ(have.plane.at<float>(y, x), want.plane.at<float>(y, x));
              EXPECT_EQ(have.confidence.at<float>(y, x), want.confidence.at<float>(y, x));
            } else {
              EXPECT_EQ(have.plane.at<float>(y, x), -1.f);
              EXPECT_EQ(have.confidence.at<float>(y, x), 0.f);
            }
          }
        }
      }
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

// Paths cross the pixels a volume leaves out (its flat curve) without a step at each, yet every
// matched pixel's sums and winner are those of the same volume with every pixel stored (the flat
// curve repeated): on every build, 4 and 8 paths, one thread and two, in one buffer and two, with
// P1 0 (erosion reaches every plane) and larger, P2 constant and by grey step. The left-out
// pixels form gaps of 1 to 20 pixels between stored blocks (runs shorter and longer than a
// path's P2 / P1 steps), one of 43 (longer than a curve of 21 planes: with P1 0 the steps stop
// at its length) and a wide border, as around an object; and with a flat curve of two costs
// (stepped pixel by pixel); half the stored pixels have a
// single deep minimum, which the steps across a run spread over the most planes.
TEST(SweepEngine, PathsCrossLeftOutPixelsAsIfSteppedThroughEach) {
  const int w = 61, h = 31;
  cv::RNG rng(12);
  const cv::Mat gray = UniformNoise(w, h, &rng);
  for (int planes : {21, 128}) {
    sweep::CostVolume all = RandomCostVolume(w, h, planes, &rng);
    const uint16_t flat_cost = static_cast<uint16_t>(rng.uniform(0, static_cast<int>(sweep::kMaxCost) + 1));
    std::vector<uint8_t> stored(static_cast<size_t>(w) * h, 0);
    for (int y = 5; y < h - 4; ++y) {   // stored blocks of 3-9 columns with gaps of 1-20 between
      for (int x = 6 + (y % 3); x < w - 5;) {
        const int block = rng.uniform(3, 10), gap = rng.uniform(1, 21);
        for (int i = x; i < std::min(x + block, w - 5); ++i) stored[static_cast<size_t>(y) * w + i] = 1;
        x += block + gap;
      }
    }
    for (int y = 0; y < h; ++y) stored[static_cast<size_t>(y) * w + 2] = y % 7 == 0;  // lone pixels in the border
    for (int x = 0; x < w; ++x) stored[static_cast<size_t>(h / 2) * w + x] = x < 9 || x >= w - 9;  // a gap of 43 > 32 planes
    all.unmatched.assign(static_cast<size_t>(w) * h, 1);
    sweep::CostVolume some = all;
    some.slots.assign(static_cast<size_t>(w) * h, sweep::CostVolume::kNotStored);
    some.flat.assign(some.stride, flat_cost);
    some.data.clear();
    size_t left_out = 0;
    for (size_t pixel = 0; pixel < stored.size(); ++pixel) {
      uint16_t* c = all.data.data() + pixel * all.stride;
      if (!stored[pixel]) {
        std::fill(c, c + all.stride, flat_cost);
        ++left_out;
        continue;
      }
      if (rng.uniform(0, 2) == 0) {  // a single deep minimum, which the erosion spreads over the most planes
        std::fill(c, c + planes, sweep::kMaxCost);
        c[rng.uniform(0, planes)] = 0;
      }
      all.unmatched[pixel] = some.unmatched[pixel] = rng.uniform(0, 10) < 2;  // a few stored ones unmatched
      some.slots[pixel] = static_cast<uint32_t>(some.data.size() / some.stride);
      some.data.insert(some.data.end(), c, c + all.stride);
    }
    ASSERT_GT(left_out, stored.size() / 3);
    for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
      if (!sweep::SetIsa(isa)) continue;
      for (int paths : {4, 8}) {
        for (int p1 : {0, 120, 240}) {
          for (double gamma : {0.0, 12.0}) {
            for (int threads : {1, 2}) {
              SCOPED_TRACE(std::string(sweep::IsaName(isa)) + ", planes " + std::to_string(planes) + ", paths " +
                           std::to_string(paths) + ", p1 " + std::to_string(p1) + ", gamma " + std::to_string(gamma) +
                           ", threads " + std::to_string(threads));
              sweep::EngineOptions options;
              options.paths = paths, options.p1 = p1, options.p2_gamma = gamma, options.sgm_threads = threads;
              for (bool one_buffer : {false, true}) {
                sweep::Aggregated expected, got;
                sweep::Aggregate(all, gray, options, &expected, one_buffer);
                sweep::Aggregate(some, gray, options, &got, one_buffer);
                size_t differ = 0;
                for (size_t pixel = 0; pixel < stored.size(); ++pixel) {
                  if (!all.Matched(pixel)) continue;
                  for (int d = 0; d < planes; ++d) differ += got.Sum(pixel, d) != expected.Sum(pixel, d);
                }
                EXPECT_EQ(differ, 0u) << (one_buffer ? "one buffer" : "two buffers");
              }
              LargeBuffer<uint16_t> sums_all, sums_some;
              const sweep::Winners want = sweep::AggregateAndPick(all, gray, options, sweep::CertaintyOptions{3.0}, &sums_all);
              const sweep::Winners have = sweep::AggregateAndPick(some, gray, options, sweep::CertaintyOptions{3.0}, &sums_some);
              size_t differ = 0;
              for (int y = 0; y < h; ++y) {
                for (int x = 0; x < w; ++x) {
                  differ += have.plane.at<float>(y, x) != want.plane.at<float>(y, x);
                  differ += have.confidence.at<float>(y, x) != want.confidence.at<float>(y, x);
                }
              }
              EXPECT_EQ(differ, 0u) << "winners";
            }
          }
        }
      }
    }
    // A curve for the left-out pixels that is not one cost (no volume the engine builds has one):
    // those pixels are stepped one by one, with the same sums as the volume storing them.
    some.flat[3] = static_cast<uint16_t>(flat_cost / 2);
    for (size_t pixel = 0; pixel < stored.size(); ++pixel) {
      if (!stored[pixel]) all.data[pixel * all.stride + 3] = some.flat[3];
    }
    sweep::SetIsa(sweep::BestIsa());
    sweep::Aggregated expected, got;
    sweep::Aggregate(all, gray, sweep::EngineOptions(), &expected);
    sweep::Aggregate(some, gray, sweep::EngineOptions(), &got);
    size_t differ = 0;
    for (size_t pixel = 0; pixel < stored.size(); ++pixel) {
      if (!all.Matched(pixel)) continue;
      for (int d = 0; d < planes; ++d) differ += got.Sum(pixel, d) != expected.Sum(pixel, d);
    }
    EXPECT_EQ(differ, 0u) << "a flat curve of two costs";
  }
  sweep::SetIsa(sweep::BestIsa());
}

// Picking each pixel's winner in the backward pass (the multi-view stage's path) gives the winners
// and certainties of the sums stored and then searched, on every build, with unmatched pixels,
// with few planes and many, 4 and 8 paths, without the semi-global passes, and with a sums buffer
// that holds an earlier call's values; and so do the passes with their paths split over two
// threads (sgm_threads 2), whose sums are those of one thread. The sums buffer then holds the
// matched pixels' sums alone, in scan order.
TEST(SweepEngine, PickingWinnersInTheBackwardPassEqualsSearchingTheSums) {
  const int w = 29, h = 13;
  cv::RNG rng(9);
  const cv::Mat gray = UniformNoise(w, h, &rng);
  for (int planes : {21, 100, 128}) {
    sweep::CostVolume volume = RandomCostVolume(w, h, planes, &rng);
    volume.unmatched.resize(static_cast<size_t>(w) * h);
    size_t unmatched = 0;
    for (uint8_t& u : volume.unmatched) unmatched += u = rng.uniform(0, 10) < 3;
    ASSERT_GT(unmatched, 0u);
    for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
      if (!sweep::SetIsa(isa)) continue;
      for (int paths : {0, 4, 8}) {  // 0: no semi-global passes
        SCOPED_TRACE(std::string(sweep::IsaName(isa)) + ", planes " + std::to_string(planes) + ", paths " +
                     std::to_string(paths));
        sweep::EngineOptions options;
        options.semi_global = paths > 0;
        options.paths = paths > 0 ? paths : 8;
        sweep::Aggregated aggregated;
        sweep::Aggregate(volume, gray, options, &aggregated, /*one_buffer=*/true);
        const sweep::Winners want = sweep::WinnerTakeAll(aggregated, &volume, sweep::CertaintyOptions{0.5});
        for (int threads : {1, 2}) {
          SCOPED_TRACE("threads " + std::to_string(threads));
          options.sgm_threads = threads;
          if (threads == 2 && paths > 0) {
            sweep::Aggregated split;
            sweep::Aggregate(volume, gray, options, &split, /*one_buffer=*/true);
            size_t sums_differ = 0;
            for (size_t pixel = 0; pixel < static_cast<size_t>(w) * h; ++pixel) {
              if (!volume.Matched(pixel)) continue;
              for (int d = 0; d < planes; ++d) sums_differ += split.Sum(pixel, d) != aggregated.Sum(pixel, d);
            }
            EXPECT_EQ(sums_differ, 0u);
          }
          LargeBuffer<uint16_t> sums(volume.data.size());
          for (uint16_t& v : sums) v = static_cast<uint16_t>(rng.uniform(0, 65536));
          const sweep::Winners have = sweep::AggregateAndPick(volume, gray, options, sweep::CertaintyOptions{0.5}, &sums);
          EXPECT_EQ(sums.empty(), paths == 0);  // without semi-global passes the volume is picked from
          // The matched pixels' sums only (the unmatched ones' are never read).
          if (paths > 0) EXPECT_EQ(sums.size(), (static_cast<size_t>(w) * h - unmatched) * volume.stride);
          size_t differ = 0, winners = 0, graded = 0;
          for (int y = 0; y < h; ++y) {
            for (int x = 0; x < w; ++x) {
              const float confidence = have.confidence.at<float>(y, x);
              differ += have.plane.at<float>(y, x) != want.plane.at<float>(y, x);
              differ += confidence != want.confidence.at<float>(y, x);
              winners += have.plane.at<float>(y, x) >= 0;
              graded += confidence > 0 && confidence < 1;  // neither clamped end: the scale matters
            }
          }
          EXPECT_EQ(differ, 0u);
          EXPECT_EQ(winners, static_cast<size_t>(w) * h - unmatched);
          EXPECT_GT(graded, 0u);
        }
      }
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

// The census codes of every build against the definition: bit set where the window's pixel
// (borders clamped) is darker than the centre, offsets in row-major order, the centre skipped;
// a window of more than 64 offsets (11x9) keeps the last 64.
TEST(SweepEngine, CensusCodesMatchTheDefinition) {
  const int w = 53, h = 31;
  cv::Mat gray(h, w, CV_8UC1);
  cv::RNG rng(9);
  rng.fill(gray, cv::RNG::UNIFORM, 0, 6);  // few levels: ties (not darker) are common
  for (const auto& [rx, ry] : {std::pair{4, 3}, std::pair{1, 1}, std::pair{3, 4}, std::pair{5, 4}}) {
    std::vector<uint64_t> expected(static_cast<size_t>(w) * h, 0);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        uint64_t code = 0;
        for (int dy = -ry; dy <= ry; ++dy) {
          for (int dx = -rx; dx <= rx; ++dx) {
            if (dx == 0 && dy == 0) continue;
            const uint8_t q = gray.at<uint8_t>(std::clamp(y + dy, 0, h - 1), std::clamp(x + dx, 0, w - 1));
            code = (code << 1) | (q < gray.at<uint8_t>(y, x) ? 1u : 0u);
          }
        }
        expected[static_cast<size_t>(y) * w + x] = code;
      }
    }
    for (sweep::Isa isa : {sweep::Isa::kPortable, sweep::Isa::kAvx2, sweep::Isa::kAvx512}) {
      if (!sweep::SetIsa(isa)) continue;
      EXPECT_EQ(sweep::CensusTransform(gray, rx, ry), expected) << sweep::IsaName(isa) << " " << rx << "x" << ry;
    }
  }
  sweep::SetIsa(sweep::BestIsa());
}

class PlaneSweepStageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    RegisterStage_synth(&registry_);
    RegisterStage_plane_sweep(&registry_);
    dir_ = fs::path(::testing::TempDir()) /
           ("plane_sweep_test_" + std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  nlohmann::json Run(const std::string& name, const Params& params) {
    StageContext context;
    context.workspace = Workspace(dir_.string());
    context.params = params;
    context.progress = &progress_;
    context.role = registry_.Find(name)->Role();
    registry_.Find(name)->Run(context);
    return context.metrics;
  }

  // The synthetic object ring (400 sparse points) written into the workspace.
  void SynthRing(int views, int width, int height) {
    Params synth = Defaults(*registry_.Find("synth"));
    synth.Set("scene", std::string("object_ring"));
    synth.Set("views", int64_t{views});
    synth.Set("width", int64_t{width});
    synth.Set("height", int64_t{height});
    synth.Set("subdivision", int64_t{4});
    synth.Set("sparse_points", int64_t{400});
    Run("synth", synth);
  }

  StageRegistry registry_;
  fs::path dir_;
  NullProgress progress_;
};

TEST_F(PlaneSweepStageTest, DeclaresItsContract) {
  const Stage* stage = registry_.Find("plane_sweep");
  ASSERT_NE(stage, nullptr);
  EXPECT_EQ(stage->Role(), HoldoutRole::kTrainingOnly);
  Params params = Defaults(*stage);
  EXPECT_FALSE(stage->CheckParams(params).has_value());
  params.Set("bounding_box", std::vector<double>{0, 0, 0, 1});
  ASSERT_TRUE(stage->CheckParams(params).has_value());
  EXPECT_EQ(stage->CheckParams(params)->key, "bounding_box");
  params = Defaults(*stage);
  params.Set("p1", int64_t{-3});
  ASSERT_TRUE(stage->CheckParams(params).has_value());
  EXPECT_EQ(stage->CheckParams(params)->key, "p1");
  bool has_command = false;
  for (const StageCommand& command : registry_.Commands()) has_command |= command.name == "stereo-pair";
  EXPECT_TRUE(has_command);
}

TEST_F(PlaneSweepStageTest, StereoPairCommandWritesPfm) {
  const StageCommand* command = nullptr;
  for (const StageCommand& c : registry_.Commands())
    if (c.name == "stereo-pair") command = &c;
  ASSERT_NE(command, nullptr);
  const int w = 120, h = 90, shift = 5;
  const cv::Mat wide = RandomTexture(w + shift, h, 11);
  const std::string left = (dir_ / "left.png").string(), right = (dir_ / "right.png").string();
  const std::string out = (dir_ / "disp.pfm").string();
  cv::imwrite(left, wide(cv::Rect(0, 0, w, h)));
  cv::imwrite(right, wide(cv::Rect(shift, 0, w, h)));
  ASSERT_EQ(command->main({left, right, "--max-disparity", "16", "--out", out}), 0);
  const cv::Mat disparity = ReadPfm(out);
  ASSERT_EQ(disparity.size(), cv::Size(w, h));
  EXPECT_NEAR(disparity.at<float>(h / 2, w / 2), shift, 0.5);
  // Bad input: a missing file is reported, not a crash.
  EXPECT_NE(command->main({left, (dir_ / "missing.png").string(), "--out", out}), 0);
  EXPECT_NE(command->main({left, right}), 0);  // --out is required
}

// Small object ring (24 views, 240x180): most object pixels within 1% of the true depth.
TEST_F(PlaneSweepStageTest, SynthObjectRingDepthMatchesGroundTruth) {
  SynthRing(24, 240, 180);
  Params params = Defaults(*registry_.Find("plane_sweep"));
  const nlohmann::json metrics = Run("plane_sweep", params);
  EXPECT_EQ(metrics["views"].get<int>(), 24);
  EXPECT_GT(metrics["evaluations"].get<int64_t>(), 0);
  // Where the threads' time went: each timed part took some, and all of them together no more than
  // the threads had (a clock around a parallel loop would also count the other tasks its thread
  // ran while it waited, and could exceed it).
  const nlohmann::json& spent = metrics["thread_seconds"];
  double parts = 0;
  for (const char* part : {"evaluations", "box_filter", "semi_global_and_winners", "writing_maps"}) {
    EXPECT_GT(spent[part].get<double>(), 0.0) << part;
    parts += spent[part].get<double>();
  }
  EXPECT_LE(parts, spent["wall_times_threads"].get<double>());
  const Workspace ws(dir_.string());
  size_t truth = 0, within = 0, estimated = 0;
  for (int v = 0; v < 24; ++v) {
    char name[32];
    std::snprintf(name, sizeof(name), "view_%03d.png", v);
    const DepthMap gt = ReadColmapArray(ws.GroundTruthDepthPath(name));
    const DepthMap depth = ReadColmapArray(ws.DepthMapPath(name, "photometric"));
    const FloatMap normals = ReadColmapArray(ws.NormalMapPath(name, "photometric"));
    const FloatMap conf = ReadColmapArray(ws.Path(std::string("dense/stereo/confidence_maps/") + name + ".photometric.bin"));
    ASSERT_EQ(depth.width, gt.width);
    ASSERT_EQ(normals.channels, 3);
    ASSERT_EQ(conf.channels, 1);
    for (size_t i = 0; i < gt.data.size(); ++i) {
      if (!IsValidDepth(gt.data[i])) continue;
      ++truth;
      if (!IsValidDepth(depth.data[i])) continue;
      ++estimated;
      within += std::fabs(depth.data[i] - gt.data[i]) < 0.01 * gt.data[i];
    }
  }
  const double fraction = static_cast<double>(within) / truth;
  RecordProperty("fraction_within_1_percent", std::to_string(fraction));
  std::printf("object_ring 24 views 240x180: %.3f of object pixels within 1%% (%.3f estimated)\n", fraction,
              static_cast<double>(estimated) / truth);
  EXPECT_GT(fraction, 0.65);
  EXPECT_GT(static_cast<double>(within) / std::max<size_t>(1, estimated), 0.7);
}

// A camera with lens distortion is refused with a message naming the file, the image and the fix
// (its depth maps would lie on a grid multi_depth, fuse and the renderers read as the photo's own).
TEST_F(PlaneSweepStageTest, DistortedCamerasAreRefusedWithTheFix) {
  SynthRing(4, 80, 60);
  const Workspace ws(dir_.string());
  const std::string cameras = ws.SparseDir() + "/cameras.txt";
  std::ifstream in(cameras);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  in.close();
  const size_t at = text.find(" PINHOLE ");
  ASSERT_NE(at, std::string::npos);
  const size_t end = text.find('\n', at);
  text = text.substr(0, at) + " OPENCV " + text.substr(at + 9, end - at - 9) + " 0.05 0 0 0" + text.substr(end);
  std::ofstream(cameras) << text;
  try {
    Run("plane_sweep", Defaults(*registry_.Find("plane_sweep")));
    FAIL() << "a distorted camera was accepted";
  } catch (const InputError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("cameras.txt"), std::string::npos) << message;
    EXPECT_NE(message.find("view_00"), std::string::npos) << message;
    EXPECT_NE(message.find("lens distortion"), std::string::npos) << message;
    EXPECT_NE(message.find("undistort"), std::string::npos) << message;
  }
}

}  // namespace
// A hull that reaches the camera (silhouettes that filled the image) has near ~ 0: its bounds are
// not used, the sparse points give the range, and the depth is still found. With them, every plane
// but the last crowded at the camera and the last plane won every pixel.
TEST_F(PlaneSweepStageTest, HullBoundsThatReachTheCameraAreNotUsed) {
  SynthRing(12, 160, 120);
  const Workspace ws(dir_.string());
  nlohmann::json bounds = nlohmann::json::object();
  for (int v = 0; v < 12; ++v) {
    char name[32];
    std::snprintf(name, sizeof(name), "view_%03d.png", v);
    bounds[name] = {{"near", 1.7e-10}, {"far", 12.0}};
  }
  fs::create_directories(ws.Path("hull"));
  std::ofstream(ws.Path("hull/depth_bounds.json")) << bounds.dump();
  Params params = Defaults(*registry_.Find("plane_sweep"));
  params.Set("num_planes", int64_t{64});
  const nlohmann::json metrics = Run("plane_sweep", params);
  EXPECT_FALSE(metrics["bounds_from"].contains("hull")) << metrics["bounds_from"].dump();
  EXPECT_EQ(metrics["bounds_from"].value("sparse_points", 0), 12) << metrics["bounds_from"].dump();
  size_t truth = 0, within = 0;
  for (int v = 0; v < 12; ++v) {
    char name[32];
    std::snprintf(name, sizeof(name), "view_%03d.png", v);
    const DepthMap gt = ReadColmapArray(ws.GroundTruthDepthPath(name));
    const DepthMap depth = ReadColmapArray(ws.DepthMapPath(name, "photometric"));
    for (size_t i = 0; i < gt.data.size(); ++i) {
      if (!IsValidDepth(gt.data[i])) continue;
      ++truth;
      within += IsValidDepth(depth.data[i]) && std::fabs(depth.data[i] - gt.data[i]) < 0.01 * gt.data[i];
    }
  }
  EXPECT_GT(static_cast<double>(within) / truth, 0.3);
}

}  // namespace ibmr
