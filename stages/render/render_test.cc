// Tests of the unstructured lumigraph renderer against the ULR goals (seed 001, section 3
// [U 44-87]): epipole consistency, continuity at image borders and under a small camera move,
// minimal angular deviation, visibility, ties and fewer-than-k cameras; a known answer (a textured
// plane rendered with the true plane as proxy); option checks; the adapter on a tiny workspace.
#include "stages/render/render.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/render/layers.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_render(StageRegistry* registry);

namespace {

constexpr int kWidth = 96, kHeight = 72;

// Smooth colour texture on the world plane z = 0 (BGR, 0..255).
cv::Vec3b Texture(double x, double y) {
  const double r = 128 + 90 * std::sin(7.0 * x + 1.3 * std::cos(5.0 * y));
  const double g = 128 + 90 * std::sin(6.0 * y + 0.7) * std::cos(3.0 * x);
  const double b = 128 + 90 * std::cos(4.0 * (x + y));
  return cv::Vec3b(cv::saturate_cast<uint8_t>(b), cv::saturate_cast<uint8_t>(g), cv::saturate_cast<uint8_t>(r));
}

Camera TestCamera() { return Camera::Pinhole(kWidth, kHeight, 80, 80, kWidth / 2.0, kHeight / 2.0); }

// A camera at `eye` looking at the origin, its photo of the textured plane z = 0 (ray-cast at
// 4x4 sub-samples per pixel, box-filtered).
SourceView PlaneView(const Eigen::Vector3d& eye, const std::string& name) {
  SourceView view;
  view.name = name;
  view.camera = TestCamera();
  view.cam_from_world = LookAt(eye, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
  view.image = cv::Mat(kHeight, kWidth, CV_8UC3);
  const Rigid3d world_from_cam = view.cam_from_world.Inverse();
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      double sum[3] = {0, 0, 0};
      for (int s = 0; s < 16; ++s) {
        const Eigen::Vector3d ray = world_from_cam.rotation *
                                    view.camera.CamFromImg(Eigen::Vector2d(x + (s % 4 + 0.5) / 4, y + (s / 4 + 0.5) / 4));
        const double t = -eye.z() / ray.z();
        const cv::Vec3b c = Texture(eye.x() + t * ray.x(), eye.y() + t * ray.y());
        for (int k = 0; k < 3; ++k) sum[k] += c[k] / 16.0;
      }
      view.image.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uint8_t>(sum[0]), cv::saturate_cast<uint8_t>(sum[1]),
                                                 cv::saturate_cast<uint8_t>(sum[2]));
    }
  }
  return view;
}

// Cameras on a circle of radius `radius` at height 3 above the plane.
std::vector<SourceView> Ring(int count, double radius) {
  std::vector<SourceView> views;
  for (int i = 0; i < count; ++i) {
    const double a = 2 * M_PI * i / count;
    views.push_back(PlaneView(Eigen::Vector3d(radius * std::cos(a), radius * std::sin(a), 3.0), "v" + std::to_string(i)));
  }
  return views;
}

const Plane kGround{Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ()};

double Psnr(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  double sum = 0;
  size_t n = 0;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = 0; x < a.cols; ++x) {
      if (!mask.at<uint8_t>(y, x)) continue;
      for (int c = 0; c < 3; ++c) {
        const double d = a.at<cv::Vec3b>(y, x)[c] - b.at<cv::Vec3b>(y, x)[c];
        sum += d * d;
      }
      n += 3;
    }
  }
  return 10 * std::log10(255.0 * 255.0 / std::max(1e-12, sum / n));
}

// The stage's parameters at their defaults (list parameters empty), as a config without them gives.
Params DefaultParams(const Stage& stage) {
  Params params;
  for (const ParamSpec& spec : stage.Parameters()) {
    if (spec.type == ParamType::kString) {
      params.Set(spec.key, spec.default_yaml);
    } else if (spec.type == ParamType::kInt) {
      params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
    } else if (spec.type == ParamType::kDouble) {
      params.Set(spec.key, std::stod(spec.default_yaml));
    } else if (spec.type == ParamType::kBool) {
      params.Set(spec.key, spec.default_yaml == "true");
    } else if (spec.type == ParamType::kDoubleList) {
      params.Set(spec.key, std::vector<double>{});
    } else {
      params.Set(spec.key, std::vector<std::string>{});
    }
  }
  return params;
}

TEST(RenderOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(RenderOptions().Check(&error)) << error;
  EXPECT_EQ(RenderOptions().k, 4);  // [U 214]
}

TEST(RenderOptions, RejectsBadValues) {
  const auto expect_key = [](RenderOptions options, const std::string& key) {
    std::string error;
    EXPECT_FALSE(options.Check(&error));
    EXPECT_EQ(error.rfind(key + ":", 0), 0u) << error;
  };
  RenderOptions o;
  o.k = 1;
  expect_key(o, "k");
  o = RenderOptions();
  o.alpha = -1;
  expect_key(o, "alpha");
  o = RenderOptions();
  o.beta = std::nan("");
  expect_key(o, "beta");
  o = RenderOptions();
  o.alpha = o.beta = o.gamma = 0;
  expect_key(o, "alpha");
  o = RenderOptions();
  o.fov_margin = 0.5;
  expect_key(o, "fov_margin");
  o = RenderOptions();
  o.visibility_epsilon = 0;
  expect_key(o, "visibility_epsilon");
  o = RenderOptions();
  o.max_penalty = 0;
  expect_key(o, "max_penalty");
  o = RenderOptions();
  o.proxy_extend_px = 17;
  expect_key(o, "proxy_extend_px");
  o.proxy_extend_px = -1;
  expect_key(o, "proxy_extend_px");
}

// Two surfaces side by side (depth 2 on the left, 5 on the right) with a one-pixel gap between
// them, a hole column of 9 pixels in the left one and a ring of holes around both: extended by 2
// pixels, covered pixels keep their depths, a hole pixel takes the depth of the nearest covered
// one (the front one where both touch it), the wide hole's middle stays open, and so does every
// pixel more than 2 pixels from the surfaces.
TEST(ExtendIntoHoles, HolesNearTheMeshTakeTheNearestDepthAndWideOnesStayOpen) {
  DepthMap depth(40, 20, 1, 0.f);
  for (int y = 5; y < 15; ++y) {
    for (int x = 5; x < 20; ++x) depth.At(x, y) = 2.f;
    for (int x = 21; x < 35; ++x) depth.At(x, y) = 5.f;
    for (int x = 8; x < 17; ++x) depth.At(x, y) = 0.f;  // a hole 9 pixels wide
  }
  const DepthMap before = depth;
  ExtendIntoHoles(&depth, 2);
  for (int y = 0; y < 20; ++y) {
    for (int x = 0; x < 40; ++x) {
      if (IsValidDepth(before.At(x, y))) {
        EXPECT_EQ(depth.At(x, y), before.At(x, y)) << x << "," << y;
      }
    }
  }
  EXPECT_EQ(depth.At(20, 10), 2.f);  // between the surfaces: the front one
  EXPECT_EQ(depth.At(36, 10), 5.f);  // two pixels beyond the right edge
  EXPECT_FALSE(IsValidDepth(depth.At(37, 10)));
  EXPECT_EQ(depth.At(6, 3), 2.f);    // above the left surface
  EXPECT_FALSE(IsValidDepth(depth.At(6, 2)));
  EXPECT_EQ(depth.At(9, 10), 2.f);   // inside the wide hole, near its sides
  EXPECT_EQ(depth.At(15, 10), 2.f);
  EXPECT_FALSE(IsValidDepth(depth.At(12, 10)));  // its middle stays open
  EXPECT_EQ(depth.At(3, 3), 2.f);    // diagonal neighbours count
  EXPECT_FALSE(IsValidDepth(depth.At(2, 2)));
  DepthMap untouched = before;
  ExtendIntoHoles(&untouched, 0);
  EXPECT_EQ(untouched.data, before.data);
}

// The definition HoleSources follows (radius steps of a 3x3 erosion over the whole image, holes
// as +infinity, the first of equal neighbours in row-major order), written out plainly: the
// frontier sweep must give every pixel the same source on random maps with many equal depths,
// holes at the borders and radii from 1 to 6.
std::vector<int> HoleSourcesByErosion(const DepthMap& depth, int radius) {
  const int w = depth.width, h = depth.height;
  std::vector<int> source(static_cast<size_t>(w) * h, -1);
  std::vector<float> current(source.size(), std::numeric_limits<float>::infinity());
  for (size_t i = 0; i < source.size(); ++i) {
    if (IsValidDepth(depth.data[i])) current[i] = depth.data[i], source[i] = static_cast<int>(i);
  }
  for (int step = 0; step < radius; ++step) {
    std::vector<float> next = current;
    std::vector<int> next_source = source;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (source[i] >= 0) continue;
        for (int ny = std::max(0, y - 1); ny <= std::min(h - 1, y + 1); ++ny) {
          for (int nx = std::max(0, x - 1); nx <= std::min(w - 1, x + 1); ++nx) {
            const size_t n = static_cast<size_t>(ny) * w + nx;
            if (current[n] < next[i]) next[i] = current[n], next_source[i] = source[n];
          }
        }
      }
    }
    current.swap(next);
    source.swap(next_source);
  }
  return source;
}

TEST(ExtendIntoHoles, TheFrontierSweepGivesEachHoleTheSourceOfTheWholeImageErosion) {
  std::mt19937 random(7);
  for (int trial = 0; trial < 40; ++trial) {
    const int w = 5 + static_cast<int>(random() % 60), h = 3 + static_cast<int>(random() % 40);
    DepthMap depth(w, h, 1, 0.f);
    const double covered = 0.02 + 0.3 * (trial % 5) / 4.0;
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    for (float& d : depth.data) {
      // Four depth values only, so that neighbours tie often; some holes are NaN or infinite.
      if (unit(random) < covered) d = 1.f + static_cast<float>(random() % 4);
      else if (unit(random) < 0.05) d = trial % 2 ? std::numeric_limits<float>::quiet_NaN() : std::numeric_limits<float>::infinity();
    }
    const int radius = 1 + trial % 6;
    EXPECT_EQ(HoleSources(depth, radius), HoleSourcesByErosion(depth, radius)) << "trial " << trial << " " << w << "x" << h;
  }
}

// The renderer's blend search visits sources from a lower bound of their penalty up and stops
// early; it must give exactly what the definition gives (every visible source's penalty, the k
// smallest): the same sources in the same order, the same weights and penalties to the bit. Scenes:
// 30 sources on two rings (some at the same place: equal penalties, ties broken by index), each
// with a visibility map that holds the ground plane's depth with random holes and random wrong
// patches (so that many sources are hidden), points on and off the plane, near the image borders
// (field-of-view term), desired cameras near and at a source centre, every k, both weightings.
TEST(Ulr, PrunedBlendSearchGivesExactlyTheWeightsOfTheDefinition) {
  std::vector<SourceView> sources = Ring(12, 1.5);
  for (SourceView& v : Ring(12, 0.7)) sources.push_back(v);
  for (int i = 0; i < 6; ++i) sources.push_back(sources[static_cast<size_t>(i) * 2]);  // duplicates: ties
  std::mt19937 random(11);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (SourceView& v : sources) {
    v.proxy_depth = DepthMap(v.camera.width, v.camera.height, 1, 0.f);
    const Rigid3d world_from_cam = v.cam_from_world.Inverse();
    for (int y = 0; y < v.camera.height; ++y) {
      for (int x = 0; x < v.camera.width; ++x) {
        const Eigen::Vector3d ray = world_from_cam.rotation * v.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
        const double t = -world_from_cam.translation.z() / ray.z();  // the plane z = 0, along the camera z
        const double z = (v.cam_from_world * (world_from_cam.translation + t * ray)).z();
        const double r = unit(random);
        v.proxy_depth.At(x, y) = r < 0.1 ? 0.f : r < 0.25 ? static_cast<float>(z * 0.7) : static_cast<float>(z);
      }
    }
  }
  size_t compared = 0, covered = 0;
  for (const int k : {2, 3, 4, 8}) {
    for (const bool epipole : {false, true}) {
      RenderOptions options;
      options.k = k;
      options.epipole_consistent = epipole;
      options.gamma = 0.5;  // the field-of-view term matters near the borders
      const UlrRenderer renderer(&sources, options);
      for (int trial = 0; trial < 400; ++trial) {
        const Eigen::Vector3d p(4 * unit(random) - 2, 4 * unit(random) - 2, trial % 4 == 0 ? 0.3 * unit(random) : 0.0);
        Eigen::Vector3d desired(3 * unit(random) - 1.5, 3 * unit(random) - 1.5, 2.5 + unit(random));
        if (trial % 25 == 0) desired = sources[static_cast<size_t>(trial) % sources.size()].cam_from_world.Inverse().translation;
        const std::vector<BlendWeight> pruned = renderer.Weights(p, desired);
        const std::vector<BlendWeight> definition = renderer.Weights(p, desired, /*exhaustive=*/true);
        ASSERT_EQ(pruned.size(), definition.size()) << "k " << k << " trial " << trial;
        for (size_t j = 0; j < pruned.size(); ++j) {
          EXPECT_EQ(pruned[j].source, definition[j].source) << "k " << k << " trial " << trial << " entry " << j;
          EXPECT_EQ(pruned[j].weight, definition[j].weight) << "k " << k << " trial " << trial << " entry " << j;
          EXPECT_EQ(pruned[j].penalty, definition[j].penalty) << "k " << k << " trial " << trial << " entry " << j;
        }
        ++compared;
        covered += !pruned.empty();
      }
    }
  }
  EXPECT_GT(covered, compared / 3);  // the scenes do exercise the blend, not only empty pixels
}

TEST(Ulr, EpipoleConsistencyReproducesSourceImageExactly) {
  const std::vector<SourceView> sources = Ring(8, 1.5);
  RenderOptions options;  // epipole_consistent = true
  const UlrRenderer renderer(&sources, options);
  // A deliberately wrong proxy: the plane 1 unit above the true one. Geometry must not matter.
  const Plane wrong{Eigen::Vector3d(0, 0, 1), Eigen::Vector3d::UnitZ()};
  const SourceView& s = sources[3];
  const RenderResult result =
      renderer.Render(s.camera, s.cam_from_world, PlaneSurface(wrong, s.camera, s.cam_from_world));
  const int margin = static_cast<int>(std::ceil(options.fov_margin * std::min(kWidth, kHeight))) + 1;
  const cv::Rect inner(margin, margin, kWidth - 2 * margin, kHeight - 2 * margin);
  cv::Mat diff;
  cv::absdiff(result.image(inner), s.image(inner), diff);
  double max_diff = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
  EXPECT_EQ(max_diff, 0.0) << "a desired camera at a source centre must reproduce that source exactly";
  // The linear weights alone (no 1/penalty) blend neighbours in: not exact with a wrong proxy.
  options.epipole_consistent = false;
  const UlrRenderer linear(&sources, options);
  const RenderResult blended =
      linear.Render(s.camera, s.cam_from_world, PlaneSurface(wrong, s.camera, s.cam_from_world));
  cv::absdiff(blended.image(inner), s.image(inner), diff);
  EXPECT_GT(cv::norm(diff, cv::NORM_L1), 0.0);
}

TEST(Ulr, TruePlaneProxyPredictsHeldOutView) {
  const std::vector<SourceView> sources = Ring(12, 1.5);
  const SourceView truth = PlaneView(Eigen::Vector3d(1.2, 0.5, 3.2), "heldout");  // between ring cameras
  const UlrRenderer renderer(&sources, RenderOptions());
  const RenderResult result =
      renderer.Render(truth.camera, truth.cam_from_world, PlaneSurface(kGround, truth.camera, truth.cam_from_world));
  EXPECT_GT(result.covered_pixels, 0.9 * kWidth * kHeight);
  EXPECT_GT(Psnr(result.image, truth.image, result.coverage), 30.0);
  // A wrong plane predicts worse.
  const Plane wrong{Eigen::Vector3d(0, 0, 1), Eigen::Vector3d::UnitZ()};
  const RenderResult off =
      renderer.Render(truth.camera, truth.cam_from_world, PlaneSurface(wrong, truth.camera, truth.cam_from_world));
  EXPECT_LT(Psnr(off.image, truth.image, off.coverage) + 5, Psnr(result.image, truth.image, result.coverage));
}

TEST(Ulr, WeightsFallToZeroAtImageBorder) {
  const std::vector<SourceView> sources = Ring(8, 1.5);
  const UlrRenderer renderer(&sources, RenderOptions());
  const Eigen::Vector3d desired(1.4, 0.3, 3.1);
  // Walk a ground point towards and across the border of source 0's image.
  const SourceView& s = sources[0];
  const Rigid3d world_from_cam = s.cam_from_world.Inverse();
  double previous = 1.0;
  bool was_positive = false;
  for (double u = 20; u > 0.2; u -= 0.25) {
    const Eigen::Vector3d ray = world_from_cam.rotation * s.camera.CamFromImg(Eigen::Vector2d(u, kHeight / 2.0));
    const Eigen::Vector3d p = world_from_cam.translation + (-world_from_cam.translation.z() / ray.z()) * ray;
    double w0 = 0;
    for (const BlendWeight& w : renderer.Weights(p, desired)) {
      ASSERT_TRUE(std::isfinite(w.weight));
      if (w.source == 0) w0 = w.weight;
    }
    if (w0 > 0) was_positive = true;
    if (u < 3.0 && was_positive) EXPECT_LE(w0, previous + 1e-12) << "u=" << u;  // falls monotonically
    if (u < 0.75) EXPECT_LT(w0, 0.02) << "u=" << u;
    previous = w0;
  }
  EXPECT_TRUE(was_positive) << "source 0 should weigh at the image centre for this desired camera";
}

TEST(Ulr, SmallCameraMoveChangesImageLittle) {
  const std::vector<SourceView> sources = Ring(12, 1.5);
  const UlrRenderer renderer(&sources, RenderOptions());
  const Camera camera = TestCamera();
  const Rigid3d a = LookAt(Eigen::Vector3d(1.0, 0.8, 3.0), Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
  const Rigid3d b = LookAt(Eigen::Vector3d(1.001, 0.8, 3.0), Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
  const Plane wrong{Eigen::Vector3d(0, 0, 0.6), Eigen::Vector3d::UnitZ()};  // blending matters
  const RenderResult ra = renderer.Render(camera, a, PlaneSurface(wrong, camera, a));
  const RenderResult rb = renderer.Render(camera, b, PlaneSurface(wrong, camera, b));
  cv::Mat diff;
  cv::absdiff(ra.image, rb.image, diff);
  EXPECT_LT(cv::mean(diff)[0] + cv::mean(diff)[1] + cv::mean(diff)[2], 3 * 1.0);
  double max_diff = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
  cv::Point where;
  cv::Mat gray;
  cv::transform(diff, gray, cv::Matx13f(1, 1, 1));
  cv::minMaxLoc(gray, nullptr, nullptr, nullptr, &where);
  EXPECT_LT(max_diff, 12.0) << where << " cov " << int(ra.coverage.at<uint8_t>(where)) << int(rb.coverage.at<uint8_t>(where));
}

TEST(Ulr, MinimalAngularDeviation) {
  const std::vector<SourceView> sources = Ring(8, 1.5);
  RenderOptions options;
  options.gamma = 0;  // angle only
  const UlrRenderer renderer(&sources, options);
  const Eigen::Vector3d p(0.05, -0.02, 0);
  const Eigen::Vector3d desired(1.3, 0.4, 3.0);
  const std::vector<BlendWeight> weights = renderer.Weights(p, desired);
  ASSERT_EQ(weights.size(), 4u);
  // The camera with the smallest angle between its ray and the desired ray weighs most.
  int best = -1;
  double best_angle = 1e9;
  for (size_t i = 0; i < sources.size(); ++i) {
    const Eigen::Vector3d c = sources[i].cam_from_world.Inverse().translation - p;
    const Eigen::Vector3d d = desired - p;
    const double angle = std::atan2(c.cross(d).norm(), c.dot(d));
    if (angle < best_angle) best_angle = angle, best = static_cast<int>(i);
  }
  EXPECT_EQ(weights[0].source, best);
  double sum = 0;
  for (size_t j = 0; j < weights.size(); ++j) {
    sum += weights[j].weight;
    if (j > 0) EXPECT_GE(weights[j - 1].weight, weights[j].weight);
  }
  EXPECT_NEAR(sum, 1.0, 1e-12);
  EXPECT_EQ(weights[3].weight, 0.0);  // the k-th camera is the threshold [U 124]
}

TEST(Ulr, OccludedCameraGetsNoWeight) {
  std::vector<SourceView> sources = Ring(8, 1.5);
  const Eigen::Vector3d p(0.1, 0.1, 0);
  const Eigen::Vector3d desired = sources[2].cam_from_world.Inverse().translation + Eigen::Vector3d(0.05, 0, 0);
  {
    const UlrRenderer renderer(&sources, RenderOptions());
    const std::vector<BlendWeight> weights = renderer.Weights(p, desired);
    ASSERT_FALSE(weights.empty());
    EXPECT_EQ(weights[0].source, 2);
  }
  // Source 2's proxy depth map: the true plane, except an occluder in front of p.
  for (SourceView& s : sources) {
    s.proxy_depth = DepthMap(kWidth, kHeight, 1, 0.f);
    for (int y = 0; y < kHeight; ++y) {
      for (int x = 0; x < kWidth; ++x) {
        const Rigid3d w = s.cam_from_world.Inverse();
        const Eigen::Vector3d ray = w.rotation * s.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
        const double t = -w.translation.z() / ray.z();
        s.proxy_depth.At(x, y) = static_cast<float>((s.cam_from_world * (w.translation + t * ray)).z());
      }
    }
  }
  const Eigen::Vector3d in_cam = sources[2].cam_from_world * p;
  const Eigen::Vector2d pixel = sources[2].camera.ImgFromCam(in_cam);
  sources[2].proxy_depth.At(static_cast<int>(pixel.x()), static_cast<int>(pixel.y())) = static_cast<float>(in_cam.z() * 0.5);
  const UlrRenderer renderer(&sources, RenderOptions());
  const std::vector<BlendWeight> weights = renderer.Weights(p, desired);
  ASSERT_FALSE(weights.empty());
  for (const BlendWeight& w : weights) EXPECT_NE(w.source, 2) << "an occluded camera must get no weight";
}

TEST(Ulr, TiedPenaltiesGiveUniformWeightsNotNaN) {
  // Four cameras symmetric about the desired ray: equal angle penalties.
  std::vector<SourceView> sources;
  for (int i = 0; i < 4; ++i) {
    const double a = M_PI / 2 * i;
    sources.push_back(PlaneView(Eigen::Vector3d(0.5 * std::cos(a), 0.5 * std::sin(a), 3.0), "s" + std::to_string(i)));
  }
  for (bool epipole : {true, false}) {
    RenderOptions options;
    options.epipole_consistent = epipole;
    const UlrRenderer renderer(&sources, options);
    const std::vector<BlendWeight> weights = renderer.Weights(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 3.0));
    ASSERT_EQ(weights.size(), 4u);
    for (const BlendWeight& w : weights) {
      EXPECT_TRUE(std::isfinite(w.weight));
      EXPECT_NEAR(w.weight, 0.25, 1e-9);
    }
  }
}

TEST(Ulr, WeightsStayContinuousWhenEveryCameraNearsItsBorder) {
  // Three cameras looking straight down from (0, y_i, 3): a ground point walking along +x nears the
  // right border of all three images at once (same u, same field-of-view penalty), so beyond some
  // point every penalty exceeds max_penalty. The weights must not jump there (they did, to 1/3
  // each, giving a camera with a penalty of ~1e27 a third of the pixel).
  std::vector<SourceView> sources;
  for (const double y : {0.1, 0.3, 0.5}) {
    SourceView view = PlaneView(Eigen::Vector3d(0, y, 3), "y" + std::to_string(y));
    view.cam_from_world = LookAt(Eigen::Vector3d(0, y, 3), Eigen::Vector3d(0, y, 0), Eigen::Vector3d(0, 1, 0));
    sources.push_back(view);
  }
  const UlrRenderer renderer(&sources, RenderOptions());
  const Eigen::Vector3d desired(0, 0.25, 3.0);  // nearest in angle: source 1 (y = 0.3)
  const SourceView& s = sources[1];
  const Rigid3d world_from_cam = s.cam_from_world.Inverse();
  const auto point_at = [&](double u) {
    const Eigen::Vector3d ray = world_from_cam.rotation * s.camera.CamFromImg(Eigen::Vector2d(u, kHeight / 2.0));
    return Eigen::Vector3d(world_from_cam.translation + (-world_from_cam.translation.z() / ray.z()) * ray);
  };
  const auto weights_at = [&](double u) {
    std::vector<double> w(sources.size(), 0.0);
    double smallest = std::numeric_limits<double>::infinity();
    for (const BlendWeight& b : renderer.Weights(point_at(u), desired)) {
      EXPECT_TRUE(std::isfinite(b.weight)) << "u=" << u;
      w[b.source] = b.weight;
      smallest = std::min(smallest, b.penalty);
    }
    return std::make_pair(w, smallest);
  };
  // The image side of the point where the smallest penalty reaches max_penalty (pi), by bisection.
  double inside = kWidth / 2.0, outside = kWidth - 0.5 - 1e-9;
  ASSERT_LT(weights_at(inside).second, M_PI);
  ASSERT_GT(weights_at(outside).second, M_PI);
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (inside + outside);
    (weights_at(mid).second < M_PI ? inside : outside) = mid;
  }
  const std::vector<double> before = weights_at(inside).first, after = weights_at(outside).first;
  for (size_t i = 0; i < sources.size(); ++i) EXPECT_NEAR(before[i], after[i], 1e-6) << "source " << i;
  EXPECT_NEAR(after[1], 1.0, 1e-6);
  // And on towards the border, every penalty far beyond max_penalty: still the nearest camera.
  for (double u = outside; u < kWidth - 0.5; u += 0.01) {
    const std::vector<double> w = weights_at(u).first;
    EXPECT_DOUBLE_EQ(w[1], 1.0) << "u=" << u;
    EXPECT_EQ(w[0] + w[2], 0.0) << "u=" << u;
  }
}

TEST(Ulr, FewerThanKCamerasHandled) {
  const std::vector<SourceView> one = {PlaneView(Eigen::Vector3d(0.3, 0, 3), "a")};
  const UlrRenderer renderer(&one, RenderOptions());
  const std::vector<BlendWeight> w1 = renderer.Weights(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 3));
  ASSERT_EQ(w1.size(), 1u);
  EXPECT_DOUBLE_EQ(w1[0].weight, 1.0);
  const std::vector<SourceView> two = {PlaneView(Eigen::Vector3d(0.3, 0, 3), "a"),
                                       PlaneView(Eigen::Vector3d(-0.6, 0, 3), "b")};
  const UlrRenderer renderer2(&two, RenderOptions());
  const std::vector<BlendWeight> w2 = renderer2.Weights(Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 0, 3));
  ASSERT_EQ(w2.size(), 2u);
  EXPECT_EQ(w2[0].source, 0);
  EXPECT_NEAR(w2[0].weight + w2[1].weight, 1.0, 1e-12);
  // A point no camera sees: not covered.
  EXPECT_TRUE(renderer2.Weights(Eigen::Vector3d(100, 0, 0), Eigen::Vector3d(0, 0, 3)).empty());
}

// A 2 x 2 render from 4 x 4 sub-samples: the covered fraction becomes the pixel's alpha, the
// colour is premultiplied (missed sub-samples black); FillHoles fills pixels covered less than half.
TEST(Downsample, PartlyCoveredPixelsKeepTheirShareAndLessThanHalfIsFilled) {
  RenderResult fine;
  fine.image = cv::Mat(4, 4, CV_8UC3, cv::Scalar::all(0));
  fine.coverage = cv::Mat(4, 4, CV_8UC1, cv::Scalar::all(0));
  ProxySurface surface;
  surface.width = surface.height = 4;
  surface.hit.assign(16, 0);
  auto sample = [&](int x, int y, bool hit, bool coloured) {
    surface.hit[y * 4 + x] = hit;
    if (coloured) {
      fine.image.at<cv::Vec3b>(y, x) = cv::Vec3b(200, 200, 200);
      fine.coverage.at<uint8_t>(y, x) = 255;
    }
  };
  sample(0, 0, true, true);  // pixel (0, 0): one of four sub-samples on the model, three miss it
  for (int y = 0; y < 2; ++y)
    for (int x = 2; x < 4; ++x) sample(x, y, true, true);  // pixel (1, 0): all four
  sample(0, 2, true, true);                                 // pixel (0, 1): one coloured, three hit
  sample(1, 2, true, false);                                // the model where no source sees it
  sample(0, 3, true, false);
  sample(1, 3, true, false);
  const RenderResult coarse = Downsample(fine, surface, 2);  // pixel (1, 1): nothing
  EXPECT_EQ(coarse.coverage.at<uint8_t>(0, 0), 64);
  EXPECT_EQ(coarse.image.at<cv::Vec3b>(0, 0), cv::Vec3b(50, 50, 50));
  EXPECT_EQ(coarse.coverage.at<uint8_t>(0, 1), 255);
  EXPECT_EQ(coarse.image.at<cv::Vec3b>(0, 1), cv::Vec3b(200, 200, 200));
  EXPECT_EQ(coarse.coverage.at<uint8_t>(1, 0), 255);  // the unseen sub-samples are left out
  EXPECT_EQ(coarse.image.at<cv::Vec3b>(1, 0), cv::Vec3b(200, 200, 200));
  EXPECT_EQ(coarse.coverage.at<uint8_t>(1, 1), 0);
  EXPECT_EQ(coarse.image.at<cv::Vec3b>(1, 1), cv::Vec3b(0, 0, 0));
  EXPECT_EQ(coarse.covered_pixels, 3u);

  RenderResult background;
  background.image = cv::Mat(2, 2, CV_8UC3, cv::Scalar::all(100));
  background.coverage = cv::Mat(2, 2, CV_8UC1, cv::Scalar::all(255));
  const RenderResult filled = FillHoles(coarse, background);
  EXPECT_EQ(filled.image.at<cv::Vec3b>(0, 0), cv::Vec3b(100, 100, 100));  // a quarter: the background's
  EXPECT_EQ(filled.image.at<cv::Vec3b>(0, 1), cv::Vec3b(200, 200, 200));
  EXPECT_EQ(filled.image.at<cv::Vec3b>(1, 1), cv::Vec3b(100, 100, 100));
  EXPECT_EQ(filled.covered_pixels, 4u);
  EXPECT_EQ(cv::countNonZero(filled.coverage == 255), 4);
}

// A capture composited on a colour (import.alpha composite): every model's render goes over that
// colour as the photos' alpha went over it: holes take it, covered pixels keep their colour, a
// partly covered one (premultiplied, coverage as alpha) blends as the composited photo does.
TEST(FillWithColour, HolesTakeTheCapturesBackgroundAndEdgesBlendByCoverage) {
  RenderResult render;
  render.image = cv::Mat(1, 3, CV_8UC3, cv::Scalar::all(0));
  render.coverage = cv::Mat(1, 3, CV_8UC1, cv::Scalar::all(0));
  render.image.at<cv::Vec3b>(0, 0) = cv::Vec3b(10, 20, 30);  // covered
  render.coverage.at<uint8_t>(0, 0) = 255;
  render.image.at<cv::Vec3b>(0, 1) = cv::Vec3b(25, 25, 25);  // a quarter covered by a colour of 100
  render.coverage.at<uint8_t>(0, 1) = 64;
  render.covered_pixels = 2;
  for (const cv::Vec3b colour : {cv::Vec3b(255, 255, 255), cv::Vec3b(0, 0, 0), cv::Vec3b(40, 80, 120)}) {
    const RenderResult filled = FillWithColour(render, colour);
    EXPECT_EQ(filled.image.at<cv::Vec3b>(0, 0), cv::Vec3b(10, 20, 30));
    EXPECT_EQ(filled.image.at<cv::Vec3b>(0, 2), colour) << "a hole takes the background";
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(filled.image.at<cv::Vec3b>(0, 1)[c], 25 + colour[c] * 191.0 / 255, 0.51);
    EXPECT_EQ(filled.covered_pixels, 3u);
    EXPECT_EQ(cv::countNonZero(filled.coverage == 255), 3);
  }
}

TEST(ProxyPlane, MeanInverseDepthAndNearestToAxes) {
  const Rigid3d cam = LookAt(Eigen::Vector3d(0, 0, 5), Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
  Plane plane;
  ASSERT_TRUE(PlaneAtMeanInverseDepth({Eigen::Vector3d(0, 0, 3), Eigen::Vector3d(0, 0, 1)}, cam, &plane));
  // depths 2 and 4: 1 / mean(1/2, 1/4) = 8/3
  EXPECT_NEAR((plane.point - Eigen::Vector3d(0, 0, 5)).norm(), 8.0 / 3.0, 1e-12);
  EXPECT_NEAR(plane.normal.z(), -1.0, 1e-12);
  Eigen::Vector3d point;
  ASSERT_TRUE(PointNearestToAxes({Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 0)},
                                 {Eigen::Vector3d(-1, 0, 0.1), Eigen::Vector3d(0, -1, 0.1)}, &point));
  EXPECT_NEAR(point.x(), point.y(), 1e-9);
  EXPECT_FALSE(PointNearestToAxes({Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1, 0, 0)},
                                  {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(0, 0, 1)}, &point));
}

// The adapter on a tiny workspace: plane + a mesh of the true ground + a missing hull.
TEST(RenderStage, RendersHeldOutViewsAndSkipsMissingProxy) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_render_test_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "images");
  const std::vector<SourceView> views = Ring(8, 1.5);
  SparseModel model;
  model.cameras[1] = TestCamera();
  for (size_t i = 0; i < views.size(); ++i) {
    Image image;
    image.image_id = static_cast<int>(i) + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    image.cam_from_world = views[i].cam_from_world;
    model.images[image.image_id] = image;
    WriteImage((root / "images" / image.name).string(), views[i].image);
  }
  WriteSparseModelText((root / "sparse").string(), model);
  TriangleMesh ground;
  ground.vertices = {{-5, -5, 0}, {5, -5, 0}, {5, 5, 0}, {-5, 5, 0}};
  ground.faces = {{0, 1, 2}, {0, 2, 3}};
  fs::create_directories(root / "ground_truth");
  WriteMeshPly((root / "ground_truth/mesh.ply").string(), ground);

  StageRegistry registry;
  RegisterStage_render(&registry);
  const Stage* stage = registry.Find("render");
  ASSERT_NE(stage, nullptr);
  StageContext context;
  context.workspace = Workspace(root.string());
  context.role = stage->Role();
  context.heldout_images = {"v0.png", "v4.png"};
  context.params = DefaultParams(*stage);
  context.params.Set("proxies", std::vector<std::string>{"ground_truth/mesh.ply", "plane", "hull/hull.ply", "splat_depth",
                                                         "splat_surfels"});
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  NullProgress progress;
  context.progress = &progress;
  stage->Run(context);
  EXPECT_TRUE(fs::exists(root / "renders/ground_truth_mesh/v0.png"));
  EXPECT_TRUE(fs::exists(root / "renders/plane/v4.coverage.png"));
  EXPECT_TRUE(fs::exists(root / "renders/v4.png"));
  const nlohmann::json summary = nlohmann::json::parse(std::ifstream((root / "renders/renders.json").string()));
  EXPECT_EQ(summary["primary"], "ground_truth_mesh");
  ASSERT_EQ(summary["proxies"].size(), 5u);
  EXPECT_EQ(summary["proxies"][2]["status"], "skipped");
  EXPECT_NE(summary["proxies"][2]["reason"].get<std::string>().find("hull/hull.ply"), std::string::npos);
  // No depth maps and no surfels in this workspace: the splat models are skipped, naming the file.
  EXPECT_EQ(summary["proxies"][3]["status"], "skipped");
  EXPECT_NE(summary["proxies"][3]["reason"].get<std::string>().find(".geometric.bin"), std::string::npos)
      << summary["proxies"][3]["reason"];
  EXPECT_EQ(summary["proxies"][4]["status"], "skipped");
  EXPECT_NE(summary["proxies"][4]["reason"].get<std::string>().find("surfels/surfels.ply"), std::string::npos);
  // background: plane fills the mesh model's holes in a second image; the plane itself has none.
  EXPECT_TRUE(fs::exists(root / "renders/ground_truth_mesh/v0.filled.png"));
  EXPECT_TRUE(fs::exists(root / "renders/ground_truth_mesh/v0.filled.coverage.png"));
  EXPECT_FALSE(fs::exists(root / "renders/plane/v0.filled.png"));
  for (const auto& name : {"v1.png", "v2.png", "v3.png", "v5.png"}) {
    EXPECT_NE(std::find(summary["training_views"].begin(), summary["training_views"].end(), name),
              summary["training_views"].end());
  }
  // The true ground as a mesh proxy predicts the held-out photo well.
  const cv::Mat rendered = ReadImageColor((root / "renders/ground_truth_mesh/v0.png").string());
  const cv::Mat coverage = ReadImageUnchanged((root / "renders/ground_truth_mesh/v0.coverage.png").string());
  EXPECT_GT(cv::countNonZero(coverage), kWidth * kHeight / 2);
  EXPECT_GT(Psnr(rendered, views[0].image, coverage), 28.0);
  fs::remove_all(root);
}

// A workspace of the ring of 8 plane views (v0.png .. v7.png; `extra` adds more images at v0's
// pose) and a render context with every parameter at its default.
struct RenderWorkspace {
  fs::path root;
  StageRegistry registry;
  const Stage* stage = nullptr;
  StageContext context;
  NullProgress progress;

  RenderWorkspace(const std::string& tag, const std::vector<std::string>& extra) {
    root = fs::temp_directory_path() / ("ibmr_render_" + tag + "_" + std::to_string(::getpid()));
    fs::remove_all(root);
    fs::create_directories(root / "images");
    const std::vector<SourceView> views = Ring(8, 1.5);
    SparseModel model;
    model.cameras[1] = TestCamera();
    std::vector<std::string> names;
    for (size_t i = 0; i < views.size(); ++i) names.push_back("v" + std::to_string(i) + ".png");
    names.insert(names.end(), extra.begin(), extra.end());
    for (size_t i = 0; i < names.size(); ++i) {
      Image image;
      image.image_id = static_cast<int>(i) + 1;
      image.camera_id = 1;
      image.name = names[i];
      image.cam_from_world = views[i < views.size() ? i : 0].cam_from_world;
      model.images[image.image_id] = image;
      fs::create_directories((root / "images" / image.name).parent_path());
      WriteImage((root / "images" / image.name).string(), views[i < views.size() ? i : 0].image);
    }
    WriteSparseModelText((root / "sparse").string(), model);
    RegisterStage_render(&registry);
    stage = registry.Find("render");
    context.workspace = Workspace(root.string());
    context.role = stage->Role();
    context.params = DefaultParams(*stage);
    context.params.Set("proxies", std::vector<std::string>{"plane"});
    context.progress = &progress;
  }
  ~RenderWorkspace() { fs::remove_all(root); }
};

TEST(RenderStage, RefusesViewsWhoseFilesWouldCollide) {
  RenderWorkspace ws("stems", {"v0.jpg", "left/v1.png"});
  ws.context.heldout_images = {"v0.png", "v0.jpg"};
  try {
    ws.stage->Run(ws.context);
    ADD_FAILURE() << "v0.png and v0.jpg would both write renders/<proxy>/v0.png";
  } catch (const InputError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("\"v0.png\""), std::string::npos) << message;
    EXPECT_NE(message.find("\"v0.jpg\""), std::string::npos) << message;
    EXPECT_NE(message.find("rename"), std::string::npos) << message;
  }
  ws.context.heldout_images = {"v1.png", "left/v1.png"};  // one stem in two folders
  EXPECT_THROW(ws.stage->Run(ws.context), InputError);
  EXPECT_FALSE(fs::exists(ws.root / "renders/plane/v1.png")) << "refused before anything is written";
}

TEST(RenderStage, CheckParamsNamesCollidingProxiesAndADegenerateLookAt) {
  RenderWorkspace ws("params", {});
  Params params = ws.context.params;
  params.Set("proxies", std::vector<std::string>{"plane", "hull/hull.ply", "hull.ply"});
  std::optional<ParamError> error = ws.stage->CheckParams(params);
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ(error->key, "proxies");
  EXPECT_NE(error->message.find("hull/hull.ply"), std::string::npos) << error->message;
  EXPECT_NE(error->message.find("\"hull.ply\""), std::string::npos) << error->message;
  params.Set("proxies", std::vector<std::string>{"plane", "hull/hull.ply", "hull2=hull.ply"});
  EXPECT_FALSE(ws.stage->CheckParams(params).has_value());

  params.Set("novel_look_at", std::vector<double>{1, 2, 3, 1, 2, 3});
  error = ws.stage->CheckParams(params);
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ(error->key, "novel_look_at");
  params.Set("novel_look_at", std::vector<double>{1, 2, 3, 0, 0, 0});
  EXPECT_FALSE(ws.stage->CheckParams(params).has_value());
}

TEST(RenderStage, ARenderWithoutFillRemovesAnEarlierRunsFilledImages) {
  RenderWorkspace ws("filled", {});
  TriangleMesh ground;
  ground.vertices = {{-0.5, -0.5, 0}, {0.5, -0.5, 0}, {0.5, 0.5, 0}, {-0.5, 0.5, 0}};  // leaves holes
  ground.faces = {{0, 1, 2}, {0, 2, 3}};
  fs::create_directories(ws.root / "ground_truth");
  WriteMeshPly((ws.root / "ground_truth/mesh.ply").string(), ground);
  ws.context.heldout_images = {"v0.png"};
  ws.context.params.Set("proxies", std::vector<std::string>{"ground_truth/mesh.ply", "plane"});
  ws.stage->Run(ws.context);
  ASSERT_TRUE(fs::exists(ws.root / "renders/ground_truth_mesh/v0.filled.png"));
  ws.context.params.Set("background", std::string("none"));
  ws.stage->Run(ws.context);
  EXPECT_FALSE(fs::exists(ws.root / "renders/ground_truth_mesh/v0.filled.png"));
  EXPECT_FALSE(fs::exists(ws.root / "renders/ground_truth_mesh/v0.filled.coverage.png"));
  const nlohmann::json summary = nlohmann::json::parse(std::ifstream((ws.root / "renders/renders.json").string()));
  EXPECT_FALSE(summary["proxies"][0]["views"]["v0.png"].contains("filled"));
}

// With background: plane, the plane model takes the background's render (drawn once): the same
// image, coverage and facts as the plane drawn on its own (background: none), for a held-out view
// and for a training view left out of its own sources.
TEST(RenderStage, PlaneModelFromTheBackgroundEqualsItsOwnRender) {
  RenderWorkspace ws("plane_background", {});
  TriangleMesh ground;
  ground.vertices = {{-0.5, -0.5, 0}, {0.5, -0.5, 0}, {0.5, 0.5, 0}, {-0.5, 0.5, 0}};
  ground.faces = {{0, 1, 2}, {0, 2, 3}};
  fs::create_directories(ws.root / "ground_truth");
  WriteMeshPly((ws.root / "ground_truth/mesh.ply").string(), ground);
  ws.context.heldout_images = {"v0.png"};
  ws.context.params.Set("views", std::vector<std::string>{"v0.png", "v3.png"});
  ws.context.params.Set("proxies", std::vector<std::string>{"ground_truth/mesh.ply", "plane"});
  const auto read = [&](const std::string& stem) {
    return std::make_tuple(ReadImageColor((ws.root / ("renders/plane/" + stem + ".png")).string()),
                           ReadImageUnchanged((ws.root / ("renders/plane/" + stem + ".coverage.png")).string()),
                           nlohmann::json::parse(std::ifstream((ws.root / ("renders/plane/" + stem + ".json")).string())));
  };
  ws.stage->Run(ws.context);
  ASSERT_TRUE(fs::exists(ws.root / "renders/ground_truth_mesh/v0.filled.png"));  // the background was drawn
  const auto [image0, coverage0, facts0] = read("v0");
  const auto [image3, coverage3, facts3] = read("v3");
  ws.context.params.Set("background", std::string("none"));
  ws.stage->Run(ws.context);
  const auto [own_image0, own_coverage0, own_facts0] = read("v0");
  const auto [own_image3, own_coverage3, own_facts3] = read("v3");
  EXPECT_GT(cv::countNonZero(own_coverage0), 0);
  EXPECT_EQ(cv::norm(image0, own_image0, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(coverage0, own_coverage0, cv::NORM_INF), 0);
  EXPECT_EQ(facts0, own_facts0);
  EXPECT_EQ(cv::norm(image3, own_image3, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(coverage3, own_coverage3, cv::NORM_INF), 0);
  EXPECT_EQ(facts3, own_facts3);
  EXPECT_EQ(facts3["sources"], 6);  // v3 left out of the 7 training views
}

// Leave-one-out for `layers`: a training view rendered with exclude_self does not use its own
// reference set, which would reproduce its photo at angle 0.
TEST(Layers, ExcludedReferenceSetIsNotUsed) {
  const Camera camera = Camera::Pinhole(32, 24, 30, 30, 16, 12);
  const auto set_at = [&](const std::string& name, const Eigen::Vector3d& eye, const cv::Scalar& bgr) {
    LayerSet set;
    set.image = name;
    set.camera = camera;
    set.cam_from_world = LookAt(eye, Eigen::Vector3d(eye.x(), eye.y(), 4), Eigen::Vector3d(0, -1, 0));
    SpriteLayer layer;
    layer.normal = Eigen::Vector3d::UnitZ();
    layer.offset = 4;  // the plane z = 4
    layer.rgba = cv::Mat(24, 32, CV_8UC4, cv::Scalar(bgr[0], bgr[1], bgr[2], 255));
    set.layers.push_back(layer);
    return set;
  };
  std::vector<LayerSet> sets = {set_at("a.png", {0, 0, 0}, cv::Scalar(0, 0, 255)),
                                set_at("b.png", {0.2, 0, 0}, cv::Scalar(255, 0, 0))};
  const Rigid3d at_a = sets[0].cam_from_world;
  const LayersRenderer renderer(std::move(sets), 2, Eigen::Vector3d(0, 0, 4));
  EXPECT_TRUE(renderer.HasSet("a.png"));
  EXPECT_FALSE(renderer.HasSet("c.png"));
  const RenderResult with_self = renderer.Render(camera, at_a);
  const RenderResult without = renderer.Render(camera, at_a, "a.png");
  const cv::Point centre(16, 12);
  ASSERT_EQ(with_self.coverage.at<uint8_t>(centre), 255);
  EXPECT_GT(with_self.image.at<cv::Vec3b>(centre)[2], 200);  // its own (red) layer dominates at angle 0
  ASSERT_EQ(without.coverage.at<uint8_t>(centre), 255);
  EXPECT_EQ(without.image.at<cv::Vec3b>(centre), cv::Vec3b(255, 0, 0));  // only b's (blue) layer
}

// A renderer that reads its reference sets from their folders for each view (the stage's way:
// only the sets a view is drawn from are in memory) draws what the sets in memory draw, two
// layers overlapping; a set whose sprite went missing is an IoError naming the file.
TEST(Layers, SetsReadFromTheirFoldersDrawAsTheSetsInMemory) {
  const Camera camera = Camera::Pinhole(40, 30, 36, 36, 20, 15);
  const auto set_at = [&](const std::string& name, const Eigen::Vector3d& eye) {
    LayerSet set;
    set.image = name;
    set.camera = camera;
    set.cam_from_world = LookAt(eye, Eigen::Vector3d(eye.x(), eye.y(), 4), Eigen::Vector3d(0, -1, 0));
    SpriteLayer back, front;
    back.normal = front.normal = Eigen::Vector3d::UnitZ();
    back.offset = 4;   // the plane z = 4, all of the view, a gradient
    front.offset = 3;  // z = 3, the left half, nearer
    back.rgba = cv::Mat(30, 40, CV_8UC4);
    front.rgba = cv::Mat(30, 40, CV_8UC4, cv::Scalar(0, 0, 0, 0));
    for (int y = 0; y < 30; ++y) {
      for (int x = 0; x < 40; ++x) {
        back.rgba.at<cv::Vec4b>(y, x) = cv::Vec4b(static_cast<uint8_t>(6 * x), static_cast<uint8_t>(8 * y), 90, 255);
        if (x < 20) front.rgba.at<cv::Vec4b>(y, x) = cv::Vec4b(30, 200, static_cast<uint8_t>(10 * y), 255);
      }
    }
    set.layers = {back, front};
    return set;
  };
  std::vector<LayerSet> sets = {set_at("a.png", {0, 0, 0}), set_at("b.png", {0.3, 0, 0})};
  const fs::path root = fs::temp_directory_path() / ("ibmr_layers_folders_" + std::to_string(::getpid()));
  fs::remove_all(root);
  std::vector<LayerSet> headers;
  std::vector<std::string> folders;
  for (const LayerSet& set : sets) {
    folders.push_back((root / set.image).string());
    WriteLayerSet(folders.back(), set);
    headers.push_back(ReadLayerSet(folders.back()));
    for (SpriteLayer& layer : headers.back().layers) layer.rgba.release(), layer.residual.release();
  }
  const LayersRenderer in_memory(sets, 2, Eigen::Vector3d(0, 0, 4));
  const LayersRenderer from_folders(headers, folders, 2, Eigen::Vector3d(0, 0, 4));
  const Rigid3d between = LookAt({0.12, 0.05, 0}, Eigen::Vector3d(0.12, 0.05, 4), Eigen::Vector3d(0, -1, 0));
  const RenderResult expected = in_memory.Render(camera, between);
  const RenderResult drawn = from_folders.Render(camera, between);
  ASSERT_GT(expected.covered_pixels, 1000);
  EXPECT_EQ(drawn.covered_pixels, expected.covered_pixels);
  EXPECT_EQ(cv::norm(drawn.image, expected.image, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(drawn.coverage, expected.coverage, cv::NORM_INF), 0);
  // The front layer hides the back one on the left: its green shows there.
  EXPECT_GT(drawn.image.at<cv::Vec3b>(15, 5)[1], 190);

  fs::remove(root / "b.png" / "layer_1.png");
  try {
    from_folders.Render(camera, between);
    ADD_FAILURE() << "a missing sprite must be an IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("layer_1.png"), std::string::npos) << e.what();
  }
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
