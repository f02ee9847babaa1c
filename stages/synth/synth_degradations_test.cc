// The stability matrix's degradations: strength 0 renders the clean scene exactly; each one at
// strength 1 does what it says (texture gone from the patches, a highlight that moves with the
// view, fewer views, cameras off by the stated amount, noise of the stated sigma, per-view gains)
// while the truth (depth, masks, the true mesh's shape) stays the clean scene's.
#include "stages/synth/synth.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <set>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stages/synth/synth_degradations.h"

namespace ibmr {
namespace {

SynthOptions Small(SynthDegradation degradation, double strength) {
  SynthOptions options;
  options.views = 8;
  options.width = 96;
  options.height = 72;
  options.subdivision = 3;
  options.sparse_points = 150;
  options.degradation = degradation;
  options.strength = strength;
  return options;
}

SynthView Render(const SynthOptions& options, int view) { return RenderSynthView(BuildSynthScene(options), view, options); }

// Mean absolute horizontal gradient inside the mask: how much texture a stereo window sees.
double TextureEnergy(const SynthView& view) {
  cv::Mat grey, gradient;
  cv::cvtColor(view.image, grey, cv::COLOR_BGR2GRAY);
  cv::Sobel(grey, gradient, CV_32F, 1, 0);
  cv::Mat inner;
  cv::erode(view.mask, inner, cv::Mat::ones(5, 5, CV_8U));
  return cv::mean(cv::abs(gradient), inner)[0];
}

TEST(SynthDegradations, NamesRoundTripAndStrengthIsChecked) {
  for (const std::string name : {"none", "textureless", "specular", "repetitive", "few_views", "camera_noise",
                                 "image_noise", "exposure", "pose_outliers", "hand_held"}) {
    SynthDegradation d;
    ASSERT_TRUE(SynthDegradationFromName(name, &d)) << name;
    EXPECT_EQ(SynthDegradationName(d), name);
  }
  SynthDegradation d;
  EXPECT_FALSE(SynthDegradationFromName("blur", &d));
  std::string error;
  SynthOptions o = Small(SynthDegradation::kSpecular, 1.5);
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("strength", 0), 0u) << error;
}

TEST(SynthDegradations, StrengthZeroIsTheCleanScene) {
  const SynthView clean = Render(Small(SynthDegradation::kNone, 0), 2);
  for (SynthDegradation d : {SynthDegradation::kTextureless, SynthDegradation::kSpecular, SynthDegradation::kRepetitive,
                             SynthDegradation::kImageNoise, SynthDegradation::kExposure}) {
    const SynthView view = Render(Small(d, 0), 2);
    EXPECT_EQ(cv::norm(view.image, clean.image, cv::NORM_INF), 0) << SynthDegradationName(d);
  }
}

TEST(SynthDegradations, EachChangesTheImagesAndKeepsTheTruth) {
  const SynthOptions clean_options = Small(SynthDegradation::kNone, 0);
  const SynthView clean = Render(clean_options, 2);
  const double clean_texture = TextureEnergy(clean);

  const SynthView flat = Render(Small(SynthDegradation::kTextureless, 1), 2);
  EXPECT_LT(TextureEnergy(flat), 0.35 * clean_texture) << "shading edges remain, texture goes";
  EXPECT_EQ(cv::norm(flat.mask, clean.mask, cv::NORM_L1), 0);
  EXPECT_EQ(flat.depth.data, clean.depth.data);
  const SynthView half = Render(Small(SynthDegradation::kTextureless, 0.5), 2);
  EXPECT_LT(TextureEnergy(half), 0.95 * clean_texture);
  EXPECT_GT(TextureEnergy(half), TextureEnergy(flat));

  // The highlight brightens some surface pixels, and a point's colour then depends on the view.
  const SynthView shiny = Render(Small(SynthDegradation::kSpecular, 1), 2);
  cv::Mat brighter;
  cv::compare(shiny.image, clean.image, brighter, cv::CMP_GT);
  EXPECT_GT(cv::countNonZero(brighter.reshape(1)), 30);
  EXPECT_EQ(shiny.depth.data, clean.depth.data);

  const SynthView stripes = Render(Small(SynthDegradation::kRepetitive, 1), 2);
  EXPECT_GT(cv::norm(stripes.image, clean.image, cv::NORM_L1) / clean.image.total(), 10.0);

  const SynthView noisy = Render(Small(SynthDegradation::kImageNoise, 0.5), 2);
  cv::Mat difference;
  cv::subtract(noisy.image, clean.image, difference, cv::noArray(), CV_32F);
  cv::Scalar mean, sigma;
  cv::meanStdDev(difference.reshape(1), mean, sigma);
  EXPECT_NEAR(sigma[0], 12.0, 1.5) << "sigma 24 * 0.5, a little less where bytes clip";

  // Gains differ from view to view, within +-50%.
  double low = 10, high = 0;
  for (int view = 0; view < 8; ++view) {
    const double ratio = cv::mean(Render(Small(SynthDegradation::kExposure, 1), view).image)[1] /
                         cv::mean(Render(clean_options, view).image)[1];
    low = std::min(low, ratio);
    high = std::max(high, ratio);
  }
  EXPECT_GT(high - low, 0.2);
  EXPECT_GT(low, 0.45);
  EXPECT_LT(high, 1.55);
}

TEST(SynthDegradations, FewViewsAndCameraNoise) {
  EXPECT_EQ(BuildSynthScene(Small(SynthDegradation::kFewViews, 1)).views.size(), 4u);   // 8 * 0.25 = 2, at least 4
  EXPECT_EQ(BuildSynthScene(Small(SynthDegradation::kFewViews, 0.5)).views.size(), 5u);  // 8 * 0.625
  SynthOptions big = Small(SynthDegradation::kFewViews, 1);
  big.views = 24;
  EXPECT_EQ(BuildSynthScene(big).views.size(), 6u);

  const SynthOptions options = Small(SynthDegradation::kCameraNoise, 1);
  const SynthScene scene = BuildSynthScene(options);
  SparseModel model = BuildSynthSparseModel(scene, options, nullptr);
  const SparseModel truth = model;
  scene.degradation.PerturbCameras(&model);
  double angle = 0, shift = 0;
  for (const auto& [id, image] : model.images) {
    const Image& t = truth.images.at(id);
    angle += t.cam_from_world.rotation.angularDistance(image.cam_from_world.rotation) * 180 / M_PI / model.images.size();
    shift += (t.Center() - image.Center()).norm() / model.images.size();
  }
  // Mean of |N(0, sigma I3)| is 1.6 sigma: rotation sigma 1 degree, position sigma 1% of the ring (4).
  EXPECT_GT(angle, 0.7);
  EXPECT_LT(angle, 2.8);
  EXPECT_GT(shift, 0.02);
  EXPECT_LT(shift, 0.13);
  EXPECT_NE(model.cameras.begin()->second.params[0], truth.cameras.begin()->second.params[0]);
}

// pose_outliers turns and moves the written cameras of views 3, 15, ... only, by 5 degrees times
// the strength; PoseDisplacementsPx sees exactly those views move, by more than a pixel.
TEST(SynthDegradations, PoseOutliersMoveOneViewInTwelve) {
  SynthOptions options = Small(SynthDegradation::kPoseOutliers, 0.5);
  options.views = 24;
  const SynthScene scene = BuildSynthScene(options);
  SparseModel model = BuildSynthSparseModel(scene, options, nullptr);
  const SparseModel truth = model;
  scene.degradation.PerturbCameras(&model);
  const std::map<std::string, double> px = PoseDisplacementsPx(truth, model);
  const std::vector<int> ids = model.ImageIdsByName();
  ASSERT_EQ(ids.size(), 24u);
  for (size_t i = 0; i < ids.size(); ++i) {
    const Image& image = model.images.at(ids[i]), &t = truth.images.at(ids[i]);
    const double degrees = t.cam_from_world.rotation.angularDistance(image.cam_from_world.rotation) * 180 / M_PI;
    if (i % 12 == 3) {
      EXPECT_NEAR(degrees, 2.5, 1e-6) << image.name;
      EXPECT_GT(px.at(image.name), 1.0) << image.name;
    } else {
      EXPECT_EQ(degrees, 0) << image.name;
      EXPECT_EQ(px.at(image.name), 0) << image.name;
    }
  }
  EXPECT_EQ(model.cameras.begin()->second.params[0], truth.cameras.begin()->second.params[0]);
}

// hand_held (the forward-facing scene made as hard as a hand-held capture): the true axes are
// no longer parallel (each turned by at most 3 degrees), a plant of thin blades stands in the room
// and is seen, the written cameras are off by about 0.03 degree with the focal exact, gains differ
// within +-15%; the truth keeps the true (turned) cameras.
TEST(SynthDegradations, HandHeldTurnsTheAxesAddsFrondsAndDisturbsThePoses) {
  SynthOptions options = Small(SynthDegradation::kHandHeld, 1);
  options.scene = SynthSceneKind::kForwardFacing;
  options.views = 12;
  options.width = 160;
  options.height = 120;
  SynthOptions clean_options = options;
  clean_options.degradation = SynthDegradation::kNone;
  const SynthScene scene = BuildSynthScene(options), clean = BuildSynthScene(clean_options);
  ASSERT_EQ(scene.views.size(), clean.views.size());
  double largest = 0, smallest = 180;
  for (size_t i = 0; i < scene.views.size(); ++i) {
    const double degrees =
        scene.views[i].cam_from_world.rotation.angularDistance(clean.views[i].cam_from_world.rotation) * 180 / M_PI;
    largest = std::max(largest, degrees);
    smallest = std::min(smallest, degrees);
    EXPECT_LT((scene.views[i].Center() - clean.views[i].Center()).norm(), 1e-9);  // turned about the eye
  }
  EXPECT_LE(largest, 3.0 + 1e-9);
  EXPECT_GT(largest, 1.0);
  int frond_part = -1;
  for (size_t p = 0; p < scene.parts.size(); ++p) {
    if (scene.parts[p].name == "fronds") frond_part = static_cast<int>(p);
  }
  ASSERT_GE(frond_part, 0);
  EXPECT_EQ(std::count(scene.face_part.begin(), scene.face_part.end(), frond_part), 14 * 12);
  for (const SynthPart& part : clean.parts) EXPECT_NE(part.name, "fronds");
  // The back wall gives way to the sky: pixels without depth, in the sky's colour.
  EXPECT_GT(scene.background.minCoeff(), 0.5);
  // The blades are seen: the views differ from the clean scene's where they stand, in front.
  const SynthView view = RenderSynthView(scene, 5, options);
  const SynthView clean_view = RenderSynthView(clean, 5, clean_options);
  int nearer = 0;
  for (int y = 0; y < options.height; ++y) {
    for (int x = 0; x < options.width; ++x) nearer += view.depth.At(x, y) < clean_view.depth.At(x, y) - 0.05f;
  }
  EXPECT_GT(nearer, 0.005 * options.width * options.height);
  int sky = 0;
  for (int y = 0; y < options.height; ++y) {
    for (int x = 0; x < options.width; ++x) sky += !IsValidDepth(view.depth.At(x, y)) && IsValidDepth(clean_view.depth.At(x, y));
  }
  EXPECT_GT(sky, 0.05 * options.width * options.height);

  SparseModel model = BuildSynthSparseModel(scene, options, nullptr);
  const SparseModel truth = model;
  scene.degradation.PerturbCameras(&model);
  double angle = 0;
  for (const auto& [id, image] : model.images) {
    angle += truth.images.at(id).cam_from_world.rotation.angularDistance(image.cam_from_world.rotation) * 180 / M_PI /
             model.images.size();
  }
  EXPECT_GT(angle, 0.01);  // rotation sigma 0.02 degree: mean about 0.032
  EXPECT_LT(angle, 0.06);
  EXPECT_EQ(model.cameras.begin()->second.params[0], truth.cameras.begin()->second.params[0]);
  std::set<double> gains;
  for (int i = 0; i < 12; ++i) {
    EXPECT_NEAR(scene.degradation.Gain(i), 1.0, 0.15 + 1e-12);
    gains.insert(scene.degradation.Gain(i));
  }
  EXPECT_EQ(gains.size(), 12u);
  EXPECT_EQ(scene.degradation.NoiseSigma(), 3.0);
}

}  // namespace
}  // namespace ibmr
