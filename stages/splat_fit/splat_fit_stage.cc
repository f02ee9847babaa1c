// Adapter of the splat_fit stage (seed 000 §3 lines 5597-5604 and §5 lines 4454-4586, seed 004
// §5.4; see splat_fit.h): reads the training views (undistorted pinhole cameras and their photos),
// the initial particles (surfels/surfels.ply, else dense/fused.ply with radii from their nearest
// neighbours) and the capture's background colour (background.json; black without one), adds a
// backdrop behind the points where the capture is forward-facing (AddBackdrop), fits the splats (and
// the background colour where the capture does not give it) and writes
//   splat_fit/splats.ply    the fitted splats in the layout Gaussian-splatting viewers read
//                           (pipeline/core/gaussian_splats.h)
//   splat_fit/curve.json    the fitting curve: training L1 and PSNR every 50 steps, splat count
//   splat_fit/background.json  {"rgb": [r, g, b] in [0, 1], "fitted": bool}: the colour the splats
//                           were fitted over; where fitted, part of the model (the render model
//                           draws it behind the splats)
// Its record holds the fit's statistics (no held-out view is read): splats, steps, final training
// error, and forward / backward seconds per image megapixel per 100k splats.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <nanoflann.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_info.h"
#include "pipeline/core/capture_shape.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/splat_fit/splat_fit.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

constexpr char kSurfels[] = "surfels/surfels.ply";
constexpr char kFused[] = "dense/fused.ply";
const std::vector<std::string> kInitNames = {"auto", "surfels", "fused"};
const std::vector<std::string> kBackdropNames = {"auto", "on", "off"};
const std::vector<std::string> kBackgroundNames = {"auto", "capture", "fit"};

// The capture's kind as the runner decided it (capture.json, which also carries a plan.kind the
// config set), else as the poses show it.
std::string CaptureKind(const Workspace& workspace, const SparseModel& model) {
  const nlohmann::json capture = ReadJsonOr(workspace.Path(kCaptureFile), nlohmann::json());
  if (capture.is_object()) {
    const CaptureShape shape = CaptureShape::FromJson(capture);
    if (!shape.kind.empty()) return shape.kind;
  }
  return AnalyseCapture(model, CaptureHasAlpha(workspace)).kind;
}

// The mean colour (RGB) of the training photos' outermost pixel rows and columns: where a capture's
// background shows, if anywhere; the fitted background's start.
Eigen::Vector3f BorderMean(const std::vector<SplatFitView>& views) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double count = 0;
  for (const SplatFitView& view : views) {
    const cv::Mat& image = view.image;
    for (const cv::Rect& edge : {cv::Rect(0, 0, image.cols, 1), cv::Rect(0, image.rows - 1, image.cols, 1),
                                 cv::Rect(0, 0, 1, image.rows), cv::Rect(image.cols - 1, 0, 1, image.rows)}) {
      const cv::Scalar s = cv::sum(image(edge));
      sum += Eigen::Vector3d(s[0], s[1], s[2]);
      count += edge.area();
    }
  }
  if (count == 0) return Eigen::Vector3f::Zero();
  return (sum / count).cast<float>();
}

// Radii for points without one: the mean distance to their 3 nearest neighbours (nanoflann).
struct CloudAdaptor {
  const std::vector<Eigen::Vector3f>& points;
  size_t kdtree_get_point_count() const { return points.size(); }
  float kdtree_get_pt(size_t i, size_t dim) const { return points[i][dim]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

std::vector<float> NeighbourRadii(const std::vector<Eigen::Vector3f>& points) {
  CloudAdaptor adaptor{points};
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, CloudAdaptor>, CloudAdaptor, 3>;
  Tree tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  tree.buildIndex();
  std::vector<float> radii(points.size(), 0.0f);
  for (size_t i = 0; i < points.size(); ++i) {
    unsigned int index[4];
    float distance2[4];
    const size_t found = tree.knnSearch(points[i].data(), 4, index, distance2);
    float sum = 0;
    for (size_t k = 1; k < found; ++k) sum += std::sqrt(distance2[k]);
    radii[i] = found > 1 ? sum / static_cast<float>(found - 1) : 0.0f;
  }
  return radii;
}

class SplatFitStage : public Stage {
 public:
  std::string Name() const override { return "splat_fit"; }
  std::string Summary() const override {
    return "Oriented elliptical splats fitted to the training photos by gradient descent (splat_fit/splats.ply)";
  }
  // 5: splat_fit/background.json; footprints cut at the circle of 3 sigmas (splat_rasterizer.h)
  std::string Version() const override { return "5"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }

  std::vector<ParamSpec> Parameters() const override {
    const SplatFitOptions d;
    const auto num = DefaultNumberText;
    return {
        {"init", ParamType::kString, "auto", "Initial particles: surfels (surfels/surfels.ply), fused (dense/fused.ply) or auto (surfels where they exist)", kInitNames},
        {"background", ParamType::kString, "auto",
         "Colour the splats are drawn over: capture (background.json's, else black), fit (fitted with the splats from "
         "that, or from the photos' border where unknown), auto (capture where background.json gives one or a backdrop "
         "is added, else fit)",
         kBackgroundNames},
        {"backdrop", ParamType::kString, "auto",
         "Discs on a sphere behind the scene's points for what lies beyond them (a sky): on, off, or auto (on for "
         "forward-facing captures, capture.json's kind)", kBackdropNames},
        {"backdrop_step", ParamType::kInt, "16", "Backdrop: one disc per this many pixels square of each view, [1, 1024]"},
        {"backdrop_distance", ParamType::kDouble, "2", "Backdrop: sphere radius over the 99th percentile of the points' distances, (1, 100]"},
        {"max_initial", ParamType::kInt, "300000", "Initial particles kept (a random subset beyond it), [1, 1e7]"},
        {"initial_opacity", ParamType::kDouble, "0.3", "Opacity of the initial splats, (0, 1)"},
        {"iterations", ParamType::kInt, std::to_string(d.iterations), "Optimisation steps, one training view each, >= 1"},
        {"sh_degree", ParamType::kInt, std::to_string(d.sh_degree), "Final SH degree of the view-dependent colour, [0, 3]"},
        {"sh_every", ParamType::kInt, std::to_string(d.sh_every), "Steps per SH degree added, >= 1"},
        {"coarse_fraction", ParamType::kDouble, num(d.coarse_fraction), "Fraction of the steps at half resolution, [0, 1]"},
        {"max_image_size", ParamType::kInt, "0",
         "Fit against the photos scaled to at most this many pixels on their longer side (the splats are drawn at any "
         "size later); 0: as the views are, else >= 16"},
        {"lr_position", ParamType::kDouble, num(d.lr_position), "Position step, times the scene extent (decays to lr_position_final)"},
        {"lr_position_final", ParamType::kDouble, num(d.lr_position_final), "Final position step, times the scene extent"},
        {"lr_rotation", ParamType::kDouble, num(d.lr_rotation), "Rotation (quaternion) step"},
        {"lr_scale", ParamType::kDouble, num(d.lr_scale), "Log-radius step"},
        {"lr_opacity", ParamType::kDouble, num(d.lr_opacity), "Opacity-logit step"},
        {"lr_sh_dc", ParamType::kDouble, num(d.lr_sh_dc), "SH DC step"},
        {"lr_sh_rest", ParamType::kDouble, num(d.lr_sh_rest), "Higher SH coefficients' step"},
        {"densify_every", ParamType::kInt, std::to_string(d.densify_every), "Steps between density control passes, >= 1"},
        {"densify_from", ParamType::kInt, std::to_string(d.densify_from), "First step of density control, >= 0"},
        {"densify_until", ParamType::kDouble, num(d.densify_until), "Fraction of the steps with density control, [0, 1]"},
        {"densify_gradient", ParamType::kDouble, num(d.densify_gradient), "Mean projected-centre gradient that grows a splat, > 0"},
        {"dense_fraction", ParamType::kDouble, num(d.dense_fraction), "Radius (fraction of the extent) above which a growing splat splits, (0, 1)"},
        {"prune_opacity", ParamType::kDouble, num(d.prune_opacity), "Splats below this opacity are removed, [0, 1)"},
        {"max_scale_fraction", ParamType::kDouble, num(d.max_scale_fraction), "Splats wider than this fraction of the extent are removed, (0, 10]"},
        {"max_splats", ParamType::kInt, std::to_string(d.max_splats), "Cap on the splat count, >= 1"},
        {"seed", ParamType::kInt, std::to_string(d.seed), "View order and the subset of initial particles, >= 0"},
        {"dssim_weight", ParamType::kDouble, num(d.dssim_weight),
         "Weight of the structural term: (1 - w) L1 + w (1 - SSIM), 3DGS's 0.2; [0, 1]"},
        {"view_gains", ParamType::kBool, d.view_gains ? "true" : "false",
         "Fit a per-channel gain per training view beside the splats (photos whose exposure differs); held-out views are "
         "drawn at the views' mean gain"},
        {"lr_gain", ParamType::kDouble, num(d.lr_gain), "Log-gain step (view_gains), [0, 1)"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (params.Int("max_image_size") != 0 && params.Int("max_image_size") < 16) {
      return ParamError{"max_image_size", "must be 0 (the views' size) or >= 16, got " + std::to_string(params.Int("max_image_size"))};
    }
    if (params.Int("max_initial") < 1 || params.Int("max_initial") > 10000000) {
      return ParamError{"max_initial", "must be in [1, 10000000], got " + std::to_string(params.Int("max_initial"))};
    }
    if (!(params.Double("initial_opacity") > 0 && params.Double("initial_opacity") < 1)) {
      return ParamError{"initial_opacity", "must be in (0, 1)"};
    }
    if (params.Int("backdrop_step") < 1 || params.Int("backdrop_step") > 1024) {
      return ParamError{"backdrop_step", "must be in [1, 1024], got " + std::to_string(params.Int("backdrop_step"))};
    }
    if (!(params.Double("backdrop_distance") > 1 && params.Double("backdrop_distance") <= 100)) {
      return ParamError{"backdrop_distance", "must be in (1, 100]"};
    }
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.ImagesRelative(), context.workspace.SparseRelative(), kBackgroundFile,
                                       kCaptureFile};
    const std::string& init = context.params.String("init");
    if (init != "fused") inputs.push_back(kSurfels);
    if (init != "surfels") inputs.push_back(kFused);
    return inputs;
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"splat_fit"}; }

  void Run(StageContext& context) const override {
    const SplatFitOptions options = ToOptions(context.params);
    const Workspace& workspace = context.workspace;
    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.size() < 2) {
      throw InputError("splat_fit: " + std::to_string(names.size()) + " training view(s) in " + workspace.SparseDir() +
                       "; fitting splats needs at least 2 (import more photos, or hold fewer out)");
    }
    GaussianSplats splats = InitialSplats(context);
    if (static_cast<int64_t>(splats.size()) > context.params.Int("max_splats")) {
      throw InputError("splat_fit.max_splats: " + std::to_string(context.params.Int("max_splats")) + " is below the " +
                       std::to_string(splats.size()) + " initial splats; raise it, or lower splat_fit.max_initial");
    }
    const std::optional<CaptureBackground> capture_background = ReadCaptureBackground(workspace);
    Eigen::Vector3f background = Eigen::Vector3f::Zero();
    if (capture_background) {
      for (int c = 0; c < 3; ++c) background[c] = capture_background->bgr[2 - c] / 255.0f;
    }

    std::vector<SplatFitView> views(names.size());
    context.progress->Begin("splat_fit: reading views", names.size());
    for (size_t i = 0; i < names.size(); ++i) {
      const Image& image = *model.FindImage(names[i]);
      const Camera& camera = model.CameraOf(image);
      if (camera.model != CameraModelId::kPinhole && camera.model != CameraModelId::kSimplePinhole) {
        throw InputError("splat_fit: view " + names[i] + " has a " + CameraModelName(camera.model) +
                         " camera; the splats are drawn in pinhole cameras: run undistort before splat_fit");
      }
      const std::string path = workspace.ImagesDir() + "/" + names[i];
      const cv::Mat photo = ReadImageColor(path);  // throws naming the file
      if (photo.cols != camera.width || photo.rows != camera.height) {
        throw InputError(path + ": is " + std::to_string(photo.cols) + "x" + std::to_string(photo.rows) + " but its camera is " +
                         std::to_string(camera.width) + "x" + std::to_string(camera.height) + "; re-run import");
      }
      SplatFitView& view = views[i];
      view.name = names[i];
      cv::Mat rgb;
      cv::cvtColor(photo, rgb, cv::COLOR_BGR2RGB);
      const int max_size = context.params.Int("max_image_size");
      Camera fitted = camera;
      if (max_size > 0 && std::max(camera.width, camera.height) > max_size) {
        fitted = camera.Scaled(static_cast<double>(max_size) / std::max(camera.width, camera.height));
        cv::resize(rgb, rgb, cv::Size(fitted.width, fitted.height), 0, 0, cv::INTER_AREA);
      }
      rgb.convertTo(view.image, CV_32FC3, 1.0 / 255.0);
      view.camera = ToSplatCamera(fitted, image.cam_from_world);
      context.progress->Advance(1, names[i]);
    }
    context.progress->End();

    const std::string& backdrop = context.params.String("backdrop");
    bool with_backdrop = backdrop == "on";
    if (backdrop == "auto") with_backdrop = CaptureKind(workspace, model) == "forward_facing";
    if (with_backdrop) {
      const size_t before = splats.size();
      const size_t added = AddBackdrop(views, static_cast<int>(context.params.Int("backdrop_step")),
                                       context.params.Double("backdrop_distance"),
                                       static_cast<float>(context.params.Double("initial_opacity")), &splats);
      context.metrics["backdrop_splats"] = added;
      spdlog::info("[splat_fit] backdrop: {} discs behind the {} initial splats (splat_fit.backdrop: {})", added, before, backdrop);
      if (static_cast<int64_t>(splats.size()) > context.params.Int("max_splats")) {
        throw InputError("splat_fit.max_splats: " + std::to_string(context.params.Int("max_splats")) + " is below the " +
                         std::to_string(splats.size()) + " initial splats with the backdrop; raise it, or lower "
                         "splat_fit.max_initial, or raise splat_fit.backdrop_step");
      }
    }
    SplatFitOptions fit_options = options;
    const std::string& background_mode = context.params.String("background");
    // auto fits the colour only where neither the capture gives it nor a backdrop stands behind the
    // points: the render model draws the splats alone, so a colour fitted in place of the backdrop
    // (a sky) would be missing from every render (hard synthetic forward scene at a quarter of the
    // size: 26.07 dB with the backdrop alone, 22.74 with the colour fitted as well).
    fit_options.fit_background =
        background_mode == "fit" || (background_mode == "auto" && !capture_background && !with_backdrop);
    if (fit_options.fit_background && !capture_background) background = BorderMean(views);
    spdlog::info("[splat_fit] {} initial splats, {} training views, {} steps (background {:.2f} {:.2f} {:.2f}{})",
                 splats.size(), views.size(), options.iterations, background[0], background[1], background[2],
                 fit_options.fit_background ? ", fitted from there" : "");
    SplatFitResult result;
    try {
      result = FitSplats(views, background, fit_options, &splats, context.progress);
    } catch (const std::invalid_argument& e) {
      throw InputError(std::string("splat_fit: ") + e.what());
    } catch (const std::runtime_error& e) {
      throw InputError(std::string("splat_fit: ") + e.what());
    }
    fs::create_directories(workspace.Path("splat_fit"));
    WriteGaussianSplatsPly(workspace.Path("splat_fit/splats.ply"), splats, "ibmr splat_fit " + Version());
    nlohmann::json curve = nlohmann::json::array();
    for (const SplatFitPoint& p : result.curve) {
      curve.push_back({{"iteration", p.iteration}, {"l1", p.l1}, {"psnr", p.psnr}, {"splats", p.splats}});
    }
    WriteFileAtomic(workspace.Path("splat_fit/curve.json"), nlohmann::json({{"curve", curve}}).dump(1) + "\n");
    WriteFileAtomic(workspace.Path("splat_fit/background.json"),
                    nlohmann::json({{"rgb", {result.background[0], result.background[1], result.background[2]}},
                                    {"fitted", fit_options.fit_background}})
                            .dump(1) +
                        "\n");

    nlohmann::json& m = context.metrics;
    m["splats"] = splats.size();
    m["training_views"] = views.size();
    m["iterations"] = options.iterations;
    m["extent"] = result.extent;
    m["splits"] = result.splits;
    m["clones"] = result.clones;
    m["pruned"] = result.pruned;
    if (!result.curve.empty()) {
      m["final_training_l1"] = result.curve.back().l1;
      m["final_training_psnr"] = result.curve.back().psnr;
    }
    m["background_rgb"] = {result.background[0], result.background[1], result.background[2]};
    m["background_fitted"] = fit_options.fit_background;
    if (!result.view_gains.empty()) {
      nlohmann::json gains = nlohmann::json::object();
      double spread = 0;
      for (size_t i = 0; i < views.size(); ++i) {
        const Eigen::Vector3f& g = result.view_gains[i];
        gains[views[i].name] = {g[0], g[1], g[2]};
        spread = std::max(spread, static_cast<double>((g.array().log().abs()).maxCoeff()));
      }
      m["view_gains"] = gains;  // RGB, per training view
      spdlog::info("[splat_fit] view gains fitted: the largest differs from the mean by {:.1f}%", 100 * (std::exp(spread) - 1));
    }
    const double per = result.megapixel_steps * std::max(1e-9, result.mean_splats / 1e5);
    m["forward_seconds"] = result.forward_seconds;
    m["backward_seconds"] = result.backward_seconds;
    m["forward_seconds_per_mpx_per_100k"] = result.forward_seconds / per;
    m["backward_seconds_per_mpx_per_100k"] = result.backward_seconds / per;
    spdlog::info("[splat_fit] {} splats ({} split, {} cloned, {} pruned); training L1 {:.4f}, PSNR {:.2f} dB; forward {:.3f} s "
                 "and backward {:.3f} s per megapixel per 100k splats",
                 splats.size(), result.splits, result.clones, result.pruned, m.value("final_training_l1", 0.0),
                 m.value("final_training_psnr", 0.0), m["forward_seconds_per_mpx_per_100k"].get<double>(),
                 m["backward_seconds_per_mpx_per_100k"].get<double>());
  }

 private:
  static SplatFitOptions ToOptions(const Params& params) {
    SplatFitOptions o;
    o.iterations = static_cast<int>(std::clamp<int64_t>(params.Int("iterations"), -1, 1 << 30));
    o.sh_degree = static_cast<int>(std::clamp<int64_t>(params.Int("sh_degree"), -1, 100));
    o.sh_every = static_cast<int>(std::clamp<int64_t>(params.Int("sh_every"), -1, 1 << 30));
    o.coarse_fraction = params.Double("coarse_fraction");
    o.lr_position = params.Double("lr_position");
    o.lr_position_final = params.Double("lr_position_final");
    o.lr_rotation = params.Double("lr_rotation");
    o.lr_scale = params.Double("lr_scale");
    o.lr_opacity = params.Double("lr_opacity");
    o.lr_sh_dc = params.Double("lr_sh_dc");
    o.lr_sh_rest = params.Double("lr_sh_rest");
    o.densify_every = static_cast<int>(std::clamp<int64_t>(params.Int("densify_every"), -1, 1 << 30));
    o.densify_from = static_cast<int>(std::clamp<int64_t>(params.Int("densify_from"), -1, 1 << 30));
    o.densify_until = params.Double("densify_until");
    o.densify_gradient = params.Double("densify_gradient");
    o.dense_fraction = params.Double("dense_fraction");
    o.prune_opacity = params.Double("prune_opacity");
    o.max_scale_fraction = params.Double("max_scale_fraction");
    o.max_splats = static_cast<int>(std::clamp<int64_t>(params.Int("max_splats"), -1, 1 << 30));
    o.seed = params.Int("seed");
    o.dssim_weight = params.Double("dssim_weight");
    o.view_gains = params.Bool("view_gains");
    o.lr_gain = params.Double("lr_gain");
    return o;
  }

  // The initial splats: one per particle (surfels: their radius; fused points: their neighbours'
  // spacing), a disc facing along its normal, the particle's colour, initial_opacity; a random
  // subset of max_initial where there are more.
  static GaussianSplats InitialSplats(const StageContext& context) {
    const std::string& init = context.params.String("init");
    const std::string surfels = context.workspace.Path(kSurfels), fused = context.workspace.Path(kFused);
    std::string path;
    if (init == "surfels" || (init == "auto" && fs::exists(surfels))) {
      path = surfels;
    } else {
      path = fused;
    }
    if (!fs::exists(path)) {
      throw InputError("splat_fit.init: " + path + " does not exist; run " +
                       (path == surfels ? std::string("surfels") : std::string("fuse")) + " before splat_fit (or set splat_fit.init)");
    }
    PointCloud cloud = ReadPointCloudPly(path);
    if (cloud.size() == 0) throw InputError(path + ": holds no point to start the splats from; check its stage's record");
    const size_t keep = static_cast<size_t>(context.params.Int("max_initial"));
    std::vector<size_t> order(cloud.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = i;
    if (order.size() > keep) {
      std::mt19937_64 rng(static_cast<uint64_t>(context.params.Int("seed")));
      std::shuffle(order.begin(), order.end(), rng);
      order.resize(keep);
      std::sort(order.begin(), order.end());
    }
    std::vector<Eigen::Vector3f> positions;
    for (size_t i : order) positions.push_back(cloud.positions[i]);
    std::vector<float> radii;
    if (cloud.radius.size() == cloud.size()) {
      for (size_t i : order) radii.push_back(cloud.radius[i]);
    } else {
      radii = NeighbourRadii(positions);
    }
    std::vector<float> sorted = radii;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const float median = std::max(1e-9f, sorted[sorted.size() / 2]);
    GaussianSplats splats;
    const float opacity = static_cast<float>(context.params.Double("initial_opacity"));
    for (size_t k = 0; k < order.size(); ++k) {
      const size_t i = order[k];
      const Eigen::Vector3f normal = cloud.normals.size() == cloud.size() && cloud.normals[i].norm() > 0.5f
                                         ? cloud.normals[i]
                                         : Eigen::Vector3f::UnitZ();
      // The particle's radius bounds its disc; the Gaussian's standard deviation is half of it.
      const float sigma = 0.5f * std::clamp(radii[k], 0.1f * median, 10.0f * median);
      Eigen::Vector3f colour = Eigen::Vector3f::Constant(0.5f);
      if (cloud.colors.size() == cloud.size()) colour = cloud.colors[i].cast<float>() / 255.0f;
      splats.Add(positions[k], RotationWithNormal(normal), Eigen::Vector2f::Constant(std::log(sigma)), opacity, colour);
    }
    spdlog::info("[splat_fit] {} initial splats from {} ({} particles)", splats.size(), context.workspace.Relative(path),
                 cloud.size());
    return splats;
  }
};

}  // namespace

void RegisterStage_splat_fit(StageRegistry* registry) { registry->Add(std::make_unique<SplatFitStage>()); }

}  // namespace ibmr
