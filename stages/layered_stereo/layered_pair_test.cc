// Tests of the two-view layered method (layered_pair.h): options, a synthetic rectified pair of two
// planes with a known answer (planes, occlusion boundary, disparity), and the registry entry.
#include "stages/layered_stereo/layered_pair.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <opencv2/imgproc.hpp>
#include <random>
#include <stdexcept>
#include <string>

#include "pipeline/core/two_view_methods.h"

namespace ibmr {
namespace {

// ---------------------------------------------------------------- options

TEST(LayeredPairOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(LayeredPairOptions().Check(&error)) << error;
}

struct InvalidOption {
  std::string name;  // the error must start with it
  std::function<void(LayeredPairOptions*)> set;
};

class LayeredPairOptionsInvalid : public testing::TestWithParam<InvalidOption> {};

TEST_P(LayeredPairOptionsInvalid, RefusedNamingTheOption) {
  LayeredPairOptions options;
  GetParam().set(&options);
  std::string error;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind(GetParam().name, 0), 0u) << error;
}

INSTANTIATE_TEST_SUITE_P(
    Ranges, LayeredPairOptionsInvalid,
    testing::Values(
        InvalidOption{"max_layers", [](LayeredPairOptions* o) { o->max_layers = 0; }},
        InvalidOption{"max_layers", [](LayeredPairOptions* o) { o->max_layers = 65; }},
        InvalidOption{"inlier_tolerance", [](LayeredPairOptions* o) { o->inlier_tolerance = 0; }},
        InvalidOption{"inlier_tolerance", [](LayeredPairOptions* o) { o->inlier_tolerance = NAN; }},
        InvalidOption{"min_layer_fraction", [](LayeredPairOptions* o) { o->min_layer_fraction = 0; }},
        InvalidOption{"min_layer_fraction", [](LayeredPairOptions* o) { o->min_layer_fraction = 1; }},
        InvalidOption{"ransac_iterations", [](LayeredPairOptions* o) { o->ransac_iterations = 0; }},
        InvalidOption{"sample_radius", [](LayeredPairOptions* o) { o->sample_radius = 1; }},
        InvalidOption{"loss_scale", [](LayeredPairOptions* o) { o->loss_scale = -1; }},
        InvalidOption{"residual_range", [](LayeredPairOptions* o) { o->residual_range = -1; }},
        InvalidOption{"residual_range", [](LayeredPairOptions* o) { o->residual_range = 17; }},
        InvalidOption{"residual_penalty", [](LayeredPairOptions* o) { o->residual_penalty = -0.5; }},
        InvalidOption{"window_radius", [](LayeredPairOptions* o) { o->window_radius = 11; }},
        InvalidOption{"initial_weight", [](LayeredPairOptions* o) { o->initial_weight = -1; }},
        InvalidOption{"initial_truncation", [](LayeredPairOptions* o) { o->initial_truncation = 0; }},
        InvalidOption{"smoothness", [](LayeredPairOptions* o) { o->smoothness = -1; }},
        InvalidOption{"edge_threshold", [](LayeredPairOptions* o) { o->edge_threshold = -1; }},
        InvalidOption{"edge_factor", [](LayeredPairOptions* o) { o->edge_factor = 1.5; }},
        InvalidOption{"occlusion_cost", [](LayeredPairOptions* o) { o->occlusion_cost = -1; }},
        InvalidOption{"refinement_passes", [](LayeredPairOptions* o) { o->refinement_passes = 6; }}),
    [](const testing::TestParamInfo<InvalidOption>& info) {
      return info.param.name + "_" + std::to_string(info.index);
    });

// ---------------------------------------------------------------- a synthetic pair of two planes

// A slanted textured background plane and, in front of it, a textured fronto-parallel rectangle:
// left view, right view (rendered from the surfaces' textures, so sub-pixel exact), the true left
// disparity and the left pixels occluded in the right view.
struct TwoPlaneScene {
  static constexpr int kWidth = 200, kHeight = 150;
  static constexpr int kFrontLeft = 70, kFrontRight = 140, kFrontTop = 40, kFrontBottom = 110;  // [left, right)
  static constexpr double kFront = 22.0;                                                      // disparity
  static double Back(double x, double y) { return 8.0 + 0.02 * x + 0.01 * y; }
  static bool InFront(double x, int y) {
    return x >= kFrontLeft && x < kFrontRight && y >= kFrontTop && y < kFrontBottom;
  }

  cv::Mat left, right, truth;  // 8-bit grey, 8-bit grey, CV_32F
  cv::Mat occluded;            // CV_8U, 1: the left pixel is hidden (or outside) in the right view
};

// Random texture, smoothed so that bilinear sampling between pixels is meaningful.
cv::Mat Texture(int width, int height, uint64_t seed) {
  cv::Mat noise(height, width, CV_32F);
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::UNIFORM, 0.0, 255.0);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 0.8);
  cv::normalize(noise, noise, 10, 245, cv::NORM_MINMAX);
  return noise;
}

float Sample(const cv::Mat& texture, double x, int y) {
  const int x0 = static_cast<int>(std::floor(x));
  const double f = x - x0;
  const int a = std::clamp(x0, 0, texture.cols - 1), b = std::clamp(x0 + 1, 0, texture.cols - 1);
  return static_cast<float>((1 - f) * texture.at<float>(y, a) + f * texture.at<float>(y, b));
}

TwoPlaneScene MakeTwoPlaneScene() {
  using S = TwoPlaneScene;
  TwoPlaneScene scene;
  // Textures indexed by the left-image x of the surface point (offset: left of the image too).
  constexpr int kMargin = 64;
  const cv::Mat back = Texture(S::kWidth + 2 * kMargin, S::kHeight, 7), front = Texture(S::kWidth + 2 * kMargin, S::kHeight, 11);
  cv::Mat left(S::kHeight, S::kWidth, CV_32F), right(S::kHeight, S::kWidth, CV_32F);
  scene.truth.create(S::kHeight, S::kWidth, CV_32F);
  scene.occluded.create(S::kHeight, S::kWidth, CV_8U);
  for (int y = 0; y < S::kHeight; ++y) {
    for (int x = 0; x < S::kWidth; ++x) {
      const bool in_front = S::InFront(x, y);
      const double d = in_front ? S::kFront : S::Back(x, y);
      left.at<float>(y, x) = Sample(in_front ? front : back, x + kMargin, y);
      scene.truth.at<float>(y, x) = static_cast<float>(d);
      // Hidden in the right view: outside it, or behind the front rectangle there.
      const double xr = x - d;
      scene.occluded.at<uint8_t>(y, x) = xr < 0 || (!in_front && S::InFront(xr + S::kFront, y));
      // The right pixel xr sees the front rectangle if xr + kFront lies in it, else the background
      // point with x - Back(x, y) = xr.
      const double front_x = x + S::kFront;
      if (S::InFront(front_x, y)) {
        right.at<float>(y, x) = Sample(front, front_x + kMargin, y);
      } else {
        const double back_x = (x + 8.0 + 0.01 * y) / (1.0 - 0.02);
        right.at<float>(y, x) = Sample(back, back_x + kMargin, y);
      }
    }
  }
  left.convertTo(scene.left, CV_8U);
  right.convertTo(scene.right, CV_8U);
  return scene;
}

// What a left-right checked matcher would give: the truth with noise, holes where the pixel is
// occluded and at random, and a few outliers.
cv::Mat NoisyInitial(const TwoPlaneScene& scene) {
  cv::Mat initial = scene.truth.clone();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> noise(-0.25f, 0.25f), unit(0.f, 1.f), outlier(1.f, 30.f);
  for (int y = 0; y < initial.rows; ++y) {
    for (int x = 0; x < initial.cols; ++x) {
      float& d = initial.at<float>(y, x);
      const float u = unit(rng);
      if (scene.occluded.at<uint8_t>(y, x) || u < 0.05f) {
        d = -1.f;
      } else if (u < 0.07f) {
        d = outlier(rng);
      } else {
        d += noise(rng);
      }
    }
  }
  return initial;
}

// The index of the result plane closest to (a, b, c) over the image, -1 if none within 0.5 pixel
// of disparity at the corners of the region [x0, x1) x [y0, y1).
int MatchingPlane(const std::vector<DisparityPlane>& planes, const std::function<double(double, double)>& truth,
                  int x0, int x1, int y0, int y1) {
  int best = -1;
  double best_error = 0.5;
  for (size_t l = 0; l < planes.size(); ++l) {
    double error = 0;
    for (const auto& [x, y] : {std::pair{x0, y0}, std::pair{x1 - 1, y0}, std::pair{x0, y1 - 1}, std::pair{x1 - 1, y1 - 1}}) {
      error = std::max(error, std::fabs(planes[l].Disparity(x, y) - truth(x, y)));
    }
    if (error < best_error) best_error = error, best = static_cast<int>(l);
  }
  return best;
}

TEST(LayeredStereoPair, RecoversTwoPlanesAndTheOcclusionBoundary) {
  using S = TwoPlaneScene;
  const TwoPlaneScene scene = MakeTwoPlaneScene();
  const LayeredPairResult result = LayeredStereoPair(scene.left, scene.right, NoisyInitial(scene), 32, LayeredPairOptions());
  ASSERT_GE(result.planes.size(), 2u);
  ASSERT_EQ(result.labels.type(), CV_32S);
  ASSERT_EQ(result.disparity.type(), CV_32F);

  // Both planes, within a fraction of a pixel of disparity over their regions.
  const int back = MatchingPlane(result.planes, S::Back, 0, S::kWidth, 0, S::kHeight);
  const int front = MatchingPlane(result.planes, [](double, double) { return S::kFront; }, S::kFrontLeft,
                                  S::kFrontRight, S::kFrontTop, S::kFrontBottom);
  ASSERT_GE(back, 0);
  ASSERT_GE(front, 0);
  EXPECT_NEAR(result.planes[back].a, 0.02, 0.002);
  EXPECT_NEAR(result.planes[back].b, 0.01, 0.002);
  EXPECT_NEAR(result.planes[back].c, 8.0, 0.3);
  EXPECT_NEAR(result.planes[front].a, 0.0, 0.002);
  EXPECT_NEAR(result.planes[front].b, 0.0, 0.002);
  EXPECT_NEAR(result.planes[front].Disparity(105, 75), S::kFront, 0.1);

  // The front layer's extent in each row inside the rectangle: its left edge is the occlusion
  // boundary (left of it the background is hidden in the right view and must stay background).
  int rows = 0, good_rows = 0;
  for (int y = S::kFrontTop + 2; y < S::kFrontBottom - 2; ++y, ++rows) {
    int first = -1, last = -1;
    for (int x = 0; x < S::kWidth; ++x) {
      if (result.labels.at<int>(y, x) != front) continue;
      if (first < 0) first = x;
      last = x;
    }
    good_rows += std::abs(first - S::kFrontLeft) <= 2 && std::abs(last - (S::kFrontRight - 1)) <= 2;
  }
  EXPECT_GE(good_rows, 0.9 * rows) << good_rows << " of " << rows << " rows";
  size_t occluded = 0, occluded_back = 0;
  for (int y = S::kFrontTop; y < S::kFrontBottom; ++y) {
    for (int x = 0; x < S::kFrontLeft; ++x) {
      if (!scene.occluded.at<uint8_t>(y, x) || x - S::Back(x, y) < 0) continue;
      ++occluded;
      occluded_back += result.labels.at<int>(y, x) == back;
    }
  }
  ASSERT_GT(occluded, 500u);  // the strip left of the rectangle, about 12 pixels wide
  EXPECT_GE(occluded_back, 0.95 * occluded);

  // A disparity everywhere (no holes), within a pixel almost everywhere.
  size_t bad = 0;
  for (int y = 0; y < S::kHeight; ++y) {
    for (int x = 0; x < S::kWidth; ++x) {
      const float d = result.disparity.at<float>(y, x);
      ASSERT_TRUE(d > 0 && std::isfinite(d)) << x << ", " << y;
      bad += std::fabs(d - scene.truth.at<float>(y, x)) > 1.f;
    }
  }
  EXPECT_LT(bad, 0.02 * S::kWidth * S::kHeight);
}

TEST(LayeredStereoPair, SameSeedSameResult) {
  const TwoPlaneScene scene = MakeTwoPlaneScene();
  const cv::Mat initial = NoisyInitial(scene);
  const LayeredPairResult a = LayeredStereoPair(scene.left, scene.right, initial, 32, LayeredPairOptions());
  const LayeredPairResult b = LayeredStereoPair(scene.left, scene.right, initial, 32, LayeredPairOptions());
  EXPECT_EQ(cv::norm(a.disparity, b.disparity, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::countNonZero(a.labels != b.labels), 0);
}

TEST(LayeredStereoPair, RefusesMismatchedInputs) {
  const TwoPlaneScene scene = MakeTwoPlaneScene();
  const cv::Mat initial = NoisyInitial(scene);
  EXPECT_THROW(LayeredStereoPair(scene.left, scene.right(cv::Rect(0, 0, 100, 100)), initial, 32, {}),
               std::invalid_argument);
  EXPECT_THROW(LayeredStereoPair(scene.left, scene.right, initial(cv::Rect(0, 0, 100, 100)), 32, {}),
               std::invalid_argument);
  EXPECT_THROW(LayeredStereoPair(scene.left, scene.right, cv::Mat(initial.size(), CV_32F, cv::Scalar(-1)), 32, {}),
               std::invalid_argument);  // no valid initial disparity
  LayeredPairOptions bad;
  bad.max_layers = 0;
  EXPECT_THROW(LayeredStereoPair(scene.left, scene.right, initial, 32, bad), std::invalid_argument);
}

// ---------------------------------------------------------------- the registry entry

TEST(LayeredTwoView, NeedsThePlaneSweepMethod) {
  RegisterTwoViewMethod("plane_sweep", TwoViewMethod());  // as if no stage registered it
  const TwoPlaneScene scene = MakeTwoPlaneScene();
  try {
    LayeredTwoView(scene.left, scene.right, 32, {});
    FAIL() << "expected std::runtime_error";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("\"plane_sweep\""), std::string::npos) << e.what();
  }
}

TEST(LayeredTwoView, RefusesUnknownAndBadOptions) {
  const TwoPlaneScene scene = MakeTwoPlaneScene();
  auto message = [&](const TwoViewOptions& options) {
    try {
      LayeredTwoView(scene.left, scene.right, 32, options);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no std::invalid_argument");
  };
  EXPECT_NE(message({{"no_such_option", "1"}}).find("no_such_option"), std::string::npos);
  EXPECT_NE(message({{"max_layers", "many"}}).find("max_layers"), std::string::npos);
  EXPECT_NE(message({{"max_layers", "0"}}).find("max_layers"), std::string::npos);
  EXPECT_NE(message({{"subpixel", "yes"}}).find("subpixel"), std::string::npos);
  EXPECT_NE(message({{"smoothness", "1.5x"}}).find("smoothness"), std::string::npos);
}

TEST(LayeredTwoView, StartsFromThePlaneSweepDisparity) {
  const TwoPlaneScene scene = MakeTwoPlaneScene();
  const cv::Mat initial = NoisyInitial(scene);
  TwoViewOptions asked;
  RegisterTwoViewMethod("plane_sweep", [&](const cv::Mat&, const cv::Mat&, int, const TwoViewOptions& options) {
    asked = options;
    return TwoViewOutput{initial.clone(), nullptr};
  });
  const TwoViewOutput output = LayeredTwoView(scene.left, scene.right, 32, {{"max_layers", "4"}, {"subpixel", "false"}});
  RegisterTwoViewMethod("plane_sweep", TwoViewMethod());
  EXPECT_EQ(asked, (TwoViewOptions{{"fill", "false"}}));  // holes kept: they mark occlusions
  ASSERT_EQ(output.disparity.size(), scene.left.size());
  EXPECT_EQ(cv::countNonZero(output.disparity <= 0), 0);
  EXPECT_GE(output.facts.at("layers").get<int>(), 2);
  EXPECT_LE(output.facts.at("layers").get<int>(), 4);
  EXPECT_TRUE(output.facts.contains("initial_seconds"));
}

}  // namespace
}  // namespace ibmr
