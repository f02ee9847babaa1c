// Adapter of the multi_depth stage (seed 000 lines 3847-3894, 5812-5950): reads the photometric
// depth, normal and confidence maps that plane_sweep wrote, makes each training view's depth map
// consistent with its neighbours' (multi_depth.h) and writes the .geometric.bin maps. Views are
// streamed: a key view and its neighbours are loaded, processed and released, one key per task.
// Per view, its agreement with the other views (issue 67): the median over its neighbours of the
// fraction of its samples each confirms, and a flag on the views that stand out on the bad side
// (a robust z-score, pipeline/core/view_agreement.h), written to dense/stereo/view_agreement.json,
// into the record and, for flagged views, as a warning in the run's log.
// When ground_truth/depth/ exists (synthetic scenes) the record holds the fraction of pixels
// with true depth that are within 1% of it, before and after.
#include <spdlog/spdlog.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <memory>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_stereo_config.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/rank_correlation.h"
#include "pipeline/core/sparsification.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/view_agreement.h"
#include "pipeline/core/view_cache.h"
#include "stages/multi_depth/multi_depth.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// A damaged map of plane_sweep's: the runner sees plane_sweep as up to date (its inputs and
// parameters did not change), so a plain run would not rewrite it.
const std::string kRerunPlaneSweep = "re-run plane_sweep with --only plane_sweep --force (a plain run sees it as up to date)";

// A neighbour's confirmed fraction counts towards the key's figure when it sees at least this many
// of the key's samples (fewer: a sliver of overlap, too noisy to judge by).
constexpr size_t kMinSeenForAgreement = 200;
// A synthetic view is wrongly posed (ScoreViewFlags) when its written camera moves its points this
// many pixels or more on average: at the stability ring's 320x240, a pose the photo visibly contradicts.
constexpr double kWrongPosePx = 1.0;
const char* const kAgreementFigure =
    "confirmed fraction: the median over a view's neighbours of the fraction of its depth samples that a "
    "neighbour sees and finds within depth_tolerance of its own depth";

std::string ConfidencePath(const Workspace& workspace, const std::string& name, const std::string& kind) {
  return workspace.ConfidenceMapPath(name, kind);
}

// Loads a view's maps; `with_normals` false skips the normal map (neighbours do not need it).
DepthView LoadView(const Workspace& workspace, const SparseModel& model, const Image& image, bool with_normals) {
  DepthView view;
  view.name = image.name;
  view.camera = model.CameraOf(image);
  view.cam_from_world = image.cam_from_world;
  const std::string depth_path = workspace.DepthMapPath(image.name, "photometric");
  if (!fs::exists(depth_path)) {
    throw InputError(depth_path + ": no photometric depth map for view '" + image.name + "'; run plane_sweep first");
  }
  view.depth = ReadColmapArray(depth_path);
  if (view.depth.channels != 1) {
    throw InputError(depth_path + ": a depth map must have 1 channel, got " + std::to_string(view.depth.channels) + "; " +
                     kRerunPlaneSweep);
  }
  const std::string confidence_path = ConfidencePath(workspace, image.name, "photometric");
  if (fs::exists(confidence_path)) {
    view.confidence = ReadColmapArray(confidence_path);
    if (view.confidence.width != view.depth.width || view.confidence.height != view.depth.height || view.confidence.channels != 1) {
      throw InputError(confidence_path + ": size differs from the depth map's (" + std::to_string(view.depth.width) + "x" +
                       std::to_string(view.depth.height) + ", 1 channel); " + kRerunPlaneSweep);
    }
  }
  const std::string normal_path = workspace.NormalMapPath(image.name, "photometric");
  if (with_normals && fs::exists(normal_path)) {
    view.normals = ReadColmapArray(normal_path);
    if (view.normals.width != view.depth.width || view.normals.height != view.depth.height || view.normals.channels != 3) {
      throw InputError(normal_path + ": a normal map must match the depth map's size with 3 channels; " + kRerunPlaneSweep);
    }
  }
  return view;
}

class MultiDepthStage : public Stage {
 public:
  std::string Name() const override { return "multi_depth"; }
  std::string Summary() const override {
    return "Depth maps made consistent across views: visibility, depth compatibility, rejection (.geometric.bin)";
  }
  // 3: confidence-error rank correlation; 4: the confidence's geometric factor (geometric_sigma);
  // 5: per-view agreement and flag (view_agreement.json); 6: the confidence's surface factor (surface_window)
  std::string Version() const override { return "6"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  bool Shardable() const override { return true; }
  double ViewMemoryMb(const StageContext& context) const override {
    const double pixels = LargestTrainingImage(context).Pixels();
    // Bytes a pixel (multi_depth.cc): the key view's depth, normals and confidence (20), each
    // neighbour's depth and confidence (8; the neighbour cache holds about one more view's worth
    // per view in flight), the result (20), the key's pixel rays (12), each neighbour's samples
    // warped into the key (4), the first pass's depth and the mask of pixels near it (5), and
    // the program. Sceaux castle at 1600 px (1.92 Mpx, 8 neighbours): 395 MB estimated, 342 MB
    // measured above the start with one view in flight and 256 MB a view with two (they share
    // the cache); the count without the rays, warps and first pass gave 291 MB, short of the
    // one-view figure by 15%.
    const double neighbours = static_cast<double>(context.params.Int("max_neighbors"));
    const double bytes = pixels * (20.0 + 8.0 * (neighbours + 1) + 20.0 + 12.0 + 4.0 * neighbours + 5.0);
    return pixels > 0 ? bytes / 1048576.0 + 100.0 : 0.0;
  }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"depth_tolerance", ParamType::kDouble, "0.01", "Relative depth difference that counts as agreement, in (0, 0.5]"},
        {"min_consistent_views", ParamType::kInt, "2", "Other views that must confirm a sample, in [1, 64]"},
        {"violation_tolerance", ParamType::kDouble, "0.03",
         "A neighbour sees through a sample when its depth is farther by more than this (relative), in (0, 1]"},
        {"max_violation_ratio", ParamType::kDouble, "0.5", "Reject when free-space violations exceed ratio * confirmations, >= 0"},
        {"min_confidence", ParamType::kDouble, "0.1", "Photometric confidence below this drops a sample, in [0, 1]"},
        {"refine_depth", ParamType::kBool, "true", "Replace depth by the confidence-weighted mean of confirming depths"},
        {"max_neighbors", ParamType::kInt, "8", "Neighbour views per key view, in [1, 64]"},
        {"max_view_angle_deg", ParamType::kDouble, "80", "Neighbour viewing direction within this angle of the key's, degrees"},
        {"fill_from_neighbors", ParamType::kBool, "true", "Fill missing or rejected pixels with a neighbour depth that other views confirm"},
        {"min_baseline_ratio", ParamType::kDouble, "0.05", "Neighbour baseline >= ratio * the key's median baseline, in [0, 1)"},
        {"view_agreement_reference", ParamType::kDouble, "0.8",
         "A view's confidence is scaled by min(1, its samples' mean geometric consistency / this), [0, 1]; 0: off"},
        {"surface_window", ParamType::kInt, "3",
         "Confidence times how close a pixel's depth lies to the plane through the depths of the (2n+1)^2 around it, [0, 15]; 0: off"},
        {"surface_residual_scale", ParamType::kDouble, "2",
         "That plane distance at which the factor is exp(-1/2), in medians of the view's distances, > 0"},
        {"surface_floor", ParamType::kDouble, "0.5", "The surface factor's least value, [0, 1]"},
        {"geometric_sigma", ParamType::kDouble, "0.003",
         "Relative depth disagreement of a neighbour at which its factor of the confidence is exp(-1/2), [0, 0.5]; 0: off"},
        {"view_flag_z", ParamType::kDouble, "3.5",
         "A view is flagged when its confirmed fraction is this many robust sigmas (1.4826 MAD) below the views' median, > 0"},
        {"view_flag_min_scale", ParamType::kDouble, "0.08",
         "Least robust sigma of the confirmed fraction (a clean capture's views agree too uniformly to judge by their MAD), >= 0"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (!ToFlagOptions(params).Check(&error)) return ParamError::FromCheck(error);
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.SparseRelative()};
    const std::vector<std::string> names = context.TrainingImageNamesIfReadable();
    if (names.empty()) {  // before sparse/ exists: the folders, for dependency order only
      for (const char* folder : {"dense/stereo/depth_maps", "dense/stereo/normal_maps", "dense/stereo/confidence_maps"}) inputs.push_back(folder);
      return inputs;
    }
    for (const std::string& name : names) {
      inputs.push_back("dense/stereo/depth_maps/" + name + ".photometric.bin");
      inputs.push_back("dense/stereo/normal_maps/" + name + ".photometric.bin");
      inputs.push_back(Workspace::ConfidenceMapRelative(name, "photometric"));
    }
    inputs.push_back("ground_truth/depth");  // metrics only; "missing" on real data
    inputs.push_back("ground_truth/pose_error.json");
    return inputs;
  }

  std::vector<std::string> Outputs(const StageContext& context) const override {
    std::vector<std::string> outputs = {kFusionConfig, Workspace::ViewAgreementRelative()};
    for (const std::string& name : context.TrainingImageNamesIfReadable()) {
      outputs.push_back("dense/stereo/depth_maps/" + name + ".geometric.bin");
      outputs.push_back("dense/stereo/normal_maps/" + name + ".geometric.bin");
      outputs.push_back(Workspace::ConfidenceMapRelative(name, "geometric"));
    }
    return outputs;
  }

  void Run(StageContext& context) const override {
    const MultiDepthOptions options = ToOptions(context.params);
    const ViewFlagOptions flag_options = ToFlagOptions(context.params);
    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.size() < 2) {
      throw InputError("multi_depth: needs at least 2 training views to check depth maps against each other, " +
                       context.workspace.SparseDir() + " has " + std::to_string(names.size()) +
                       " (after holdout): hold out fewer views, or drop multi_depth and set fuse.input_type: photometric");
    }
    std::vector<const Image*> images;
    for (const std::string& name : names) images.push_back(model.FindImage(name));
    const Workspace& workspace = context.workspace;
    const bool has_truth = fs::is_directory(workspace.Path("ground_truth/depth"));

    // Neighbours' maps (depth and confidence) stay loaded while the views in flight may ask for them
    // again: a view's neighbours are mostly the previous view's.
    ViewCache<DepthView> neighbor_maps(CapacityForViewsInFlight(options.max_neighbors + 1),
                                       [&](const std::string& other) {
                                         return LoadView(workspace, model, *model.FindImage(other), /*with_normals=*/false);
                                       });
    const PerViewSummary summary = ForEachView(context, "consistent depth maps", names, [&](const std::string& name) {
      const Image& key_image = *model.FindImage(name);
      const DepthView key = LoadView(workspace, model, key_image, /*with_normals=*/true);
      std::vector<std::shared_ptr<const DepthView>> neighbors;
      for (int index : SelectNeighbors(key_image, images, options)) neighbors.push_back(neighbor_maps.Get(images[index]->name));
      std::vector<const DepthView*> pointers;
      for (const auto& n : neighbors) pointers.push_back(n.get());
      const MultiDepthResult result = MakeDepthConsistent(key, pointers, options);
      WriteColmapArray(workspace.DepthMapPath(name, "geometric"), result.depth);
      WriteColmapArray(workspace.NormalMapPath(name, "geometric"), result.normals);
      WriteColmapArray(ConfidencePath(workspace, name, "geometric"), result.confidence);

      const MultiDepthStats& st = result.stats;
      nlohmann::json piece = {
          {"stats", {st.input_samples, st.low_confidence, st.unconfirmed, st.violated, st.kept, st.filled}},
          {"without_neighbors", neighbors.empty()}, {"view_agreement", st.view_agreement}};
      nlohmann::json per_neighbor = nlohmann::json::array();
      for (const NeighborAgreement& n : st.neighbors) {
        per_neighbor.push_back({n.name, n.seen, n.confirmed, n.seen ? n.consistency_sum / n.seen : 0.0});
      }
      piece["neighbor_agreement"] = std::move(per_neighbor);
      double confirmed = 0;
      if (ViewConfirmedFraction(st, kMinSeenForAgreement, &confirmed)) piece["confirmed_fraction"] = confirmed;
      const std::string truth_path = workspace.GroundTruthDepthPath(name);
      if (has_truth && fs::exists(truth_path)) {
        const DepthMap truth = ReadColmapArray(truth_path);  // read once for all four measures
        const DepthAccuracy view_before = CompareDepth(key.depth, truth, 0.01);
        const DepthAccuracy view_after = CompareDepth(result.depth, truth, 0.01);
        // photometric confidence, its error; geometric confidence, its error
        std::vector<double> view_pairs[4];
        CollectConfidenceAndError(key.depth, key.confidence, truth, &view_pairs[0], &view_pairs[1]);
        CollectConfidenceAndError(result.depth, result.confidence, truth, &view_pairs[2], &view_pairs[3]);
        piece["before"] = {view_before.truth_pixels, view_before.estimated, view_before.within_tolerance};
        piece["after"] = {view_after.truth_pixels, view_after.estimated, view_after.within_tolerance};
        piece["pairs"] = {view_pairs[0], view_pairs[1], view_pairs[2], view_pairs[3]};
      }
      return piece;
    });

    // Totals over every view (resumed and sharded ones too), in name order.
    MultiDepthStats totals;
    DepthAccuracy before, after;
    std::vector<double> pairs[4];  // over views: as the pieces' pairs
    size_t views_without_neighbors = 0;
    std::vector<double> view_agreements;  // per view, in name order
    for (const auto& [name, piece] : summary.pieces) {
      const std::vector<size_t> st = piece.at("stats").get<std::vector<size_t>>();
      Accumulate(MultiDepthStats{st.at(0), st.at(1), st.at(2), st.at(3), st.at(4), st.at(5)}, &totals);
      if (piece.at("without_neighbors").get<bool>()) ++views_without_neighbors;
      if (piece.contains("view_agreement")) view_agreements.push_back(piece["view_agreement"].get<double>());
      if (!piece.contains("before")) continue;
      const std::vector<size_t> b = piece["before"].get<std::vector<size_t>>();
      const std::vector<size_t> a = piece["after"].get<std::vector<size_t>>();
      Accumulate(DepthAccuracy{b.at(0), b.at(1), b.at(2)}, &before);
      Accumulate(DepthAccuracy{a.at(0), a.at(1), a.at(2)}, &after);
      for (int k = 0; k < 4; ++k) {
        const std::vector<double> values = piece["pairs"][k].get<std::vector<double>>();
        pairs[k].insert(pairs[k].end(), values.begin(), values.end());
      }
    }

    WriteFileAtomic(workspace.Path(kFusionConfig), FormatFusionConfig(names));
    FlagDisagreeingViews(summary, flag_options, context);
    nlohmann::json& m = context.metrics;
    m["views"] = names.size();
    m["input_samples"] = totals.input_samples;
    m["dropped_low_confidence"] = totals.low_confidence;
    m["dropped_unconfirmed"] = totals.unconfirmed;
    m["dropped_free_space_violation"] = totals.violated;
    m["kept_samples"] = totals.kept;
    m["filled_from_neighbors"] = totals.filled;
    m["kept_fraction"] = totals.input_samples ? double(totals.kept) / totals.input_samples : 0.0;
    m["views_without_neighbors"] = views_without_neighbors;
    if (!view_agreements.empty()) {  // how well the views agree with their neighbours (geometric_sigma)
      std::sort(view_agreements.begin(), view_agreements.end());
      m["view_agreement_min"] = view_agreements.front();
      m["view_agreement_median"] = view_agreements[view_agreements.size() / 2];
    }
    if (before.truth_pixels > 0) {
      m["truth_pixels"] = before.truth_pixels;
      m["photometric_within_1pct_of_textured"] = before.FractionOfTruth();
      m["photometric_within_1pct_of_estimated"] = before.FractionOfEstimated();
      m["geometric_within_1pct_of_textured"] = after.FractionOfTruth();
      m["geometric_within_1pct_of_kept"] = after.FractionOfEstimated();
      m["geometric_kept_of_textured"] = double(after.estimated) / after.truth_pixels;
      // Does the confidence fall where the error rises? (Spearman's rho; negative is good.)
      m["photometric_confidence_error_spearman"] = SpearmanCorrelation(pairs[0], pairs[1]);
      m["geometric_confidence_error_spearman"] = SpearmanCorrelation(pairs[2], pairs[3]);
      // The area under each confidence's sparsification curve over the optimal one (1: perfect).
      m["photometric_sparsification_auc_ratio"] = SparsificationAucRatio(pairs[0], pairs[1]);
      m["geometric_sparsification_auc_ratio"] = SparsificationAucRatio(pairs[2], pairs[3]);
    }
    spdlog::info("[multi_depth] {} views: kept {} of {} samples ({:.1f}%; {} low confidence, {} unconfirmed, {} seen through), {} filled",
                 names.size(), totals.kept, totals.input_samples, 100.0 * m["kept_fraction"].get<double>(),
                 totals.low_confidence, totals.unconfirmed, totals.violated, totals.filled);
    if (before.truth_pixels > 0) {
      spdlog::info("[multi_depth] within 1% of the true depth: {:.1f}% of textured pixels ({:.1f}% before), {:.1f}% of kept",
                   100 * after.FractionOfTruth(), 100 * before.FractionOfTruth(), 100 * after.FractionOfEstimated());
    }
  }

 private:
  // (confidence, relative depth error) of every third pixel in each direction where both the map
  // and the truth have depth; confidence 1 where the map has none.
  static void CollectConfidenceAndError(const DepthMap& depth, const FloatMap& confidence, const DepthMap& truth,
                                        std::vector<double>* confidences, std::vector<double>* errors) {
    if (truth.width != depth.width || truth.height != depth.height) return;
    const bool sized = confidence.width == depth.width && confidence.height == depth.height && !confidence.Empty();
    for (int y = 1; y < depth.height; y += 3) {
      for (int x = 1; x < depth.width; x += 3) {
        const float z = depth.At(x, y), t = truth.At(x, y);
        if (!(z > 0) || !(t > 0)) continue;
        confidences->push_back(sized ? confidence.At(x, y) : 1.0);
        errors->push_back(std::abs(z - t) / t);
      }
    }
  }
  // Issue 67: each view's confirmed fraction against the others', the flag, the file, the record's
  // metrics and the log's warning.
  static void FlagDisagreeingViews(const PerViewSummary& summary, const ViewFlagOptions& flag_options, StageContext& context) {
    std::vector<ViewAgreement> views;
    for (const auto& [name, piece] : summary.pieces) {
      ViewAgreement view;
      view.name = name;
      if (piece.contains("confirmed_fraction")) {
        view.has_figure = true;
        view.figure = piece["confirmed_fraction"].get<double>();
      }
      if (piece.contains("view_agreement")) view.extra["mean_geometric_consistency"] = piece["view_agreement"];
      if (piece.contains("neighbor_agreement")) {
        nlohmann::json neighbors = nlohmann::json::array();
        for (const auto& n : piece["neighbor_agreement"]) {
          const double seen = n.at(1).get<double>();
          neighbors.push_back({{"name", n.at(0)}, {"seen", n.at(1)}, {"confirmed_fraction", seen > 0 ? n.at(2).get<double>() / seen : 0.0}});
        }
        view.extra["neighbors"] = std::move(neighbors);
      }
      views.push_back(std::move(view));
    }
    const ViewFlagResult result = FlagViews(std::move(views), /*higher_is_better=*/true, flag_options);
    WriteFileAtomic(context.workspace.ViewAgreementPath(),
                    ViewAgreementJson(result, kAgreementFigure, /*higher_is_better=*/true, flag_options).dump(1) + "\n");
    nlohmann::json& m = context.metrics;
    nlohmann::json figures = nlohmann::json::object(), z = nlohmann::json::object();
    double worst_z = 0;
    for (const ViewAgreement& v : result.views) {
      if (!v.has_figure) continue;
      figures[v.name] = v.figure;
      z[v.name] = v.z;
      worst_z = std::min(worst_z, v.z);
    }
    m["view_confirmed_fraction"] = std::move(figures);
    m["view_confirmed_z"] = std::move(z);
    m["view_confirmed_median"] = result.scores.median;
    m["view_confirmed_scale"] = result.scores.scale;
    m["view_confirmed_min_z"] = worst_z;
    m["views_scored"] = result.scored;
    m["views_flagged"] = result.flagged;
    m["views_flagged_count"] = result.flagged.size();
    m["capture_agreement_poor"] = result.capture_poor;
    // Synthetic captures know each written camera's error (synth: ground_truth/pose_error.json):
    // how well the flags name the wrong views (the stability matrix's pose-error cells).
    const std::string truth_path = context.workspace.GroundTruthPoseErrorPath();
    if (std::filesystem::exists(truth_path)) {
      const nlohmann::json truth = ReadStageJson(truth_path, "synth", "multi_depth");
      std::map<std::string, double> displacement;
      try {
        for (const auto& [name, view] : truth.at("views").items()) displacement[name] = view.at("displacement_px").get<double>();
      } catch (const nlohmann::json::exception& e) {
        throw IoError(truth_path + ": expected {\"views\": {NAME: {\"displacement_px\": N}}} (" + e.what() + "); re-run synth");
      }
      const ViewFlagScore score = ScoreViewFlags(result, displacement, kWrongPosePx);
      auto number_or_null = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); };
      m["view_flag_precision"] = number_or_null(score.precision);
      m["view_flag_recall"] = number_or_null(score.recall);
      m["view_flag_false_calls"] = score.false_calls;
      m["views_wrong_pose"] = score.wrong;
      m["views_called_out"] = score.called_out;
    }
    const std::string message = "[multi_depth] " + ViewFlagMessage(result, "confirmed fraction", flag_options);
    if (result.flagged.empty() && result.scored >= static_cast<size_t>(flag_options.min_views)) {
      spdlog::info("{}", message);
    } else {
      spdlog::warn("{}", message);
    }
    const std::string capture = CaptureAgreementMessage(result, "confirmed fraction", flag_options);
    if (!capture.empty()) spdlog::warn("[multi_depth] {}", capture);
  }

  static ViewFlagOptions ToFlagOptions(const Params& params) {
    ViewFlagOptions options;
    options.z_threshold = params.Double("view_flag_z");
    options.min_scale = params.Double("view_flag_min_scale");
    return options;
  }

  static void Accumulate(const MultiDepthStats& s, MultiDepthStats* total) {
    total->input_samples += s.input_samples;
    total->low_confidence += s.low_confidence;
    total->unconfirmed += s.unconfirmed;
    total->violated += s.violated;
    total->kept += s.kept;
    total->filled += s.filled;
  }
  static void Accumulate(const DepthAccuracy& a, DepthAccuracy* total) {
    total->truth_pixels += a.truth_pixels;
    total->estimated += a.estimated;
    total->within_tolerance += a.within_tolerance;
  }

  static MultiDepthOptions ToOptions(const Params& params) {
    MultiDepthOptions options;
    options.depth_tolerance = params.Double("depth_tolerance");
    options.min_consistent_views = static_cast<int>(params.Int("min_consistent_views"));
    options.max_violation_ratio = params.Double("max_violation_ratio");
    options.violation_tolerance = params.Double("violation_tolerance");
    options.min_confidence = params.Double("min_confidence");
    options.refine_depth = params.Bool("refine_depth");
    options.max_neighbors = static_cast<int>(params.Int("max_neighbors"));
    options.max_view_angle_deg = params.Double("max_view_angle_deg");
    options.min_baseline_ratio = params.Double("min_baseline_ratio");
    options.geometric_sigma = params.Double("geometric_sigma");
    options.view_agreement_reference = params.Double("view_agreement_reference");
    options.surface_window = static_cast<int>(params.Int("surface_window"));
    options.surface_residual_scale = params.Double("surface_residual_scale");
    options.surface_floor = params.Double("surface_floor");
    options.fill_from_neighbors = params.Bool("fill_from_neighbors");
    return options;
  }
};

}  // namespace

void RegisterStage_multi_depth(StageRegistry* registry) { registry->Add(std::make_unique<MultiDepthStage>()); }

}  // namespace ibmr
