// The splat fit on in-memory data: a set of known discs recovered from its renders (held-out views
// within a tolerance, far better than where the fit started); a small step against the gradient
// lowers the objective; density control keeps the count within its cap, leaves no NaN, and a split
// changes the image little against removing the splat; bad options and inputs are refused.
#include "stages/splat_fit/splat_fit.h"
#include "stages/splat_fit/photometric_loss.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include <random>

namespace ibmr {
namespace {

SplatCamera LookingAt(const Eigen::Vector3f& eye, int size = 64) {
  SplatCamera camera;
  camera.width = camera.height = size;
  camera.fx = camera.fy = 1.2f * size;
  camera.cx = camera.cy = 0.5f * size;
  const Eigen::Vector3f forward = (-eye).normalized();
  Eigen::Vector3f right = forward.cross(Eigen::Vector3f::UnitZ());
  if (right.norm() < 1e-3f) right = Eigen::Vector3f::UnitX();
  right.normalize();
  const Eigen::Vector3f down = forward.cross(right);
  camera.rotation.row(0) = right;
  camera.rotation.row(1) = down;
  camera.rotation.row(2) = forward;
  camera.translation = -camera.rotation * eye;
  return camera;
}

// 40 discs on a sphere of radius 0.6, facing out, each its own colour.
GaussianSplats KnownDiscs() {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> unit(0, 1);
  GaussianSplats splats;
  for (int i = 0; i < 40; ++i) {
    const float z = 2 * unit(rng) - 1, phi = 6.2831853f * unit(rng);
    const Eigen::Vector3f n(std::sqrt(1 - z * z) * std::cos(phi), std::sqrt(1 - z * z) * std::sin(phi), z);
    splats.Add(0.6f * n, RotationWithNormal(n), Eigen::Vector2f(std::log(0.12f + 0.05f * unit(rng)), std::log(0.12f)), 0.9f,
               Eigen::Vector3f(unit(rng), unit(rng), unit(rng)));
  }
  return splats;
}

std::vector<SplatFitView> Views(const GaussianSplats& truth, const std::vector<Eigen::Vector3f>& eyes,
                                const Eigen::Vector3f& background) {
  std::vector<SplatFitView> views;
  for (const Eigen::Vector3f& eye : eyes) {
    SplatFitView view;
    view.camera = LookingAt(eye);
    SplatFrame frame;
    SplatRasterOptions options;
    options.background = background;
    RenderSplats(truth, view.camera, options, &frame);
    view.image = frame.image.clone();
    views.push_back(view);
  }
  return views;
}

double Psnr(const GaussianSplats& splats, const SplatFitView& view, const Eigen::Vector3f& background) {
  SplatFrame frame;
  SplatRasterOptions options;
  options.background = background;
  RenderSplats(splats, view.camera, options, &frame);
  cv::Mat diff = frame.image - view.image;
  const double mse = cv::mean(diff.mul(diff))[0] / 3 + cv::mean(diff.mul(diff))[1] / 3 + cv::mean(diff.mul(diff))[2] / 3;
  return 10 * std::log10(1.0 / std::max(mse, 1e-12));
}

std::vector<Eigen::Vector3f> Ring(int count, float elevation, float offset) {
  std::vector<Eigen::Vector3f> eyes;
  for (int i = 0; i < count; ++i) {
    const float a = 6.2831853f * (i + offset) / count;
    eyes.push_back(3.0f * Eigen::Vector3f(std::cos(elevation) * std::cos(a), std::cos(elevation) * std::sin(a), std::sin(elevation)));
  }
  return eyes;
}

// 600 steps, view-independent colour, no density control (a known count): the fits that compare
// one option on and off.
SplatFitOptions ShortFixedFit() {
  SplatFitOptions options;
  options.iterations = 600;
  options.sh_degree = 0;
  options.densify_from = 100000;
  return options;
}

TEST(SplatFit, KnownDiscsAreRecoveredFromTheirRenders) {
  const Eigen::Vector3f background(1, 1, 1);
  const GaussianSplats truth = KnownDiscs();
  std::vector<Eigen::Vector3f> eyes = Ring(12, 0.3f, 0.0f);
  const std::vector<Eigen::Vector3f> low = Ring(6, -0.4f, 0.5f);
  eyes.insert(eyes.end(), low.begin(), low.end());
  const std::vector<SplatFitView> training = Views(truth, eyes, background);
  const std::vector<SplatFitView> heldout = Views(truth, Ring(5, 0.1f, 0.25f), background);
  // Start: the discs moved by 0.03, grey, half as opaque, radii off by a third.
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0, 1);
  GaussianSplats start = truth;
  for (size_t i = 0; i < start.size(); ++i) {
    start.position[i] += 0.03f * Eigen::Vector3f(noise(rng), noise(rng), noise(rng));
    start.log_scale[i] += Eigen::Vector2f::Constant(std::log(1.33f));
    start.opacity_logit[i] = 0.0f;
    for (int c = 0; c < 3; ++c) start.Sh(i)[c] = 0.0f;
  }
  double before = 0;
  for (const SplatFitView& view : heldout) before += Psnr(start, view, background) / heldout.size();
  SplatFitOptions options;
  options.iterations = 600;
  options.sh_degree = 0;
  options.coarse_fraction = 0.2;
  options.densify_from = 100000;  // known count: no density control here
  options.lr_position = 2e-3;
  options.lr_position_final = 2e-4;
  GaussianSplats fitted = start;
  const SplatFitResult result = FitSplats(training, background, options, &fitted, nullptr);
  double after = 0;
  for (const SplatFitView& view : heldout) after += Psnr(fitted, view, background) / heldout.size();
  EXPECT_GT(after, before + 8) << "held out: " << before << " -> " << after << " dB";
  EXPECT_GT(after, 28.0) << "held-out PSNR of the recovered discs";
  ASSERT_FALSE(result.curve.empty());
  EXPECT_LT(result.curve.back().l1, result.curve.front().l1);
}

// Photos whose exposure differs (each view's image times its own RGB gain, within +-20%): with
// view_gains the fit recovers each view's gains up to the views' common factor and predicts
// held-out views (drawn at the mean exposure) better than the fit that must average them.
TEST(SplatFit, ViewGainsRecoverEachPhotosExposure) {
  const Eigen::Vector3f background(0, 0, 0);
  const GaussianSplats truth = KnownDiscs();
  std::vector<Eigen::Vector3f> eyes = Ring(12, 0.3f, 0.0f);
  const std::vector<Eigen::Vector3f> low = Ring(6, -0.4f, 0.5f);
  eyes.insert(eyes.end(), low.begin(), low.end());
  std::vector<SplatFitView> training = Views(truth, eyes, background);
  const std::vector<SplatFitView> heldout = Views(truth, Ring(5, 0.1f, 0.25f), background);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> spread(-0.2f, 0.2f);
  std::vector<Eigen::Vector3f> true_gains;
  for (SplatFitView& view : training) {
    true_gains.emplace_back(1 + spread(rng), 1 + spread(rng), 1 + spread(rng));
    cv::multiply(view.image, cv::Scalar(true_gains.back()[0], true_gains.back()[1], true_gains.back()[2]), view.image);
  }
  // The held-out photos are at the training gains' geometric mean, which the fit's gains are
  // normalised to.
  Eigen::Vector3f mean_log = Eigen::Vector3f::Zero();
  for (const Eigen::Vector3f& g : true_gains) mean_log += g.array().log().matrix() / true_gains.size();
  std::vector<SplatFitView> heldout_photos = heldout;
  for (SplatFitView& view : heldout_photos) {
    const Eigen::Vector3f g = mean_log.array().exp();
    cv::multiply(view.image, cv::Scalar(g[0], g[1], g[2]), view.image);
  }
  SplatFitOptions options = ShortFixedFit();
  options.lr_gain = 0.01;
  double psnr[2];
  for (const bool gains : {false, true}) {
    options.view_gains = gains;
    // Start: each disc's colour off by up to 0.1 (as a stereo point's colour is, from one photo).
    GaussianSplats fitted = truth;
    std::mt19937 colour_rng(13);
    std::uniform_real_distribution<float> off(-0.1f / 0.2820948f, 0.1f / 0.2820948f);  // SH DC units
    for (size_t i = 0; i < fitted.size(); ++i) {
      for (int c = 0; c < 3; ++c) fitted.Sh(i)[c] += off(colour_rng);
    }
    const SplatFitResult result = FitSplats(training, background, options, &fitted, nullptr);
    psnr[gains] = 0;
    for (const SplatFitView& view : heldout_photos) psnr[gains] += Psnr(fitted, view, background) / heldout_photos.size();
    if (!gains) {
      EXPECT_TRUE(result.view_gains.empty());
      continue;
    }
    ASSERT_EQ(result.view_gains.size(), training.size());
    double worst = 0;
    for (size_t v = 0; v < training.size(); ++v) {
      const Eigen::Array3f expected = (true_gains[v].array().log() - mean_log.array()).exp();
      worst = std::max(worst, static_cast<double>((result.view_gains[v].array() / expected - 1).abs().maxCoeff()));
    }
    EXPECT_LT(worst, 0.03) << "largest relative error of a recovered gain";
  }
  EXPECT_GT(psnr[1], psnr[0] + 3) << "held out without gains " << psnr[0] << " dB, with " << psnr[1] << " dB";
}

// The backdrop: every disc on the sphere (radius 2 x the 99th percentile of the points' distances
// from the cameras' centre), facing it, each block of every view covered by a disc within one
// spacing of its centre ray, in the block's colour for the first view, fewer discs than blocks
// where views overlap; bad arguments refused.
TEST(SplatFit, TheBackdropCoversEveryViewBehindThePoints) {
  const GaussianSplats truth = KnownDiscs();  // within 0.72 of the origin
  std::vector<SplatFitView> views = Views(truth, {Eigen::Vector3f(0, -3, 0.2f), Eigen::Vector3f(0.3f, -3, 0.2f)}, Eigen::Vector3f(0.2f, 0.4f, 0.9f));
  GaussianSplats splats = truth;
  const size_t before = splats.size();
  const int step = 8;
  const size_t added = AddBackdrop(views, step, 2.0, 0.3f, &splats);
  ASSERT_EQ(splats.size(), before + added);
  const int blocks = (64 / step) * (64 / step);
  EXPECT_GT(added, static_cast<size_t>(blocks));      // the second view adds what the first does not see
  EXPECT_LT(added, static_cast<size_t>(2 * blocks));  // and leaves out what it does
  const Eigen::Vector3f mean = 0.5f * (views[0].camera.Centre() + views[1].camera.Centre());
  std::vector<double> distances;
  for (size_t i = 0; i < before; ++i) distances.push_back((truth.position[i] - mean).norm());
  std::sort(distances.begin(), distances.end());
  const double radius = 2.0 * distances[distances.size() * 99 / 100];
  for (size_t i = before; i < splats.size(); ++i) {
    EXPECT_NEAR((splats.position[i] - mean).norm(), radius, 1e-3 * radius);
    const Eigen::Vector3f normal = RotationMatrix(splats.rotation[i]).col(2);
    EXPECT_GT(normal.dot((mean - splats.position[i]).normalized()), 0.999f);
  }
  for (const SplatFitView& view : views) {
    const Eigen::Matrix3f world_from_cam = view.camera.rotation.transpose();
    for (int y = step / 2; y < 64; y += step) {
      for (int x = step / 2; x < 64; x += step) {
        const Eigen::Vector3f ray = (world_from_cam * Eigen::Vector3f((x - view.camera.cx) / view.camera.fx,
                                                                       (y - view.camera.cy) / view.camera.fy, 1)).normalized();
        float nearest = 1e9f;
        for (size_t i = before; i < splats.size(); ++i) {
          const Eigen::Vector3f to = splats.position[i] - view.camera.Centre();
          nearest = std::min(nearest, (to - to.dot(ray) * ray).norm());
        }
        const float spacing = static_cast<float>(step * radius / view.camera.fx);
        EXPECT_LT(nearest, 1.5f * spacing) << x << "," << y;
      }
    }
  }
  // The first view's first block (its top left): the block's mean colour.
  const cv::Scalar block = cv::mean(views[0].image(cv::Rect(0, 0, step, step)));
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(splats.Sh(before)[c] * 0.2820948f + 0.5f, block[c], 1e-4);
  EXPECT_THROW(AddBackdrop(views, 0, 2.0, 0.3f, &splats), std::invalid_argument);
  EXPECT_THROW(AddBackdrop(views, 8, 1.0, 0.3f, &splats), std::invalid_argument);
  GaussianSplats none;
  EXPECT_THROW(AddBackdrop(views, 8, 2.0, 0.3f, &none), std::invalid_argument);
}

// A capture over a grey whose colour is not known: drawn over black, the fit veils the scene with
// faint splats to make up the grey; with fit_background it finds the grey (within 0.01) and
// predicts held-out views better.
TEST(SplatFit, AFittedBackgroundFindsTheCapturesColour) {
  const Eigen::Vector3f grey(0.3f, 0.35f, 0.25f);
  const GaussianSplats truth = KnownDiscs();
  const std::vector<SplatFitView> training = Views(truth, Ring(12, 0.3f, 0.0f), grey);
  const std::vector<SplatFitView> heldout = Views(truth, Ring(5, 0.1f, 0.25f), grey);
  SplatFitOptions options = ShortFixedFit();
  double psnr[2];
  for (const bool fit : {false, true}) {
    options.fit_background = fit;
    GaussianSplats fitted = truth;
    const SplatFitResult result = FitSplats(training, Eigen::Vector3f::Zero(), options, &fitted, nullptr);
    psnr[fit] = 0;
    for (const SplatFitView& view : heldout) psnr[fit] += Psnr(fitted, view, result.background) / heldout.size();
    if (fit) {
      EXPECT_LT((result.background - grey).cwiseAbs().maxCoeff(), 0.01f) << result.background.transpose();
    } else {
      EXPECT_EQ(result.background, Eigen::Vector3f::Zero());
    }
  }
  EXPECT_GT(psnr[1], psnr[0] + 3) << "held out over black " << psnr[0] << " dB, fitted background " << psnr[1] << " dB";
}

TEST(SplatFit, ASmallStepAgainstTheGradientLowersTheObjective) {
  const Eigen::Vector3f background(0, 0, 0);
  const GaussianSplats truth = KnownDiscs();
  const std::vector<SplatFitView> views = Views(truth, {Eigen::Vector3f(0.5f, 3.0f, 1.0f)}, background);
  GaussianSplats splats = truth;
  for (size_t i = 0; i < splats.size(); ++i) splats.position[i] *= 1.05f, splats.opacity_logit[i] = 0.3f;
  // The squared error (a smooth objective) and its gradient.
  const auto loss_and_gradient = [&](const GaussianSplats& s, SplatGradients* g) {
    SplatFrame frame;
    SplatRasterOptions options;
    options.background = background;
    RenderSplats(s, views[0].camera, options, &frame);
    cv::Mat diff = frame.image - views[0].image;
    if (g) {
      g->Reset(s);
      BackwardSplats(s, views[0].camera, frame, diff * 2.0, g);
    }
    const cv::Scalar sum = cv::sum(diff.mul(diff));
    return sum[0] + sum[1] + sum[2];
  };
  SplatGradients g;
  const double before = loss_and_gradient(splats, &g);
  for (const float step : {1e-4f, 1e-5f}) {
    GaussianSplats moved = splats;
    for (size_t i = 0; i < moved.size(); ++i) {
      moved.position[i] -= step * g.position[i];
      moved.rotation[i] -= step * g.rotation[i];
      moved.log_scale[i] -= step * g.log_scale[i];
      moved.opacity_logit[i] -= step * g.opacity_logit[i];
      for (int k = 0; k < 3; ++k) moved.Sh(i)[k] -= step * g.sh[i * 3 + k];
    }
    EXPECT_LT(loss_and_gradient(moved, nullptr), before) << "step " << step;
  }
}

TEST(SplatFit, DensityControlKeepsItsInvariants) {
  GaussianSplats splats = KnownDiscs();
  std::vector<float> gradient(splats.size(), 0.0f);
  for (size_t i = 0; i < splats.size(); i += 2) gradient[i] = 1.0f;  // half of them grow
  splats.opacity_logit[1] = -8.0f;                                    // nearly transparent: pruned
  SplatFitOptions options;
  options.max_splats = 50;
  options.dense_fraction = 0.03;  // radii ~0.15 of an extent 3: these split
  std::vector<int> origin;
  GaussianSplats grown = splats;
  const DensityCounts counts = ControlDensity(gradient, 3.0, options, &grown, &origin);
  EXPECT_LE(grown.size(), 50u);
  EXPECT_EQ(counts.pruned, 1u);
  EXPECT_GT(counts.splits, 0u);
  EXPECT_EQ(grown.size(), splats.size() - counts.pruned + counts.splits + counts.clones);
  EXPECT_EQ(origin.size(), grown.size());
  EXPECT_EQ(grown.Validate(), "");
  // A split's two discs stand in for the one they came from: the image changes far less than
  // without it.
  GaussianSplats one;
  one.Add(Eigen::Vector3f::Zero(), RotationWithNormal(Eigen::Vector3f::UnitY()), Eigen::Vector2f::Constant(std::log(0.3f)), 0.8f,
          Eigen::Vector3f(1, 0.2f, 0.1f));
  GaussianSplats split = one;
  std::vector<float> grow = {1.0f};
  options.dense_fraction = 0.01;
  ControlDensity(grow, 3.0, options, &split, &origin);
  ASSERT_EQ(split.size(), 2u);
  const SplatCamera camera = LookingAt(Eigen::Vector3f(0, 3, 0));
  const auto image = [&](const GaussianSplats& s) {
    SplatFrame frame;
    RenderSplats(s, camera, SplatRasterOptions(), &frame);
    return frame.image.clone();
  };
  const cv::Mat reference = image(one);
  const double split_change = cv::norm(image(split), reference, cv::NORM_L1);
  const double removed_change = cv::norm(cv::Mat::zeros(reference.size(), reference.type()), reference, cv::NORM_L1);
  EXPECT_LT(split_change, 0.5 * removed_change);
}

TEST(SplatFit, BadOptionsAndInputsAreRefused) {
  SplatFitOptions options;
  std::string error;
  EXPECT_TRUE(options.Check(&error)) << error;
  options.sh_degree = 4;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind("sh_degree", 0), 0u) << error;
  options = SplatFitOptions();
  options.max_splats = 0;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_EQ(error.rfind("max_splats", 0), 0u) << error;
  GaussianSplats none;
  EXPECT_THROW(FitSplats({}, Eigen::Vector3f::Zero(), SplatFitOptions(), &none, nullptr), std::invalid_argument);
  const std::vector<SplatFitView> views = Views(KnownDiscs(), {Eigen::Vector3f(0, 3, 0)}, Eigen::Vector3f::Zero());
  EXPECT_THROW(FitSplats(views, Eigen::Vector3f::Zero(), SplatFitOptions(), &none, nullptr), std::invalid_argument);
}

}  // namespace
}  // namespace ibmr

// The stage adapter's refusals, each naming what to change.
#include <unistd.h>

#include <filesystem>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"

namespace ibmr {
void RegisterStage_splat_fit(StageRegistry* registry);

namespace {

struct StageWorkspace {
  std::filesystem::path root;
  StageRegistry registry;
  const Stage* stage = nullptr;
  StageContext context;
  NullProgress progress;

  // `views` photos of 32x32 looking at the origin, `points` fused points.
  StageWorkspace(const std::string& name, int views, int points) {
    root = std::filesystem::temp_directory_path() / ("ibmr_splat_fit_stage_" + name + "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(root);
    std::filesystem::create_directories(root / "images");
    std::filesystem::create_directories(root / "dense");
    RegisterStage_splat_fit(&registry);
    stage = registry.Find("splat_fit");
    SparseModel model;
    model.cameras[1] = Camera::Pinhole(32, 32, 40, 40, 16, 16);
    for (int i = 0; i < views; ++i) {
      Image image;
      image.image_id = i + 1;
      image.camera_id = 1;
      image.name = "v" + std::to_string(i) + ".png";
      image.cam_from_world = Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.1 * i, 0, 3));
      model.images[image.image_id] = image;
      WriteImage((root / "images" / image.name).string(), cv::Mat(32, 32, CV_8UC3, cv::Scalar(10, 200, 30)));
    }
    WriteSparseModelText((root / "sparse").string(), model);
    PointCloud cloud;
    for (int i = 0; i < points; ++i) {
      cloud.positions.push_back(Eigen::Vector3f(0.01f * i, 0.02f * (i % 7), 0));
      cloud.normals.push_back(Eigen::Vector3f(0, 0, -1));
      cloud.colors.push_back(Color3u8(200, 30, 10));
    }
    WritePointCloudPly((root / "dense/fused.ply").string(), cloud);
    context.workspace = Workspace(root.string());
    context.role = HoldoutRole::kTrainingOnly;
    context.progress = &progress;
    for (const ParamSpec& spec : stage->Parameters()) {
      if (spec.type == ParamType::kInt) context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
      if (spec.type == ParamType::kDouble) context.params.Set(spec.key, std::stod(spec.default_yaml));
      if (spec.type == ParamType::kString) context.params.Set(spec.key, spec.default_yaml);
      if (spec.type == ParamType::kBool) context.params.Set(spec.key, spec.default_yaml == "true");
    }
    context.params.Set("iterations", int64_t{20});
  }
  ~StageWorkspace() { std::filesystem::remove_all(root); }
  std::string Error() {
    try {
      stage->Run(context);
    } catch (const InputError& e) {
      return e.what();
    }
    return "";
  }
};

TEST(SplatFitStage, RefusesWhatItCannotFitNamingTheKey) {
  {
    StageWorkspace ws("one_view", 1, 50);
    const std::string error = ws.Error();
    EXPECT_NE(error.find("at least 2"), std::string::npos) << error;
  }
  {
    StageWorkspace ws("no_points", 3, 0);
    const std::string error = ws.Error();
    EXPECT_NE(error.find("fused.ply"), std::string::npos) << error;
    EXPECT_NE(error.find("no point"), std::string::npos) << error;
  }
  {
    StageWorkspace ws("cap", 3, 50);
    ws.context.params.Set("max_splats", int64_t{10});
    const std::string error = ws.Error();
    EXPECT_NE(error.find("splat_fit.max_splats"), std::string::npos) << error;
  }
  {
    StageWorkspace ws("fits", 3, 50);
    EXPECT_EQ(ws.Error(), "");
    const GaussianSplats written = ReadGaussianSplatsPly((ws.root / "splat_fit/splats.ply").string());
    EXPECT_EQ(written.size(), ws.context.metrics["splats"].get<size_t>());
    EXPECT_EQ(written.sh_degree, 3);
    EXPECT_TRUE(std::filesystem::exists(ws.root / "splat_fit/curve.json"));
  }
}

// The loss's gradient with respect to the render against central differences, with the
// structural term on (the L1 part's kinks avoided: no pixel within the step of its photo's value).
TEST(PhotometricLoss, GradientMatchesCentralDifferences) {
  cv::Mat render(9, 12, CV_32FC3), photo(9, 12, CV_32FC3);
  cv::RNG rng(4);
  rng.fill(render, cv::RNG::UNIFORM, 0.1, 0.9);
  rng.fill(photo, cv::RNG::UNIFORM, 0.1, 0.9);
  cv::Mat gradient, scratch;
  const PhotometricLoss at = PhotometricLossAndGradient(render, photo, 0.2, &gradient);
  EXPECT_GT(at.ssim, -1.0);
  EXPECT_LT(at.ssim, 1.0);
  EXPECT_NEAR(at.loss, 0.8 * at.l1 + 0.2 * (1 - at.ssim), 1e-12);
  const float h = 1e-3f;
  double worst = 0, largest = 0;
  for (int y = 0; y < render.rows; ++y) {
    for (int x = 0; x < render.cols; ++x) {
      for (int c = 0; c < 3; ++c) {
        float& v = render.at<cv::Vec3f>(y, x)[c];
        if (std::abs(v - photo.at<cv::Vec3f>(y, x)[c]) < 2 * h) continue;
        const float keep = v;
        v = keep + h;
        const double up = PhotometricLossAndGradient(render, photo, 0.2, &scratch).loss;
        v = keep - h;
        const double down = PhotometricLossAndGradient(render, photo, 0.2, &scratch).loss;
        v = keep;
        const double numeric = (up - down) / (2 * h);
        worst = std::max(worst, std::abs(numeric - gradient.at<cv::Vec3f>(y, x)[c]));
        largest = std::max(largest, std::abs(numeric));
      }
    }
  }
  EXPECT_LT(worst, 0.02 * largest) << "largest " << largest;
  // Weight 0: the L1 gradient alone, SSIM not computed.
  const PhotometricLoss l1 = PhotometricLossAndGradient(render, photo, 0.0, &gradient);
  EXPECT_EQ(l1.ssim, 1.0);
  EXPECT_NEAR(std::abs(gradient.at<cv::Vec3f>(0, 0)[0]), 1.0 / (3.0 * render.total()), 1e-9);
}

}  // namespace
}  // namespace ibmr
