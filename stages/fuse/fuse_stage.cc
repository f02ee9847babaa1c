// Adapter of the fuse stage (seed 000 lines 4352-4453): streams the training views' depth, normal
// and confidence maps (.geometric.bin from multi_depth by default) and photos into PointFuser and
// writes dense/fused.ply (binary PLY: x y z nx ny nz red green blue confidence, as COLMAP's
// stereo_fusion output plus a confidence). With ground_truth/mesh.ply in the workspace the record
// gets accuracy (90th percentile distance to the mesh) and completeness.
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <filesystem>
#include <future>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/params.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/fuse/fuse.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

class FuseStage : public Stage {
 public:
  std::string Name() const override { return "fuse"; }
  std::string Summary() const override {
    return "Uncertainty-weighted merge of depth samples into points with normals, colour, confidence (dense/fused.ply)";
  }
  // 4: the points' confidence times their samples' agreement (agreement_weighting); min_confidence 0.02;
  // 5: times the surface factor (surface_neighbours)
  std::string Version() const override { return "5"; }  // 2: normals from depth in float (core); 3: no accuracy without points; confidence-error rank correlation
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }

  std::vector<ParamSpec> Parameters() const override {
    const FuseOptions d;  // the defaults are the options struct's
    return {
        {"input_type", ParamType::kString, "geometric", "Which depth maps to fuse (layered: layered_stereo's combined maps)",
         {"geometric", "photometric", "layered"}},
        {"relative_depth_sigma", ParamType::kDouble, DefaultNumberText(d.relative_depth_sigma), "Depth std / depth of a confidence-1 sample, in (0, 0.2]"},
        {"lateral_sigma_pixels", ParamType::kDouble, DefaultNumberText(d.lateral_sigma_pixels), "Std across the ray in pixels of footprint, in (0, 10]"},
        {"merge_sigmas", ParamType::kDouble, DefaultNumberText(d.merge_sigmas), "Uncertainty-weighted depth distance for a merge, in (0, 100]"},
        {"merge_pixel_radius", ParamType::kDouble, DefaultNumberText(d.merge_pixel_radius),
         "Re-projection distance to the centre of the pixel it falls in for a merge, pixels, (0, 0.71]; 0.71: anywhere in it"},
        {"max_normal_angle_deg", ParamType::kDouble, DefaultNumberText(d.max_normal_angle_deg), "Normals of merged samples within this, degrees, (0, 180]"},
        {"min_confidence", ParamType::kDouble, DefaultNumberText(d.min_confidence), "Samples below this confidence are skipped, [0, 1]"},
        {"agreement_weighting", ParamType::kBool, d.agreement_weighting ? "true" : "false",
         "Point confidence times the samples' agreement (chi-square about the merged position per view beyond 1 lowers it)"},
        {"min_views", ParamType::kInt, std::to_string(d.min_views), "Views that must have contributed to a point, [1, 1000]"},
        {"surface_neighbours", ParamType::kInt, std::to_string(d.surface_neighbours),
         "Point confidence times how close it lies to the plane through this many nearest points (0: off, [4, 256])"},
        {"surface_residual_scale", ParamType::kDouble, DefaultNumberText(d.surface_residual_scale),
         "That plane distance at which the factor is exp(-1/2), in medians of the cloud's distances, > 0"},
        {"eval_threshold", ParamType::kDouble, "-1", "Completeness distance, scene units; -1: 1% of the true mesh's bounding-box diagonal"},
        {"eval_samples", ParamType::kInt, "200000", "Surface samples for completeness, [1000, 10000000]"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    const int64_t samples = params.Int("eval_samples");
    if (samples < 1000 || samples > 10000000) return ParamError{"eval_samples", "must be in [1000, 10000000], got " + std::to_string(samples)};
    const double threshold = params.Double("eval_threshold");
    if (!(threshold > 0 || threshold == -1)) return ParamError{"eval_threshold", "must be > 0 or -1, got " + std::to_string(threshold)};
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    const std::string kind = context.params.String("input_type");
    std::vector<std::string> inputs = {context.workspace.SparseRelative(), context.workspace.ImagesRelative()};
    const std::vector<std::string> names = context.TrainingImageNamesIfReadable();
    if (names.empty()) {
      for (const char* folder : {"dense/stereo/depth_maps", "dense/stereo/normal_maps", "dense/stereo/confidence_maps"}) inputs.push_back(folder);
    }
    for (const std::string& name : names) {
      inputs.push_back("dense/stereo/depth_maps/" + name + "." + kind + ".bin");
      inputs.push_back("dense/stereo/normal_maps/" + name + "." + kind + ".bin");
      inputs.push_back(Workspace::ConfidenceMapRelative(name, kind));
    }
    inputs.push_back("ground_truth/mesh.ply");  // metrics only; "missing" on real data
    inputs.push_back("masks");                  // metrics only (silhouette check); may be missing
    return inputs;
  }

  std::vector<std::string> Outputs(const StageContext&) const override { return {"dense/fused.ply"}; }

  void Run(StageContext& context) const override {
    const FuseOptions options = ToOptions(context.params);
    const std::string kind = context.params.String("input_type");
    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.empty()) throw InputError("fuse: sparse/ has no training view");
    const Workspace& workspace = context.workspace;
    PointFuser fuser(options);
    context.progress->Begin("fusing depth maps", names.size());
    // Streamed: one view's maps in memory while the next view's are read (a thread of its own).
    auto load = [&](const std::string& name) {
      const Image& image = *model.FindImage(name);
      FuseView view;
      view.camera = model.CameraOf(image);
      view.cam_from_world = image.cam_from_world;
      const std::string depth_path = workspace.DepthMapPath(name, kind);
      if (!fs::exists(depth_path)) {
        throw InputError(depth_path + ": no " + kind + " depth map for view '" + name + "'; run " +
                         (kind == "geometric" ? "multi_depth" : kind == "layered" ? "layered_stereo" : "plane_sweep") +
                         " first (or set fuse.input_type)");
      }
      view.depth = ReadColmapArray(depth_path);
      view.normals = ReadColmapArrayMatching(workspace.NormalMapPath(name, kind), view.depth, 3);
      view.confidence = ReadColmapArrayMatching(workspace.ConfidenceMapPath(name, kind), view.depth, 1);
      const std::string image_path = workspace.ImagesDir() + "/" + name;
      if (fs::exists(image_path)) {
        view.image = ReadImageColor(image_path);
      } else {
        spdlog::warn("[fuse] {}: no photo; points from this view are grey", image_path);
      }
      return view;
    };
    std::future<FuseView> next = std::async(std::launch::async, load, names.front());
    for (size_t i = 0; i < names.size(); ++i) {
      const FuseView view = next.get();
      if (i + 1 < names.size()) next = std::async(std::launch::async, load, names[i + 1]);
      fuser.AddView(view);
      context.progress->Advance(1, names[i]);
    }
    context.progress->End();
    FuseStats stats;
    PointCloud cloud = fuser.Finish(&stats);
    const std::vector<float> surface = SurfaceFactors(cloud.positions, options.surface_neighbours, options.surface_residual_scale);
    for (size_t i = 0; i < cloud.size(); ++i) cloud.confidence[i] *= surface[i];
    cloud.comments.push_back("ibmr fuse " + Version() + " from " + kind + " depth maps of " + std::to_string(names.size()) + " views");
    WritePointCloudPly(workspace.Path("dense/fused.ply"), cloud);

    nlohmann::json& m = context.metrics;
    m["views"] = names.size();
    m["samples"] = stats.samples;
    m["merged_samples"] = stats.merged;
    m["points_before_min_views"] = stats.points;
    m["points"] = stats.kept_points;
    m["samples_per_point"] = stats.kept_points ? double(stats.samples) / stats.points : 0.0;
    spdlog::info("[fuse] {} views, {} samples -> {} points ({} seen in >= {} views)", names.size(), stats.samples, stats.points,
                 stats.kept_points, options.min_views);
    if (stats.kept_points == 0) {
      spdlog::warn("[fuse] no point is left: {}", stats.samples == 0
                   ? fmt::format("the {} views' {} depth maps hold no sample (the stereo stages' warnings say why)", names.size(), kind)
                   : fmt::format("{} samples made {} points, none seen in fuse.min_views = {} views (lower it, or add views)",
                                 stats.samples, stats.points, options.min_views));
    }
    if (fs::exists(workspace.GroundTruthMeshPath())) Evaluate(context, model, names, cloud);
    if (fs::is_directory(workspace.MasksDir())) CheckSilhouettes(context, model, names, cloud);
  }

 private:
  void Evaluate(StageContext& context, const SparseModel& model, const std::vector<std::string>& names,
                const PointCloud& cloud) const {
    const Workspace& workspace = context.workspace;
    const TriangleMesh mesh = ReadMeshPly(workspace.GroundTruthMeshPath());
    Eigen::Vector3f lo, hi;
    if (!mesh.Bounds(&lo, &hi) || mesh.faces.empty()) return;
    double threshold = context.params.Double("eval_threshold");
    if (threshold <= 0) threshold = 0.01 * (hi - lo).norm();
    const std::vector<Eigen::Vector3f> samples = SampleSurface(mesh, static_cast<size_t>(context.params.Int("eval_samples")));
    std::vector<char> visible(samples.size(), 0);
    bool have_visibility = false;
    for (const std::string& name : names) {  // surface the training views see (true depth maps)
      const std::string truth_path = workspace.GroundTruthDepthPath(name);
      if (!fs::exists(truth_path)) continue;
      const Image& image = *model.FindImage(name);
      MarkVisible(samples, model.CameraOf(image), image.cam_from_world, ReadColmapArray(truth_path), 0.01, &visible);
      have_visibility = true;
    }
    const PointSetAccuracy a = EvaluatePointSet(cloud, mesh, samples, threshold, have_visibility ? &visible : nullptr);
    nlohmann::json& m = context.metrics;
    m["completeness"] = a.completeness;
    if (cloud.size() == 0) {  // no point has a distance: no accuracy (0 would read as perfect)
      spdlog::warn("[fuse] no fused point: accuracy undefined, completeness 0");
      return;
    }
    m["accuracy_90"] = a.accuracy_90;
    m["accuracy_median"] = a.accuracy_median;
    if (have_visibility) m["completeness_visible"] = a.completeness_visible;
    m["eval_threshold"] = threshold;
    m["accuracy_90_over_threshold"] = a.accuracy_90 / threshold;
    m["confidence_error_spearman"] = a.confidence_error_spearman;  // rank correlation, points' confidence vs distance
    m["sparsification_auc_ratio"] = a.sparsification_auc_ratio;    // its sparsification area over the optimal one
    spdlog::info("[fuse] accuracy (90%) {:.4g}, completeness {:.1f}% ({:.1f}% of the seen surface) within {:.4g}", a.accuracy_90,
                 100 * a.completeness, 100 * std::max(0.0, a.completeness_visible), threshold);
  }

  // Fraction of the fused points, per training view with a mask, that project onto the silhouette.
  static void CheckSilhouettes(StageContext& context, const SparseModel& model, const std::vector<std::string>& names,
                               const PointCloud& cloud) {
    // Views in parallel; gathered in name order.
    std::vector<SilhouetteHits> hits(names.size());
    tbb::parallel_for(size_t{0}, names.size(), [&](size_t i) {
      const std::string path = context.workspace.MaskPath(names[i]);
      if (!fs::exists(path)) return;
      const Image& image = *model.FindImage(names[i]);
      const cv::Mat mask = ReadImageUnchanged(path);
      if (mask.type() != CV_8UC1) {
        spdlog::warn("[fuse] {}: not an 8-bit one-channel mask; not used for the silhouette check", path);
        return;
      }
      hits[i] = ProjectOntoSilhouette(cloud, model.CameraOf(image), image.cam_from_world, mask);
    });
    std::vector<double> fractions;
    nlohmann::json per_view = nlohmann::json::object();
    SilhouetteHits total;
    for (size_t i = 0; i < names.size(); ++i) {
      if (hits[i].projected == 0) continue;
      per_view[names[i]] = hits[i].Fraction();
      fractions.push_back(hits[i].Fraction());
      total.projected += hits[i].projected;
      total.on_silhouette += hits[i].on_silhouette;
    }
    if (fractions.empty()) return;
    std::sort(fractions.begin(), fractions.end());
    nlohmann::json& m = context.metrics;
    m["on_silhouette_fraction"] = total.Fraction();
    m["on_silhouette_fraction_min_view"] = fractions.front();
    m["on_silhouette_fraction_median_view"] = fractions[fractions.size() / 2];
    m["on_silhouette_per_view"] = per_view;
    spdlog::info("[fuse] {:.1f}% of the fused points project onto the silhouettes of masks/ ({} views; worst view {:.1f}%)",
                 100 * total.Fraction(), fractions.size(), 100 * fractions.front());
  }

  static FuseOptions ToOptions(const Params& params) {
    FuseOptions options;
    options.relative_depth_sigma = params.Double("relative_depth_sigma");
    options.lateral_sigma_pixels = params.Double("lateral_sigma_pixels");
    options.merge_sigmas = params.Double("merge_sigmas");
    options.merge_pixel_radius = params.Double("merge_pixel_radius");
    options.max_normal_angle_deg = params.Double("max_normal_angle_deg");
    options.min_confidence = params.Double("min_confidence");
    options.agreement_weighting = params.Bool("agreement_weighting");
    options.min_views = static_cast<int>(params.Int("min_views"));
    options.surface_neighbours = static_cast<int>(params.Int("surface_neighbours"));
    options.surface_residual_scale = params.Double("surface_residual_scale");
    return options;
  }
};

}  // namespace

void RegisterStage_fuse(StageRegistry* registry) { registry->Add(std::make_unique<FuseStage>()); }

}  // namespace ibmr
