// Tests of the held-out-view metrics (seed 000 lines 5906-5920): PSNR and SSIM known answers,
// coverage and masks, gain correction, nearest-camera angle, option checks, and the adapter on a
// tiny workspace with a skipped proxy.
#include "stages/score/score.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/view_checkpoint.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_score(StageRegistry* registry);

namespace {

cv::Mat Noise(int w, int h, int seed) {
  cv::Mat image(h, w, CV_8UC3);
  cv::RNG rng(0x9E3779B97F4A7C15ull * (seed + 1));  // small seeds give correlated MWC sequences
  rng.fill(image, cv::RNG::UNIFORM, cv::Scalar::all(0), cv::Scalar::all(256));
  cv::GaussianBlur(image, image, cv::Size(5, 5), 1.0);
  return image;
}

TEST(ScoreOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(ScoreOptions().Check(&error)) << error;
}

TEST(ScoreOptions, RejectsBadValues) {
  std::string error;
  ScoreOptions o;
  o.near_angle_deg = -1;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("near_angle_deg:", 0), 0u) << error;
  o = ScoreOptions();
  o.error_gain = 0;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("error_gain:", 0), 0u) << error;
}

TEST(ScoreImage, KnownPsnrSsimAndCoverage) {
  const cv::Mat real = Noise(64, 48, 1);
  cv::Mat rendered = real.clone();
  cv::Mat coverage(48, 64, CV_8UC1, cv::Scalar(0));
  coverage(cv::Rect(0, 0, 32, 48)).setTo(255);
  // Exact on covered pixels, garbage elsewhere: uncovered pixels do not count.
  rendered(cv::Rect(32, 0, 32, 48)).setTo(cv::Scalar(0, 0, 0));
  ImageScore s = ScoreImage(real, rendered, coverage, cv::Mat(), ScoreOptions());
  EXPECT_EQ(s.all.psnr, 100.0);
  EXPECT_NEAR(s.all.ssim, 1.0, 1e-9);
  EXPECT_NEAR(s.all.coverage, 0.5, 1e-12);
  EXPECT_FALSE(s.has_mask);
  // A constant error of 4 levels: MSE 16, PSNR = 10 log10(255^2 / 16).
  cv::Mat shifted;
  cv::Mat(real(cv::Rect(0, 0, 32, 48)) + cv::Scalar(4, 4, 4)).copyTo(shifted);
  cv::Mat clipped = real.clone();
  clipped.setTo(cv::Scalar(100, 100, 100));
  rendered = clipped + cv::Scalar(4, 4, 4);
  s = ScoreImage(clipped, rendered, coverage, cv::Mat(), ScoreOptions());
  EXPECT_NEAR(s.all.psnr, 10 * std::log10(255.0 * 255.0 / 16.0), 1e-9);
  // SSIM of noise against other noise is low.
  s = ScoreImage(real, Noise(64, 48, 2), coverage, cv::Mat(), ScoreOptions());
  EXPECT_LT(s.all.ssim, 0.3);
}

TEST(ScoreImage, MaskedVariantAndGainCorrection) {
  const cv::Mat real = Noise(64, 48, 3);
  cv::Mat rendered;
  real.convertTo(rendered, CV_8UC3, 0.8);  // a darker exposure
  const cv::Mat coverage(48, 64, CV_8UC1, cv::Scalar(255));
  cv::Mat mask(48, 64, CV_8UC1, cv::Scalar(0));
  mask(cv::Rect(10, 10, 30, 20)).setTo(255);
  const ImageScore plain = ScoreImage(real, rendered, coverage, mask, ScoreOptions());
  ASSERT_TRUE(plain.has_mask);
  EXPECT_EQ(plain.mask.pixels, 600u);
  EXPECT_NEAR(plain.mask.coverage, 1.0, 1e-12);
  ScoreOptions gain;
  gain.gain_correction = true;
  const ImageScore corrected = ScoreImage(real, rendered, coverage, mask, gain);
  EXPECT_NEAR(corrected.gains[0], 1.25, 0.02);
  EXPECT_GT(corrected.all.psnr, plain.all.psnr + 10);
}

// Lit photo pixels with holes counted black: a half-covered exact render of a uniformly lit photo
// has the MSE of the uncovered half against black; dark pixels of the photo do not count.
TEST(ScoreImage, PhotoScoreCountsHolesAsBlack) {
  cv::Mat real(48, 64, CV_8UC3, cv::Scalar(100, 100, 100));
  real(cv::Rect(0, 40, 64, 8)).setTo(cv::Scalar(10, 15, 20));  // dark background rows: not counted
  cv::Mat coverage(48, 64, CV_8UC1, cv::Scalar(0));
  coverage(cv::Rect(0, 0, 32, 48)).setTo(255);
  const ImageScore s = ScoreImage(real, real.clone(), coverage, cv::Mat(), ScoreOptions());
  EXPECT_EQ(s.all.psnr, 100.0);
  EXPECT_EQ(s.photo.pixels, 64u * 40u);
  EXPECT_NEAR(s.photo.coverage, 0.5, 1e-12);
  EXPECT_NEAR(s.photo.psnr, 10 * std::log10(255.0 * 255.0 / (0.5 * 100 * 100)), 1e-9);
  ScoreOptions every;
  every.photo_threshold = -1;
  EXPECT_EQ(ScoreImage(real, real.clone(), coverage, cv::Mat(), every).photo.pixels, 64u * 48u);
  every.photo_threshold = 256;
  std::string error;
  EXPECT_FALSE(every.Check(&error));
  EXPECT_EQ(error.rfind("photo_threshold:", 0), 0u) << error;
}

// SSIM as Wang et al. define it (11x11 Gaussian window, sigma 1.5, C1 = (0.01 L)^2, C2 = (0.03 L)^2,
// mean over the channels), written with OpenCV's matrix expressions, averaged over the pixels whose
// window lies inside the image (a fully covered render).
double ReferenceSsim(const cv::Mat& a8, const cv::Mat& b8) {
  const double c1 = (0.01 * 255) * (0.01 * 255), c2 = (0.03 * 255) * (0.03 * 255);
  std::vector<cv::Mat> ca, cb;
  cv::split(a8, ca);
  cv::split(b8, cb);
  cv::Mat mean = cv::Mat::zeros(a8.size(), CV_64F);
  for (size_t c = 0; c < ca.size(); ++c) {
    cv::Mat a, b, mu_a, mu_b, aa, bb, ab;
    ca[c].convertTo(a, CV_64F);
    cb[c].convertTo(b, CV_64F);
    cv::GaussianBlur(a, mu_a, cv::Size(11, 11), 1.5);
    cv::GaussianBlur(b, mu_b, cv::Size(11, 11), 1.5);
    cv::GaussianBlur(a.mul(a), aa, cv::Size(11, 11), 1.5);
    cv::GaussianBlur(b.mul(b), bb, cv::Size(11, 11), 1.5);
    cv::GaussianBlur(a.mul(b), ab, cv::Size(11, 11), 1.5);
    const cv::Mat var_a = aa - mu_a.mul(mu_a), var_b = bb - mu_b.mul(mu_b), cov = ab - mu_a.mul(mu_b);
    cv::Mat ssim;
    cv::divide((2 * mu_a.mul(mu_b) + c1).mul(2 * cov + c2), (mu_a.mul(mu_a) + mu_b.mul(mu_b) + c1).mul(var_a + var_b + c2), ssim);
    mean += ssim / static_cast<double>(ca.size());
  }
  return cv::mean(mean(cv::Rect(5, 5, a8.cols - 10, a8.rows - 10)))[0];
}

// The stage's SSIM follows the definition, and working images reused across calls of different
// sizes (as the stage's threads reuse theirs) change nothing.
TEST(ScoreImage, SsimFollowsTheDefinitionWithReusedBuffers) {
  SsimBuffers buffers;
  int seed = 5;
  for (const cv::Size size : {cv::Size(64, 48), cv::Size(64, 48), cv::Size(37, 53), cv::Size(64, 48)}) {
    const cv::Mat real = Noise(size.width, size.height, seed++);  // other images at the same size too
    cv::Mat rendered;
    cv::GaussianBlur(real, rendered, cv::Size(3, 3), 0.8);  // a softer render, partly correlated
    rendered += cv::Scalar(3, 0, 7);
    const cv::Mat coverage(size, CV_8UC1, cv::Scalar(255));
    const double expected = ReferenceSsim(real, rendered);
    EXPECT_GT(expected, 0.2);
    EXPECT_LT(expected, 0.95);
    // The stage blurs in float (score.cc): 1e-6 of the definition's double value.
    EXPECT_NEAR(ScoreImage(real, rendered, coverage, cv::Mat(), ScoreOptions(), &buffers).all.ssim, expected, 1e-6);
    EXPECT_NEAR(ScoreImage(real, rendered, coverage, cv::Mat(), ScoreOptions()).all.ssim, expected, 1e-6);
  }
  // Bright, nearly flat images, where E[a^2] - E[a]^2 cancels most: variances of a few grey
  // levels against means near 250.
  for (int seed = 30; seed < 33; ++seed) {
    const cv::Mat real = cv::Scalar::all(245) + Noise(64, 48, seed) / 32;
    const cv::Mat rendered = cv::Scalar::all(246) + Noise(64, 48, seed + 10) / 32;
    const cv::Mat coverage(48, 64, CV_8UC1, cv::Scalar(255));
    const double expected = ReferenceSsim(real, rendered);
    EXPECT_LT(expected, 0.999);
    EXPECT_NEAR(ScoreImage(real, rendered, coverage, cv::Mat(), ScoreOptions(), &buffers).all.ssim, expected, 1e-5);
  }
  // A render that is not black where uncovered: the photo score's second SSIM map (holes black)
  // is computed while the first is in use, with the same buffers.
  const cv::Mat real = Noise(64, 48, 11);
  const cv::Mat rendered = Noise(64, 48, 12);
  cv::Mat coverage(48, 64, CV_8UC1, cv::Scalar(0));
  coverage(cv::Rect(0, 0, 40, 48)).setTo(255);
  ScoreOptions every;
  every.photo_threshold = -1;
  const ImageScore reused = ScoreImage(real, rendered, coverage, cv::Mat(), every, &buffers);
  const ImageScore fresh = ScoreImage(real, rendered, coverage, cv::Mat(), every);
  EXPECT_EQ(reused.all.ssim, fresh.all.ssim);
  EXPECT_EQ(reused.photo.ssim, fresh.photo.ssim);
  EXPECT_NE(reused.photo.ssim, reused.all.ssim);
}

// The photo's statistics prepared once (the stage's cache) give every score exactly as computed afresh,
// with a mask, for the photo score's second SSIM map and with reused buffers; a reference of
// another size is refused.
TEST(ScoreImage, PreparedPhotoStatisticsGiveIdenticalScores) {
  const cv::Mat real = Noise(64, 48, 21);
  const SsimReference reference = PrepareSsimReference(real);
  SsimBuffers buffers;
  cv::Mat mask(48, 64, CV_8UC1, cv::Scalar(0));
  mask(cv::Rect(8, 4, 40, 36)).setTo(255);
  ScoreOptions every;
  every.photo_threshold = -1;
  for (int seed = 22; seed < 25; ++seed) {
    cv::Mat rendered;
    cv::GaussianBlur(real, rendered, cv::Size(3, 3), 0.8);
    rendered += Noise(64, 48, seed) / 16;
    cv::Mat coverage(48, 64, CV_8UC1, cv::Scalar(0));
    coverage(cv::Rect(0, 0, 30 + 8 * (seed - 22), 48)).setTo(255);
    const ImageScore fresh = ScoreImage(real, rendered, coverage, mask, every);
    const ImageScore prepared = ScoreImage(real, rendered, coverage, mask, every, &buffers, &reference);
    EXPECT_EQ(prepared.all.ssim, fresh.all.ssim);
    EXPECT_EQ(prepared.all.psnr, fresh.all.psnr);
    EXPECT_EQ(prepared.mask.ssim, fresh.mask.ssim);
    EXPECT_EQ(prepared.photo.ssim, fresh.photo.ssim);
    EXPECT_NE(prepared.photo.ssim, prepared.all.ssim);  // the second map was computed
  }
  const cv::Mat other = Noise(32, 48, 1);
  EXPECT_THROW(ScoreImage(other, other, cv::Mat(48, 32, CV_8UC1, cv::Scalar(255)), cv::Mat(), every, &buffers, &reference),
               std::invalid_argument);
}

TEST(ScoreImage, RejectsSizeMismatch) {
  EXPECT_THROW(ScoreImage(Noise(8, 8, 1), Noise(9, 8, 1), cv::Mat(8, 8, CV_8UC1), cv::Mat(), ScoreOptions()),
               std::invalid_argument);
}

TEST(NearestCameraAngle, RingAngles) {
  const Eigen::Vector3d c = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> ring;
  for (int i = 0; i < 8; ++i) ring.push_back(Eigen::Vector3d(std::cos(M_PI / 4 * i), std::sin(M_PI / 4 * i), 0.3));
  int nearest = -1;
  const Eigen::Vector3d query(std::cos(0.2), std::sin(0.2), 0.3);
  const double angle = NearestCameraAngleDeg(query, ring, c, &nearest);
  EXPECT_EQ(nearest, 0);
  EXPECT_GT(angle, 10.0);
  EXPECT_LT(angle, 11.5);
  EXPECT_NEAR(NearestCameraAngleDeg(ring[3], ring, c, &nearest), 0.0, 1e-9);  // same position
}

TEST(ScoreStage, WritesHeldoutJsonWithSkippedProxy) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_score_test_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "images");
  fs::create_directories(root / "renders/plane");
  fs::create_directories(root / "ground_truth/masks");
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(64, 48, 60, 60, 32, 24);
  for (int i = 0; i < 4; ++i) {
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    const double a = M_PI / 2 * i;
    image.cam_from_world = LookAt(Eigen::Vector3d(3 * std::cos(a), 3 * std::sin(a), 1), Eigen::Vector3d::Zero(),
                                  Eigen::Vector3d(0, 0, 1));
    model.images[image.image_id] = image;
    WriteImage((root / "images" / image.name).string(), Noise(64, 48, i));
  }
  WriteSparseModelText((root / "sparse").string(), model);
  cv::Mat render = Noise(64, 48, 0);
  WriteImage((root / "renders/plane/v0.png").string(), render);
  WriteImage((root / "renders/plane/v0.coverage.png").string(), cv::Mat(48, 64, CV_8UC1, cv::Scalar(255)));
  WriteImage((root / "ground_truth/masks/v0.png.png").string(), cv::Mat(48, 64, CV_8UC1, cv::Scalar(255)));
  const nlohmann::json summary = {
      {"primary", "plane"},
      {"proxies",
       {{{"name", "plane"}, {"status", "rendered"}, {"views", {{"v0.png", {{"sources", 3}}}}}},
        {{"name", "hull"}, {"status", "skipped"}, {"reason", "hull/hull.ply does not exist"}}}}};
  ASSERT_TRUE(summary["proxies"].is_array()) << summary.dump();
  ASSERT_TRUE(summary["proxies"][0]["views"]["v0.png"].is_object()) << summary.dump();
  WriteFileAtomic((root / "renders/renders.json").string(), summary.dump());

  StageRegistry registry;
  RegisterStage_score(&registry);
  const Stage* stage = registry.Find("score");
  StageContext context;
  context.workspace = Workspace(root.string());
  context.role = stage->Role();
  context.heldout_images = {"v0.png"};
  context.params.Set("gain_correction", false);
  context.params.Set("near_angle_deg", 1.0);
  context.params.Set("error_gain", int64_t{4});
  context.params.Set("photo_threshold", int64_t{20});
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  NullProgress progress;
  context.progress = &progress;
  stage->Run(context);
  const nlohmann::json out = nlohmann::json::parse(std::ifstream((root / "scores/heldout.json").string()));
  const nlohmann::json& view = out["proxies"]["plane"]["views"]["v0.png"];
  EXPECT_EQ(view["psnr"].get<double>(), 100.0);
  EXPECT_EQ(view["mask"], "ground_truth/masks/v0.png.png");
  // Cameras 90 degrees apart on the ring, 1 unit up, seen from the point their axes meet (origin).
  EXPECT_NEAR(view["nearest_training_angle_deg"].get<double>(), std::acos(0.1) * 180 / M_PI, 1e-6);
  EXPECT_EQ(out["proxies"]["plane"]["mean"]["views"], 1);
  EXPECT_EQ(out["proxies"]["hull"]["status"], "skipped");
  EXPECT_TRUE(fs::exists(root / "scores/plane/v0.png"));
  EXPECT_EQ(ReadImageColor((root / "scores/plane/v0.png").string()).cols, 3 * 64);
  fs::remove_all(root);
}

TEST(MeanOfFinitePoints, SkipsNonFinitePoints) {
  Eigen::Vector3d mean(7, 7, 7);
  EXPECT_FALSE(MeanOfFinitePoints({}, &mean));
  EXPECT_FALSE(MeanOfFinitePoints({Eigen::Vector3d(NAN, 0, 0)}, &mean));
  EXPECT_EQ(mean, Eigen::Vector3d(7, 7, 7));
  ASSERT_TRUE(MeanOfFinitePoints({Eigen::Vector3d(1, 2, 3), Eigen::Vector3d(NAN, 0, 0), Eigen::Vector3d(3, 4, INFINITY),
                                  Eigen::Vector3d(3, 2, 1)},
                                 &mean));
  EXPECT_EQ(mean, Eigen::Vector3d(2, 2, 2));
}

// Renders as renders.json lists them: the file its entry names, the filled variant only when the
// entry has one (not a stale file of an earlier run), no PSNR / SSIM for a view with no covered
// pixel (and means over the views that have them), and a missing render names the file and says
// to re-run render.
TEST(ScoreStage, ScoresWhatRendersJsonListsAndLeavesUncoveredViewsOutOfMeans) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_score_listed_test_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "images");
  fs::create_directories(root / "renders/plane");
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(64, 48, 60, 60, 32, 24);
  for (int i = 0; i < 5; ++i) {
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    const double a = 2 * M_PI / 5 * i;
    image.cam_from_world = LookAt(Eigen::Vector3d(3 * std::cos(a), 3 * std::sin(a), 1), Eigen::Vector3d::Zero(),
                                  Eigen::Vector3d(0, 0, 1));
    model.images[image.image_id] = image;
    WriteImage((root / "images" / image.name).string(), Noise(64, 48, i));
  }
  WriteSparseModelText((root / "sparse").string(), model);
  const cv::Mat full(48, 64, CV_8UC1, cv::Scalar(255)), none(48, 64, CV_8UC1, cv::Scalar(0));
  // v0: exact, with a stale filled render of an earlier run (its entry lists none).
  WriteImage((root / "renders/plane/v0.png").string(), Noise(64, 48, 0));
  WriteImage((root / "renders/plane/v0.coverage.png").string(), full);
  WriteImage((root / "renders/plane/v0.filled.png").string(), Noise(64, 48, 9));
  WriteImage((root / "renders/plane/v0.filled.coverage.png").string(), full);
  // v1: covers nothing.
  WriteImage((root / "renders/plane/v1.png").string(), cv::Mat(48, 64, CV_8UC3, cv::Scalar::all(0)));
  WriteImage((root / "renders/plane/v1.coverage.png").string(), none);
  // v2: exact, under the name its entry gives (not rebuilt from the image name); a decoy where the
  // rebuilt name would point.
  WriteImage((root / "renders/plane/other_v2.png").string(), Noise(64, 48, 2));
  WriteImage((root / "renders/plane/other_v2.coverage.png").string(), full);
  WriteImage((root / "renders/plane/v2.png").string(), Noise(64, 48, 7));
  WriteImage((root / "renders/plane/v2.coverage.png").string(), full);
  nlohmann::json views = {{"v0.png", {{"sources", 3}, {"render", "renders/plane/v0.png"}}},
                          {"v1.png", {{"sources", 3}, {"render", "renders/plane/v1.png"}}},
                          {"v2.png", {{"sources", 3}, {"render", "renders/plane/other_v2.png"}}}};
  const auto write_renders_json = [&]() {
    const nlohmann::json summary = {
        {"primary", "plane"},
        {"proxies", nlohmann::json::array({{{"name", "plane"}, {"status", "rendered"}, {"views", views}}})}};
    WriteFileAtomic((root / "renders/renders.json").string(), summary.dump());
  };
  write_renders_json();

  StageRegistry registry;
  RegisterStage_score(&registry);
  const Stage* stage = registry.Find("score");
  StageContext context;
  context.workspace = Workspace(root.string());
  context.role = stage->Role();
  context.heldout_images = {"v0.png", "v1.png", "v2.png", "v3.png"};
  context.params.Set("gain_correction", false);
  context.params.Set("near_angle_deg", 1.0);
  context.params.Set("error_gain", int64_t{4});
  context.params.Set("photo_threshold", int64_t{20});
  NullProgress progress;
  context.progress = &progress;
  stage->Run(context);
  const nlohmann::json out = nlohmann::json::parse(std::ifstream((root / "scores/heldout.json").string()));
  const nlohmann::json& scored = out["proxies"]["plane"]["views"];
  EXPECT_EQ(scored["v0.png"]["psnr"].get<double>(), 100.0);
  EXPECT_FALSE(scored["v0.png"].contains("filled_psnr")) << "a stale .filled.png was scored";
  EXPECT_FALSE(scored["v1.png"].contains("psnr"));
  EXPECT_FALSE(scored["v1.png"].contains("ssim"));
  EXPECT_EQ(scored["v1.png"]["coverage"].get<double>(), 0.0);
  EXPECT_EQ(scored["v2.png"]["psnr"].get<double>(), 100.0);
  EXPECT_EQ(scored["v2.png"]["render"], "renders/plane/other_v2.png");
  EXPECT_TRUE(fs::exists(root / "scores/plane/other_v2.png"));
  const nlohmann::json& mean = out["proxies"]["plane"]["mean"];
  EXPECT_EQ(mean["views"], 3);
  EXPECT_EQ(mean["psnr"].get<double>(), 100.0) << "the uncovered view counted as 0 dB";
  EXPECT_NEAR(mean["coverage"].get<double>(), 2.0 / 3.0, 1e-12);

  // A listed render that is gone: the error names it and says to re-run render.
  views["v3.png"] = {{"sources", 3}, {"render", "renders/plane/v3.png"}};
  write_renders_json();
  try {
    stage->Run(context);
    ADD_FAILURE() << "a missing render was not reported";
  } catch (const InputError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("renders/plane/v3.png"), std::string::npos) << message;
    EXPECT_NE(message.find("re-run the render stage"), std::string::npos) << message;
  }
  fs::remove_all(root);
}

// A workspace of `count` views on a ring (64x48 noise photos), each rendered exactly by the
// proxy "plane"; returns the stage context for it.
StageContext ExactRendersWorkspace(const fs::path& root, int count) {
  fs::remove_all(root);
  fs::create_directories(root / "images");
  fs::create_directories(root / "renders/plane");
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(64, 48, 60, 60, 32, 24);
  nlohmann::json views = nlohmann::json::object();
  StageContext context;
  for (int i = 0; i < count; ++i) {
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "v" + std::to_string(i) + ".png";
    const double a = 2 * M_PI / count * i;
    image.cam_from_world = LookAt(Eigen::Vector3d(3 * std::cos(a), 3 * std::sin(a), 1), Eigen::Vector3d::Zero(),
                                  Eigen::Vector3d(0, 0, 1));
    model.images[image.image_id] = image;
    WriteImage((root / "images" / image.name).string(), Noise(64, 48, i));
    const std::string render = "renders/plane/v" + std::to_string(i) + ".png";
    WriteImage((root / render).string(), Noise(64, 48, i));
    WriteImage((root / ("renders/plane/v" + std::to_string(i) + ".coverage.png")).string(),
               cv::Mat(48, 64, CV_8UC1, cv::Scalar(255)));
    views[image.name] = {{"sources", 3}, {"render", render}};
    context.heldout_images.insert(image.name);
  }
  WriteSparseModelText((root / "sparse").string(), model);
  const nlohmann::json summary = {
      {"primary", "plane"},
      {"proxies", nlohmann::json::array({{{"name", "plane"}, {"status", "rendered"}, {"views", views}}})}};
  WriteFileAtomic((root / "renders/renders.json").string(), summary.dump());
  context.workspace = Workspace(root.string());
  context.role = HoldoutRole::kScoring;
  context.params.Set("gain_correction", false);
  context.params.Set("near_angle_deg", 1.0);
  context.params.Set("error_gain", int64_t{4});
  context.params.Set("photo_threshold", int64_t{20});
  return context;
}

// The renders are the stage's per-view items (<proxy>/<image>): scored one at a time when the
// budget says so, each marked done with its scores, and a run stopped part-way resumes from the
// marks (a marked render is not scored again; a mark under another key does not count).
TEST(ScoreStage, ScoresRendersAsPerViewItemsThatResume) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_score_items_test_" + std::to_string(::getpid()));
  StageContext context = ExactRendersWorkspace(root, 3);
  StageRegistry registry;
  RegisterStage_score(&registry);
  const Stage* stage = registry.Find("score");
  // About 120 bytes a pixel of the largest view.
  EXPECT_NEAR(stage->ViewMemoryMb(context), 64 * 48 * 120.0 / 1048576.0, 1e-9);
  NullProgress progress;
  context.progress = &progress;
  context.max_views_in_flight = 1;
  context.checkpoint = ViewCheckpoint((root / "records/score.views").string(), "key-1");
  stage->Run(context);
  for (const char* name : {"v0.png", "v1.png", "v2.png"}) {
    EXPECT_TRUE(fs::exists(root / "records/score.views/plane" / (std::string(name) + ".done"))) << name;
  }
  auto read_psnr = [&](const std::string& view) {
    const nlohmann::json out = nlohmann::json::parse(std::ifstream((root / "scores/heldout.json").string()));
    return out["proxies"]["plane"]["views"][view]["psnr"].get<double>();
  };
  EXPECT_EQ(read_psnr("v1.png"), 100.0);
  // A mark with other scores stands for the render's scoring: the stage takes them as they are.
  nlohmann::json piece = nlohmann::json::parse(std::ifstream((root / "scores/heldout.json").string()))["proxies"]["plane"]["views"]["v1.png"];
  piece["psnr"] = 12.5;
  context.checkpoint.MarkDone("plane/v1.png", piece);
  stage->Run(context);
  EXPECT_EQ(read_psnr("v1.png"), 12.5);
  EXPECT_EQ(read_psnr("v0.png"), 100.0);
  // Another key (changed inputs or parameters): every render is scored again.
  context.checkpoint = ViewCheckpoint((root / "records/score.views").string(), "key-2");
  stage->Run(context);
  EXPECT_EQ(read_psnr("v1.png"), 100.0);
  // A renders.json (edited by hand) listing one proxy name twice: refused, not mixed.
  nlohmann::json renders = nlohmann::json::parse(std::ifstream((root / "renders/renders.json").string()));
  renders["proxies"].push_back(renders["proxies"][0]);
  WriteFileAtomic((root / "renders/renders.json").string(), renders.dump());
  try {
    stage->Run(context);
    ADD_FAILURE() << "a proxy listed twice was scored";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("listed twice"), std::string::npos) << e.what();
  }
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
