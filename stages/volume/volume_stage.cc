// Adapter of the volume stage (volume.h; seed 000 section 3, lines 5526-5610): reads the training
// views (pinhole cameras, photos) of the workspace, chooses the virtual camera(s) and depth range,
// fits the RGBA plane volume, and writes volume/<reference>/ (plane_volume.h's format, and
// strip.png: the planes side by side over a checkerboard, labelled with their depth): `mean` for
// the training views' mean pose, or one folder per training view named in `references` (local
// volumes, which the render stage blends by distance). The depth range comes from, in order:
// volume.min_depth/max_depth in the config; sparse/depth_bounds.json (per view near/far, as the
// LLFF import writes from poses_bounds.npy: the smallest near and largest far); the sparse points
// seen by the virtual camera (the nearest one and the 99th percentile of depth, widened by
// depth_margin).
// The record holds the optimisation curve (objective and data term per step and level), the
// phases' seconds, the volume's size and the fitting's memory estimate.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/stage_api.h"
#include "stages/volume/volume.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

std::string Stem(const std::string& name) { return fs::path(name).stem().string(); }

// The planes side by side, 8 to a row, each over a grey checkerboard (where it is transparent)
// at `tile` pixels wide and labelled with its index and depth: volume/<reference>/strip.png, for
// the report and for a user looking at what the volume holds.
cv::Mat PlaneStrip(const PlaneVolume& volume, int tile) {
  const int tile_h = std::max(1, tile * volume.Height() / volume.Width());
  const int columns = std::min(8, volume.Planes()), rows = (volume.Planes() + columns - 1) / columns;
  cv::Mat strip(rows * (tile_h + 2), columns * (tile + 2), CV_8UC3, cv::Scalar::all(255));
  for (int k = 0; k < volume.Planes(); ++k) {
    const cv::Mat cells(volume.Height(), volume.Width(), CV_32FC4, const_cast<float*>(volume.Plane(k)));
    cv::Mat small;
    cv::resize(cells, small, cv::Size(tile, tile_h), 0, 0, cv::INTER_AREA);
    cv::Mat tile_image(tile_h, tile, CV_8UC3);
    for (int y = 0; y < tile_h; ++y) {
      for (int x = 0; x < tile; ++x) {
        const cv::Vec4f c = small.at<cv::Vec4f>(y, x);
        const float checker = ((x / 8 + y / 8) % 2) ? 0.55f : 0.8f;
        for (int ch = 0; ch < 3; ++ch) {
          tile_image.at<cv::Vec3b>(y, x)[ch] = cv::saturate_cast<uint8_t>(255.f * (c[3] * c[ch] + (1 - c[3]) * checker));
        }
      }
    }
    char label[48];
    std::snprintf(label, sizeof(label), "%d  z %.3g", k, volume.depths[k]);
    cv::putText(tile_image, label, cv::Point(3, 12), cv::FONT_HERSHEY_PLAIN, 0.8, cv::Scalar(0, 0, 0), 1);
    tile_image.copyTo(strip(cv::Rect((k % columns) * (tile + 2) + 1, (k / columns) * (tile_h + 2) + 1, tile, tile_h)));
  }
  return strip;
}

const auto Number = DefaultNumberText;

class VolumeStage : public Stage {
 public:
  std::string Name() const override { return "volume"; }
  std::string Summary() const override {
    return "Volumetric stereo with transparency: RGBA planes in a virtual camera fitted to the photos (volume/)";
  }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  // Issue 53's finding: fronto-parallel planes sample a wide capture too coarsely (fountain-P11:
  // 14.8 dB against the surfel mesh's 19.0, after 303 s of fitting).
  CaptureUse Serves() const override {
    return {{"forward_facing"}, "volumes of fronto-parallel planes sample forward-facing captures only"};
  }

  std::vector<ParamSpec> Parameters() const override {
    const VolumeOptions d;
    return {
        {"num_planes", ParamType::kInt, std::to_string(d.num_planes), "Planes equally spaced in inverse depth, [2, 256]"},
        {"resolution", ParamType::kDouble, Number(d.resolution), "Volume pixels per training pixel, (0, 4]"},
        {"max_widen", ParamType::kDouble, Number(d.max_widen),
         "The volume's image at most this times the training images' size (widened to cover their frusta), [1, 4]"},
        {"references", ParamType::kStringList, "[]",
         "Training views whose poses hold local volumes (blended by distance when rendered); empty: one volume at the mean pose"},
        {"views_per_volume", ParamType::kInt, "0",
         "Each volume is fitted to this many training views nearest its camera (local volumes, as LLFF's); 0: all, [0, 10000]"},
        {"min_depth", ParamType::kDouble, "-1", "Near depth of the planes, scene units; -1: from depth_bounds.json or the sparse points"},
        {"max_depth", ParamType::kDouble, "-1", "Far depth of the planes, scene units; -1: from depth_bounds.json or the sparse points"},
        {"depth_margin", ParamType::kDouble, "0.1", "The sparse points' depth range widened by this fraction, [0, 1]"},
        {"window_radius", ParamType::kInt, std::to_string(d.window_radius), "Box window of the initial sweep's variance cost, [0, 16]"},
        {"vote_temperature", ParamType::kDouble, Number(d.vote_temperature),
         "Initial opacities from soft votes exp(-(cost - min) / T) (colour variance units); 0: the winner alone"},
        {"visibility_rounds", ParamType::kInt, std::to_string(d.visibility_rounds), "Initial votes recomputed with visibility, [0, 5]"},
        {"levels", ParamType::kInt, std::to_string(d.levels), "Pyramid levels of the fitting, [1, 6]"},
        {"iterations", ParamType::kInt, std::to_string(d.iterations), "Steps at the coarsest level (each finer level half as many), >= 0"},
        {"min_iterations", ParamType::kInt, std::to_string(d.min_iterations), "Steps at least per level, >= 0"},
        {"optimizer", ParamType::kString, "adam", "Step rule of the fitting", {"adam", "gradient_descent"}},
        {"learning_rate", ParamType::kDouble, Number(d.learning_rate), "Step size at each level's start (a tenth at its end), > 0"},
        {"views_per_step", ParamType::kInt, std::to_string(d.views_per_step), "Training views each step sees, in turn; 0: all, [0, 10000]"},
        {"robust_epsilon", ParamType::kDouble, Number(d.robust_epsilon), "e of the robust error sqrt(r^2 + e^2) - e, colour units, > 0"},
        {"smoothness", ParamType::kDouble, Number(d.smoothness), "Weight of colour and opacity smoothness, >= 0"},
        {"opacity_prior", ParamType::kDouble, Number(d.opacity_prior), "Weight of the prior a (1 - a) pushing opacities to 0 or 1, >= 0"},
        {"max_memory_mb", ParamType::kDouble, Number(d.max_memory_mb),
         "Memory the fitting of one volume may take, MB (see fit_memory)"},
        {"fit_memory", ParamType::kBool, "true",
         "Lower the widening (then the resolution) of a volume that would need more than max_memory_mb until it "
         "fits, and say what it chose; false: refuse it"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (params.Int("views_per_volume") < 0 || params.Int("views_per_volume") == 1 || params.Int("views_per_volume") > 10000) {
      return ParamError{"views_per_volume", "must be 0 (all views) or in [2, 10000]"};
    }
    const double margin = params.Double("depth_margin");
    if (!(margin >= 0 && margin <= 1)) return ParamError{"depth_margin", "must be in [0, 1]"};
    const double near = params.Double("min_depth"), far = params.Double("max_depth");
    if ((near > 0) != (far > 0)) return ParamError{near > 0 ? "max_depth" : "min_depth", "set both min_depth and max_depth, or neither"};
    if (near > 0 && !(far > near)) return ParamError{"max_depth", "must be greater than min_depth"};
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    // sparse/ holds depth_bounds.json when the import wrote it.
    return {context.workspace.SparseRelative(), context.workspace.Relative(context.workspace.ImagesDir())};
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"volume"}; }

  void Run(StageContext& context) const override {
    const VolumeOptions options = ToOptions(context.params);
    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.size() < 2) {
      throw InputError("volume: needs at least 2 training views, " + context.workspace.SparseRelative() + " has " +
                       std::to_string(names.size()) + " (check holdout)");
    }
    std::vector<VolumeView> views;
    for (const std::string& name : names) {
      const Image& image = *model.FindImage(name);
      VolumeView view;
      view.name = name;
      view.camera = model.CameraOf(image);
      if (view.camera.HasDistortion()) {
        throw InputError("volume: view " + name + "'s camera has lens distortion; run undistort before volume");
      }
      view.cam_from_world = image.cam_from_world;
      view.image = ReadImageColor(context.workspace.ImagesDir() + "/" + name);
      if (view.image.cols != view.camera.width || view.image.rows != view.camera.height) {
        throw InputError(context.workspace.ImagesDir() + "/" + name + ": is " + std::to_string(view.image.cols) + "x" +
                         std::to_string(view.image.rows) + " but its camera says " + std::to_string(view.camera.width) +
                         "x" + std::to_string(view.camera.height));
      }
      views.push_back(std::move(view));
    }
    std::vector<int> references;
    for (const std::string& reference : context.params.StringList("references")) {
      const auto found = std::find(names.begin(), names.end(), reference);
      if (found == names.end()) {
        throw InputError("volume.references: '" + reference + "' is not a training view (held out, or not in " +
                         context.workspace.SparseRelative() + ")");
      }
      references.push_back(static_cast<int>(found - names.begin()));
    }
    if (references.empty()) references.push_back(-1);

    fs::remove_all(context.workspace.Path("volume"));
    nlohmann::json volumes = nlohmann::json::array();
    double total_seconds_init = 0, total_seconds_fit = 0;
    for (const int reference : references) {
      const std::string folder = reference < 0 ? "mean" : Stem(names[reference]);
      // The range first from the mean pose (cheap), then the camera with its widened image.
      VirtualCamera provisional = ChooseVirtualCamera(views, reference, 1.0, 2.0, options);
      // The views this volume is fitted to: all, or the views_per_volume nearest its camera (the
      // reference view first, at distance 0).
      std::vector<VolumeView> fitted = views;
      int fitted_reference = reference;
      const size_t per_volume = static_cast<size_t>(context.params.Int("views_per_volume"));
      if (per_volume > 0 && per_volume < views.size()) {
        const Eigen::Vector3d centre = provisional.cam_from_world.Inverse().translation;
        std::stable_sort(fitted.begin(), fitted.end(), [&](const VolumeView& a, const VolumeView& b) {
          return (a.cam_from_world.Inverse().translation - centre).norm() < (b.cam_from_world.Inverse().translation - centre).norm();
        });
        fitted.resize(per_volume);
        if (reference >= 0) {
          fitted_reference = static_cast<int>(std::find_if(fitted.begin(), fitted.end(), [&](const VolumeView& v) {
                                                 return v.name == names[reference];
                                               }) - fitted.begin());
        }
      }
      std::string source;
      double near = 0, far = 0;
      DepthRange(context, model, provisional.cam_from_world, &near, &far, &source);
      VirtualCamera virtual_camera = ChooseVirtualCamera(fitted, fitted_reference, near, far, options);
      double needed_mb = VolumeFitBytes(virtual_camera, fitted, options) / 1048576.0;
      spdlog::info("[volume] {}: {} planes of {}x{} between depth {:.4g} and {:.4g} ({}); fitting needs about {:.0f} MB",
                   folder, options.num_planes, virtual_camera.camera.width, virtual_camera.camera.height, near, far,
                   source, needed_mb);
      VolumeOptions sized = options;  // the resolution and widening this volume fits the budget with
      if (needed_mb > options.max_memory_mb && context.params.Bool("fit_memory")) {
        const int width = virtual_camera.camera.width, height = virtual_camera.camera.height;
        // The planes' pixels dominate the estimate: shrink the side by the square root of the excess
        // (5% under it), the widening first down to 1 (the frusta's margins cost least), then the
        // resolution; again while the estimate (which has fixed parts: the views) is still over. A
        // cap on the widening above what the frusta need changes nothing: the resolution then
        // shrinks too.
        for (int attempt = 0; attempt < 12 && needed_mb > sized.max_memory_mb; ++attempt) {
          const double shrink = std::sqrt(sized.max_memory_mb / needed_mb) * 0.95;
          const double before_mb = needed_mb;
          if (sized.max_widen > 1) {
            sized.max_widen = std::max(1.0, sized.max_widen * shrink);
            virtual_camera = ChooseVirtualCamera(fitted, fitted_reference, near, far, sized);
            needed_mb = VolumeFitBytes(virtual_camera, fitted, sized) / 1048576.0;
          }
          if (needed_mb > 0.99 * before_mb) {  // the widening did not bind: lower the resolution
            sized.resolution *= shrink;
            virtual_camera = ChooseVirtualCamera(fitted, fitted_reference, near, far, sized);
            needed_mb = VolumeFitBytes(virtual_camera, fitted, sized) / 1048576.0;
          }
        }
        spdlog::info("[volume] {}: {} planes of {}x{} would need more than volume.max_memory_mb ({}); fitted at "
                     "resolution {:.3g} (of {}), widening at most {:.3g} (of {}): {}x{}, about {:.0f} MB",
                     folder, options.num_planes, width, height, Number(options.max_memory_mb), sized.resolution,
                     Number(options.resolution), sized.max_widen, Number(options.max_widen),
                     virtual_camera.camera.width, virtual_camera.camera.height, needed_mb);
      }
      if (needed_mb > sized.max_memory_mb) {
        throw InputError("volume: " + std::to_string(options.num_planes) + " planes of " +
                         std::to_string(virtual_camera.camera.width) + "x" + std::to_string(virtual_camera.camera.height) +
                         " need about " + std::to_string(static_cast<int>(needed_mb)) + " MB to fit, more than volume.max_memory_mb (" +
                         Number(options.max_memory_mb) + "); lower volume.num_planes or volume.resolution, or raise volume.max_memory_mb" +
                         (context.params.Bool("fit_memory") ? "" : ", or set volume.fit_memory: true"));
      }
      const VolumeResult result = FitPlaneVolume(fitted, virtual_camera, sized, context.progress);
      nlohmann::json fitted_names = nlohmann::json::array();
      for (const VolumeView& view : fitted) fitted_names.push_back(view.name);
      WritePlaneVolume(context.workspace.Path("volume/" + folder), result.volume);
      WriteImage(context.workspace.Path("volume/" + folder + "/strip.png"), PlaneStrip(result.volume, 160));
      nlohmann::json curve = nlohmann::json::array();
      for (const VolumeCurvePoint& point : result.curve) {
        curve.push_back({{"level", point.level}, {"iteration", point.iteration}, {"objective", point.objective}, {"data", point.data}});
      }
      volumes.push_back({{"folder", "volume/" + folder},
                         {"reference", reference < 0 ? "mean" : names[reference]},
                         {"views", fitted_names},
                         {"width", virtual_camera.camera.width},
                         {"height", virtual_camera.camera.height},
                         {"planes", options.num_planes},
                         {"near", near},
                         {"far", far},
                         {"depth_source", source},
                         {"memory_estimate_mb", needed_mb},
                         {"resolution", sized.resolution},
                         {"max_widen", sized.max_widen},
                         {"init_seconds", result.init_seconds},
                         {"fit_seconds", result.fit_seconds},
                         {"initial_data", result.initial_data},
                         {"final_data", result.final_data},
                         {"curve", curve}});
      total_seconds_init += result.init_seconds;
      total_seconds_fit += result.fit_seconds;
      spdlog::info("[volume] {}: data term {:.5f} -> {:.5f} at full size; init {:.1f} s, fit {:.1f} s", folder,
                   result.initial_data, result.final_data, result.init_seconds, result.fit_seconds);
    }
    context.metrics["volumes"] = volumes;
    context.metrics["init_seconds"] = total_seconds_init;
    context.metrics["fit_seconds"] = total_seconds_fit;
  }

 private:
  static VolumeOptions ToOptions(const Params& p) {
    VolumeOptions o;
    o.num_planes = static_cast<int>(p.Int("num_planes"));
    o.resolution = p.Double("resolution");
    o.max_widen = p.Double("max_widen");
    o.window_radius = static_cast<int>(p.Int("window_radius"));
    o.vote_temperature = p.Double("vote_temperature");
    o.visibility_rounds = static_cast<int>(p.Int("visibility_rounds"));
    o.levels = static_cast<int>(p.Int("levels"));
    o.iterations = static_cast<int>(p.Int("iterations"));
    o.min_iterations = static_cast<int>(p.Int("min_iterations"));
    o.optimizer = p.String("optimizer") == "gradient_descent" ? VolumeOptimizer::kGradientDescent : VolumeOptimizer::kAdam;
    o.learning_rate = p.Double("learning_rate");
    o.views_per_step = static_cast<int>(p.Int("views_per_step"));
    o.robust_epsilon = p.Double("robust_epsilon");
    o.smoothness = p.Double("smoothness");
    o.opacity_prior = p.Double("opacity_prior");
    o.max_memory_mb = p.Double("max_memory_mb");
    return o;
  }

  // The planes' depth range in the virtual camera `cam_from_world` (see the header comment).
  static void DepthRange(const StageContext& context, const SparseModel& model, const Rigid3d& cam_from_world,
                         double* near, double* far, std::string* source) {
    if (context.params.Double("min_depth") > 0) {
      *near = context.params.Double("min_depth");
      *far = context.params.Double("max_depth");
      *source = "config";
      return;
    }
    const std::string bounds_path = context.workspace.Path("sparse/depth_bounds.json");
    if (fs::exists(bounds_path)) {
      const nlohmann::json bounds = ReadStageJson(bounds_path, "import", "volume");
      double lo = 1e300, hi = 0;
      for (const auto& [name, entry] : bounds.items()) {
        if (!entry.is_object() || !entry.contains("near") || !entry.contains("far") || !entry["near"].is_number() ||
            !entry["far"].is_number() || !(entry["near"].get<double>() > 0) ||
            !(entry["far"].get<double>() > entry["near"].get<double>())) {
          throw IoError(bounds_path + ": entry '" + name + "' needs numbers 0 < near < far; re-run import");
        }
        if (context.IsHeldOut(name)) continue;
        lo = std::min(lo, entry["near"].get<double>());
        hi = std::max(hi, entry["far"].get<double>());
      }
      if (hi > lo) {
        *near = lo;
        *far = hi;
        *source = "sparse/depth_bounds.json";
        return;
      }
    }
    std::vector<double> depths;
    for (const auto& [id, point] : model.points) {
      const double z = (cam_from_world * point.xyz).z();
      if (z > 0) depths.push_back(z);
    }
    if (depths.size() < 8) {
      throw InputError("volume: no depth range: volume.min_depth/max_depth are not set, sparse/depth_bounds.json is "
                       "absent, and fewer than 8 sparse points lie in front of the virtual camera; set "
                       "volume.min_depth and volume.max_depth in the config");
    }
    std::sort(depths.begin(), depths.end());
    const double margin = context.params.Double("depth_margin");
    // The nearest point (thin occluders near the cameras hold few points) and the 99th percentile.
    const double lo = depths.front(), hi = depths[depths.size() - 1 - depths.size() / 100];
    *near = lo * (1 - margin);
    *far = hi * (1 + margin);
    if (!(*far > *near && *near > 0)) *near = 0.5 * hi, *far = 2 * hi;
    *source = "sparse_points";
  }
};

}  // namespace

void RegisterStage_volume(StageRegistry* registry) { registry->Add(std::make_unique<VolumeStage>()); }

}  // namespace ibmr
