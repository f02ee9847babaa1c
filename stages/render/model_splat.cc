// The point splatting render models (seed 004, sections 4.3-4.6 and 5.4; splat.h):
//   splat_depth[:TYPE][@N]        the training views' depth maps, dense/stereo/depth_maps/<view>.<TYPE>.bin
//                                 (TYPE: splat_depth_type by default; "truth": ground_truth/depth/<view>.bin)
//                                 with the photos, skins and outliers flagged (depth_images.h), every
//                                 drawable sample kept; @N: from every N x N block
//   splat_depth_merged[:TYPE][@N] the same after tile merging [N 4.6]: one sample per surface point
//   splat_surfels                 the oriented discs of surfels/surfels.ply
// A missing input (no depth maps, no surfels) skips the model. exclude_self leaves a training view's
// own depth samples out (its depth map still took part in the skin test and the merging); surfels
// are one model made from every photo.
#include <spdlog/spdlog.h>

#include <chrono>
#include <filesystem>
#include <mutex>
#include <set>

#include "pipeline/core/errors.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/process_memory.h"
#include "stages/render/depth_image_io.h"
#include "stages/render/render_model.h"
#include "stages/render/splat.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

SplatOptions ToSplatOptions(const Params& params) {
  SplatOptions options;
  options.radius_scale = params.Double("splat_radius_scale");
  options.max_radius_px = params.Double("splat_max_radius_px");
  options.max_stretch = params.Double("splat_max_stretch");
  options.depth_tolerance = params.Double("splat_depth_tolerance");
  options.angle_epsilon_deg = params.Double("splat_angle_epsilon_deg");
  options.k = static_cast<int>(params.Int("splat_k"));
  return options;
}

DepthImageOptions ToDepthImageOptions(const Params& params) {
  DepthImageOptions options;
  options.min_confidence = params.Double("splat_min_confidence");
  options.skin_tolerance = params.Double("skin_tolerance");
  options.skin_views = static_cast<int>(params.Int("skin_views"));
  options.free_space_views = static_cast<int>(params.Int("free_space_views"));
  options.color_tolerance = static_cast<int>(params.Int("color_tolerance"));
  options.merge_tolerance = params.Double("merge_tolerance");
  options.merge_views = static_cast<int>(params.Int("merge_views"));
  return options;
}

bool KnownDepthType(const std::string& type) { return type == "geometric" || type == "photometric" || type == "truth"; }

// A splat model: a cloud of samples made once, drawn into any number of views.
class SplatModel : public RenderModel {
 public:
  using RenderModel::RenderModel;

  ModelView Render(const RenderScene& scene, const DesiredView& view) const override {
    const auto start = std::chrono::steady_clock::now();
    const Camera camera = scene.factor > 1 ? view.camera.Scaled(scene.factor) : view.camera;
    const int self = DrawsSourceRays() ? scene.SelfSource(view.name) : -1;
    const SplatImage splats =
        RenderSplats(cloud_, camera, view.cam_from_world, splat_options_, self);
    ModelView drawn;
    drawn.fine.image = splats.image;
    drawn.fine.coverage = splats.coverage;
    drawn.fine.covered_pixels = splats.covered_pixels;
    drawn.sources = DrawsSourceRays() ? scene.training.size() - (self >= 0 ? 1 : 0) : 0;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::lock_guard<std::mutex> lock(mutex_);
    seconds_ += seconds;
    megapixels_ += 1e-6 * view.camera.width * view.camera.height;
    return drawn;
  }

  void AddMetrics(nlohmann::json* metrics) const override {
    if (cloud_.size() == 0 || !(megapixels_ > 0)) return;
    // Speed of the splatting alone: milliseconds per output megapixel per million samples.
    (*metrics)["ms_per_megapixel_per_million_splats_" + Name()] =
        1e3 * seconds_ / megapixels_ / (1e-6 * cloud_.size());
  }

 protected:
  // True when the samples come from the training views' depth maps (leave-one-out applies).
  virtual bool DrawsSourceRays() const = 0;

  SplatCloud cloud_;
  SplatOptions splat_options_;  // the render stage's splat keys, read once in Prepare

 private:
  mutable std::mutex mutex_;
  mutable double seconds_ = 0, megapixels_ = 0;  // the views' splatting
};

class DepthSplatModel : public SplatModel {
 public:
  DepthSplatModel(ModelEntry entry, const Workspace&, bool merge = false)
      : SplatModel(std::move(entry)), merge_(merge) {}

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {DepthType(context.params) == "truth" ? "ground_truth/depth" : "dense/stereo"};
  }
  std::string SourcePath(const Workspace&) const override { return "dense/stereo"; }

  // The training views' depth images, flagged, skins found, merged [N 4.3-4.6].
  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) override {
    const auto start = std::chrono::steady_clock::now();
    depth_type_ = DepthType(scene.context->params);
    splat_options_ = ToSplatOptions(scene.context->params);
    DepthImageOptions options = ToDepthImageOptions(scene.context->params);
    options.merge = merge_;
    std::vector<DepthImage> images;
    try {
      images = LoadDepthImages(scene.context->workspace, *scene.model, scene.training, depth_type_);
    } catch (const InputError& e) {  // no depth maps (yet): like a missing mesh, not fatal
      return std::string(e.what());
    }
    if (entry_.detail > 1) {
      for (DepthImage& image : images) image = DownsampleDepthImage(image, entry_.detail);
    }
    size_t drawable = 0, outliers = 0;
    for (DepthImage& image : images) {
      FlagSamples(&image, options.min_confidence);
      for (const uint8_t flag : image.flags) drawable += IsDrawable(flag);
    }
    const size_t skins = DetectSkins(&images, options, &outliers);
    const size_t merged = MergeTiles(&images, options);
    const size_t views = images.size();
    cloud_ = CloudFromDepthImages(std::move(images));
    // The depth images' memory back to the system: when the models before this one left the heap
    // with free space, the images were placed there, and free() keeps such memory resident (the
    // full-size castle after vdtm: 1757 -> 1042 MB held while the views are drawn).
    ReleaseFreeHeap();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    spdlog::info("[render] splat_depth{} ({}): {} views, {} samples, {} skin connections, {} outliers, {} merged "
                 "away -> {} splats ({:.1f} s)",
                 merge_ ? "_merged" : "", depth_type_, views, drawable, skins, outliers, merged, cloud_.size(), seconds);
    (*facts)["samples_before_merge"] = drawable;
    (*facts)["samples"] = cloud_.size();
    (*facts)["skin_connections"] = skins;
    (*facts)["outliers"] = outliers;
    (*facts)["merged_away"] = merged;
    return std::nullopt;
  }

  // Samples as an RGBD image stores them: 3 colour and 4 depth bytes each.
  nlohmann::json Size() const override {
    return {{"kind", "depth_samples"}, {"elements", cloud_.size()}, {"bytes", cloud_.size() * 7}};
  }
  bool FromTruth(const Workspace&) const override { return depth_type_ == "truth"; }
  void AddMetrics(nlohmann::json* metrics) const override {
    SplatModel::AddMetrics(metrics);
    (*metrics)["samples_" + Name()] = cloud_.size();
  }

 protected:
  bool DrawsSourceRays() const override { return true; }

 private:
  std::string DepthType(const Params& params) const {
    return entry_.option.empty() ? params.String("splat_depth_type") : entry_.option;
  }

  bool merge_;
  std::string depth_type_;
};

// splat_depth_merged: one sample per surface point (tile merging, [N 4.6]).
class MergedDepthSplatModel : public DepthSplatModel {
 public:
  MergedDepthSplatModel(ModelEntry entry, const Workspace& workspace)
      : DepthSplatModel(std::move(entry), workspace, true) {}
};

class SurfelSplatModel : public SplatModel {
 public:
  SurfelSplatModel(ModelEntry entry, const Workspace& workspace)
      : SplatModel(std::move(entry)), path_(workspace.Path("surfels/surfels.ply")) {}

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.Relative(path_)};
  }
  std::string SourcePath(const Workspace& workspace) const override { return workspace.Relative(path_); }
  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) override {
    splat_options_ = ToSplatOptions(scene.context->params);
    if (!fs::exists(path_)) return path_ + " does not exist (run the surfels stage)";
    cloud_ = CloudFromSurfels(ReadPointCloudPly(path_), 0.f);
    if (cloud_.size() == 0) return path_ + " holds no finite surfel";
    (*facts)["samples"] = cloud_.size();
    return std::nullopt;
  }
  // The surfels as their file stores them.
  nlohmann::json Size() const override {
    std::error_code ec;
    const auto bytes = fs::file_size(path_, ec);
    return {{"kind", "surfels"}, {"elements", cloud_.size()}, {"bytes", ec ? uintmax_t{0} : bytes}};
  }
  bool MadeFromEveryPhoto() const override { return true; }

 protected:
  bool DrawsSourceRays() const override { return false; }

 private:
  std::string path_;
};

std::string CheckDepthType(const ModelEntry& entry) {
  return entry.option.empty() || KnownDepthType(entry.option)
             ? std::string()
             : "\"" + entry.entry + "\": depth type must be geometric, photometric or truth";
}

// The splat options and depth image options (their YAML keys carry a prefix the structs do not
// know), and splat_depth_type.
std::optional<ParamError> CheckSplatParams(const Params& params) {
  std::string error;
  if (!ToSplatOptions(params).Check(&error) || !ToDepthImageOptions(params).Check(&error)) {
    const ParamError e = ParamError::FromCheck(error);
    static const std::set<std::string> unprefixed = {"skin_tolerance",  "skin_views",  "free_space_views", "color_tolerance",
                                                     "merge_tolerance", "merge_views", "tile_size"};
    return ParamError{unprefixed.count(e.key) ? e.key : (e.key == "min_confidence" ? "splat_min_confidence" : "splat_" + e.key),
                      e.message};
  }
  if (!KnownDepthType(params.String("splat_depth_type"))) {
    return ParamError{"splat_depth_type",
                      "must be geometric, photometric or truth, got \"" + params.String("splat_depth_type") + "\""};
  }
  return std::nullopt;
}

// splat_depth and splat_depth_merged: "splat_depth_truth" for splat_depth:truth.
template <typename Model>
RenderModelKind DepthSplatKind(const std::string& keyword, const std::string& summary) {
  RenderModelKind kind = NewRenderModelKind<Model>(keyword, summary);
  kind.syntax = keyword + "[:TYPE][@N]";
  kind.max_detail = 16;
  kind.detail_meaning = "block size of " + keyword;
  kind.takes_option = true;
  kind.check_entry = CheckDepthType;
  kind.default_name = [](const ModelEntry& entry) {
    return entry.keyword + (entry.option.empty() ? "" : "_" + entry.option);
  };
  return kind;
}

}  // namespace

RenderModelKind SplatDepthKind() {
  RenderModelKind kind = DepthSplatKind<DepthSplatModel>(
      "splat_depth", "point splats of the training views' depth maps (TYPE geometric, photometric or truth; @N: N x N "
                     "blocks) with skins and outliers flagged (seed 004)");
  kind.params = {
      {"splat_depth_type", ParamType::kString, "geometric",
       "depth maps splat_depth draws: geometric (multi_depth), photometric (plane_sweep) or truth "
       "(ground_truth/depth); an entry splat_depth:TYPE overrides it",
       {}},
      {"splat_radius_scale", ParamType::kDouble, "1",
       "scales the splats' radii (source pixel half-diagonals, surfel radii), in (0, 8]", {}},
      {"splat_max_radius_px", ParamType::kDouble, "8", "bound on a splat's radius in output pixels, in [0.5, 256]", {}},
      {"splat_max_stretch", ParamType::kDouble, "2",
       "bound on a depth sample's footprint along its tangent plane, in source pixels, in [1, 16]; "
       "larger trusts the normals at grazing angles (true depth: 4 -> +1.6 dB, stereo depth: -0.1 to -0.3 dB)",
       {}},
      {"splat_depth_tolerance", ParamType::kDouble, "0.05", "relative depth band of samples blended at a pixel, in (0, 1)",
       {}},
      {"splat_angle_epsilon_deg", ParamType::kDouble, "0.5", "softens the 1/angle^2 weight of a sample's source ray, in (0, 90]",
       {}},
      {"splat_k", ParamType::kInt, "4",
       "source views blended per pixel by splat_depth (ULR's k); 0: all, weighted 1/angle^2, in [0, 8]", {}},
      {"splat_min_confidence", ParamType::kDouble, "0", "depth samples below this confidence are not drawn, in [0, 1]", {}},
      {"skin_tolerance", ParamType::kDouble, "0.02", "relative free-space margin of skin detection, in (0, 1)", {}},
      {"skin_views", ParamType::kInt, "8", "views each depth image is tested against for skins (0: none), in [0, 64]", {}},
      {"free_space_views", ParamType::kInt, "2",
       "a depth sample in front of the depth of this many of the skin_views views is dropped (0: kept), in [0, 64]", {}},
      {"color_tolerance", ParamType::kInt, "0",
       "a depth sample whose colour differs by more than this (0-255) from most views that see its surface is "
       "dropped (0: no colour test), in [0, 255]",
       {}},
      {"merge_tolerance", ParamType::kDouble, "0.01", "relative depth agreement of merged samples, in (0, 1)", {}},
      {"merge_views", ParamType::kInt, "8", "views a depth sample is compared with when merging, in [1, 64]", {}},
  };
  kind.check_params = CheckSplatParams;
  return kind;
}

RenderModelKind SplatDepthMergedKind() {
  return DepthSplatKind<MergedDepthSplatModel>(
      "splat_depth_merged", "splat_depth after tile merging: one sample per surface point (seed 004 [N 4.6])");
}

RenderModelKind SplatSurfelsKind() {
  return NewRenderModelKind<SurfelSplatModel>("splat_surfels", "the oriented discs of surfels/surfels.ply");
}

}  // namespace ibmr
