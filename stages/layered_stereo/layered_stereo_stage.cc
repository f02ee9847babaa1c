// Adapter of the layered_stereo stage (layers.h; seed 000 lines 5625-5811, 5906-5950): per training
// view, reads its photo and depth map (plane_sweep's, made consistent by multi_depth) and those of
// its nearest neighbours, and writes layers/<image>/ (pipeline/core/layered_sprites.h): planes,
// RGBA sprites, residual depth, the combined depth map, and the held-out error against the layer
// count. Also registers the two-view method "layered" (layered_pair.h) for `ibmr stereo-pair`.
#include <spdlog/spdlog.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/layered_sprites.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/two_view_methods.h"
#include "stages/layered_stereo/layered_pair.h"
#include "stages/layered_stereo/layers.h"
#include "stages/layered_stereo/truth_planes.h"
#include "pipeline/core/ply_io.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

Eigen::Vector3d CentreOf(const Image& image) { return -(image.cam_from_world.R().transpose() * image.cam_from_world.translation); }
Eigen::Vector3d AxisOf(const Image& image) { return image.cam_from_world.R().transpose() * Eigen::Vector3d::UnitZ(); }

class LayeredStereoStage : public Stage {
 public:
  std::string Name() const override { return "layered_stereo"; }
  std::string Summary() const override {
    return "Planar layers per view: plane, RGBA sprite, residual depth; layer count by held-out prediction (layers/)";
  }
  std::string Version() const override { return "3"; }  // 2: depth_maps/<image>.layered.bin; 3: planes fitted along the rays, away from depth edges
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  // Planes per reference view, drawn from the nearest references: a forward-facing capture's model
  // (fountain-P11: 61 s for layers 1-4 dB below the surfel mesh).
  CaptureUse Serves() const override {
    return {{"forward_facing"}, "layers of planes per reference view serve forward-facing captures"};
  }
  bool Shardable() const override { return true; }
  double ViewMemoryMb(const StageContext& context) const override {
    const double pixels = LargestTrainingImage(context).Pixels();
    const double layers = static_cast<double>(context.params.Int("max_layers"));
    const double n = static_cast<double>(context.params.Int("num_neighbors"));
    const double scale = context.params.Double("selection_scale");
    // Planes costed at once (DataCosts' parallel loop over the planes): 2 on two cores.
    const double threads = std::min(layers, static_cast<double>(std::max(1, tbb::this_task_arena::max_concurrency())));
    // Bytes a pixel of the view at the largest moment of each step (layers.cc):
    //  - the costs at full size (AssignPixels): the view's and its neighbours' photos and depths
    //    (7 bytes each), the photos as floats (12 each), a cost and a plane depth per plane (8),
    //    and for each plane being costed one difference per neighbour plus a warp and the cost
    //    itself (4 n + 16); the residual sweep adds a depth per plane (4);
    //  - the count selection, on the views scaled by selection_scale (scale^2 of the pixels): the
    //    same costs there, and a float RGBA render per count and neighbour (16 l n), while the
    //    full-size inputs stay loaded.
    // The sprites themselves (8 a layer) come after the costs are freed. Sceaux castle at 1600 px
    // (1.92 Mpx, 6 layers, 4 neighbours): 479 MB estimated; measured 462 MB above the start with
    // one view in flight and 406 MB a view with two (the old count, which held every plane's
    // warped neighbours at once, gave 1485 MB and kept the full-size run to one view at a time).
    // DataCosts against `others` neighbours; the count selection holds each neighbour out in turn.
    const auto data_costs = [&](double others) { return 19.0 * (others + 1) + 8.0 * layers + threads * (4.0 * others + 16.0); };
    const double costs = data_costs(n) + (context.params.Int("residual_steps") > 0 ? 4.0 * layers : 0.0);
    const double selection = 7.0 * (n + 1) + scale * scale * (data_costs(n - 1) + 16.0 * layers * n);
    const double bytes = pixels * std::max(costs, selection);
    return pixels > 0 ? bytes / 1048576.0 + 100.0 : 0.0;
  }

  std::vector<ParamSpec> Parameters() const override {
    const LayeredOptions d;
    const auto num = DefaultNumberText;
    return {
        {"max_layers", ParamType::kInt, std::to_string(d.max_layers), "Planes at most per view, [1, 16]"},
        {"plane_tolerance", ParamType::kDouble, num(d.plane_tolerance), "A depth sample is on a plane within this fraction of its depth, (0, 0.2]"},
        {"min_layer_fraction", ParamType::kDouble, num(d.min_layer_fraction), "A plane needs this fraction of the view's depth samples, (0, 1)"},
        {"ransac_iterations", ParamType::kInt, std::to_string(d.ransac_iterations), "RANSAC hypotheses per plane, [10, 100000]"},
        {"sample_step", ParamType::kInt, std::to_string(d.sample_step), "Depth samples every this many pixels for plane fitting, [1, 16]"},
        {"residual_steps", ParamType::kInt, std::to_string(d.residual_steps), "Residual depth by a plane sweep of this many (odd) offsets around each layer's plane; 0: from the depth map"},
        {"edge_margin_px", ParamType::kInt, std::to_string(d.edge_margin_px), "Plane fits use samples at least this many pixels from a depth discontinuity, [0, 64]"},
        {"max_residual", ParamType::kDouble, num(d.max_residual), "Residual depth at most this fraction of the plane's depth, [0, 0.5]"},
        {"depth_weight", ParamType::kDouble, num(d.depth_weight), "Assignment cost of a depth one tolerance off the plane, grey levels"},
        {"smoothness", ParamType::kDouble, num(d.smoothness), "Potts cost between 4-neighbours in different layers, grey levels"},
        {"icm_sweeps", ParamType::kInt, std::to_string(d.icm_sweeps), "Sweeps of ICM for the assignment, [0, 100]"},
        {"max_cost", ParamType::kDouble, num(d.max_cost), "Pixels no plane explains better (and without depth) stay empty, grey levels"},
        {"extend_px", ParamType::kInt, std::to_string(d.extend_px), "Sprites extend this far under nearer layers, pixels, [0, 256]"},
        {"count_tolerance", ParamType::kDouble, num(d.count_tolerance), "Smallest layer count within this fraction of the best held-out error, [0, 1]"},
        {"choose_count", ParamType::kBool, "true", "Choose the layer count by held-out prediction (else every plane found)"},
        {"photometric_refinement", ParamType::kBool, "false",
         "Also refine each plane by the photo-consistency of its pixels across the views (Ceres); off: on the synthetic "
         "room it tilted the far walls by up to 5 degrees, which the depth samples fix to 0.6"},
        {"selection_scale", ParamType::kDouble, num(d.selection_scale), "The layer count is chosen on the views scaled by this, (0, 1]"},
        {"num_neighbors", ParamType::kInt, "4", "Neighbour views per reference view, [1, 16]"},
        {"max_view_angle_deg", ParamType::kDouble, "60", "Neighbours' optical axes within this angle of the reference's, degrees"},
        {"depth_maps", ParamType::kString, "geometric", "Depth maps to start from", {"geometric", "photometric"}},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (params.Int("num_neighbors") < 1 || params.Int("num_neighbors") > 16) {
      return ParamError{"num_neighbors", "must be in [1, 16], got " + std::to_string(params.Int("num_neighbors"))};
    }
    const double angle = params.Double("max_view_angle_deg");
    if (!(angle > 0 && angle <= 180)) return ParamError{"max_view_angle_deg", "must be in (0, 180]"};
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.SparseRelative(), context.workspace.Relative(context.workspace.ImagesDir())};
    const std::string kind = context.params.String("depth_maps");
    const std::vector<std::string> names = context.TrainingImageNamesIfReadable();
    if (names.empty()) {
      inputs.push_back("dense/stereo/depth_maps");
      return inputs;
    }
    for (const std::string& name : names) inputs.push_back("dense/stereo/depth_maps/" + name + "." + kind + ".bin");
    inputs.push_back("ground_truth");  // metrics only; "missing" on real data
    return inputs;
  }

  std::vector<std::string> Outputs(const StageContext& context) const override {
    std::vector<std::string> outputs = {"layers"};
    for (const std::string& name : context.TrainingImageNamesIfReadable()) {
      outputs.push_back("dense/stereo/depth_maps/" + name + ".layered.bin");
      outputs.push_back("dense/stereo/normal_maps/" + name + ".layered.bin");
    }
    return outputs;
  }

  void Run(StageContext& context) const override {
    const LayeredOptions options = ToOptions(context.params);
    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.size() < 2) throw InputError("layered_stereo: needs at least 2 training views, sparse/ has " + std::to_string(names.size()));
    const Workspace& workspace = context.workspace;
    const std::string kind = context.params.String("depth_maps");
    const int max_neighbours = static_cast<int>(context.params.Int("num_neighbors"));
    const double max_angle = context.params.Double("max_view_angle_deg") * M_PI / 180.0;

    auto load = [&](const std::string& name) {
      const Image& image = *model.FindImage(name);
      LayerView view;
      view.name = name;
      view.cam_from_world = image.cam_from_world;
      const std::string depth_path = workspace.DepthMapPath(name, kind);
      if (!fs::exists(depth_path)) {
        throw InputError(depth_path + ": no " + kind + " depth map for view '" + name + "'; run " +
                         (kind == "geometric" ? "multi_depth" : "plane_sweep") + " first (or set layered_stereo.depth_maps)");
      }
      const FloatMap depth = ReadColmapArray(depth_path);
      if (depth.channels != 1 || depth.width < 8 || depth.height < 8) {
        throw InputError(depth_path + ": a depth map must have 1 channel and at least 8x8 pixels");
      }
      const Camera camera = model.CameraOf(image);
      view.camera = camera.Scaled(static_cast<double>(depth.width) / camera.width);
      view.camera.width = depth.width;
      view.camera.height = depth.height;
      view.depth = cv::Mat(depth.height, depth.width, CV_32F);
      for (int y = 0; y < depth.height; ++y)
        for (int x = 0; x < depth.width; ++x) view.depth.at<float>(y, x) = std::isfinite(depth.At(x, y)) ? depth.At(x, y) : 0.f;
      const cv::Mat photo = ReadImageColor(workspace.ImagesDir() + "/" + name);
      cv::resize(photo, view.image, cv::Size(depth.width, depth.height), 0, 0, cv::INTER_AREA);
      return view;
    };

    // Synthetic scenes: the true mesh's planes measure the layers (metrics only).
    const bool has_truth = fs::exists(workspace.GroundTruthMeshPath());
    const TriangleMesh truth = has_truth ? ReadMeshPly(workspace.GroundTruthMeshPath()) : TriangleMesh();

    const PerViewSummary summary = ForEachView(context, "layers", names, [&](const std::string& name) {
      const Image& reference_image = *model.FindImage(name);
      // Neighbours: the nearest camera centres whose optical axes are within the angle.
      std::vector<std::pair<double, std::string>> candidates;
      for (const std::string& other : names) {
        if (other == name) continue;
        const Image& image = *model.FindImage(other);
        const double angle = std::acos(std::clamp(AxisOf(image).dot(AxisOf(reference_image)), -1.0, 1.0));
        if (angle > max_angle) continue;
        candidates.emplace_back((CentreOf(image) - CentreOf(reference_image)).norm(), other);
      }
      std::sort(candidates.begin(), candidates.end());
      if (static_cast<int>(candidates.size()) > max_neighbours) candidates.resize(max_neighbours);
      const LayerView reference = load(name);
      std::vector<LayerView> neighbours;
      for (const auto& [distance, other] : candidates) neighbours.push_back(load(other));
      std::vector<const LayerView*> pointers;
      for (const LayerView& n : neighbours) pointers.push_back(&n);
      LayeredResult result = ReconstructLayers(reference, pointers, options);
      result.layers.facts["planes_found"] = result.planes.size();
      result.layers.facts["layer_count"] = result.curve.chosen;
      result.layers.facts["heldout_rms_by_count"] = result.curve.rms_error;
      std::vector<std::string> neighbour_names;
      for (const auto& [distance, other] : candidates) neighbour_names.push_back(other);
      result.layers.facts["neighbours"] = neighbour_names;
      result.layers.facts["seconds"] = result.seconds;
      WriteLayerSet(workspace.Path("layers/" + name), result.layers);
      // The combined depth map beside the plane sweep's, as a third kind ("layered"), with the
      // front layer's plane normal (camera frame, facing the camera): fuse.input_type: layered.
      {
        cv::Mat front;
        const cv::Mat depth = CombinedDepth(result.layers, &front);
        FloatMap depth_map(depth.cols, depth.rows, 1), normal_map(depth.cols, depth.rows, 3);
        const Eigen::Matrix3d r = result.layers.cam_from_world.R();
        for (int y = 0; y < depth.rows; ++y) {
          for (int x = 0; x < depth.cols; ++x) {
            depth_map.At(x, y) = depth.at<float>(y, x);
            const int k = front.at<int>(y, x);
            if (k < 0) continue;
            Eigen::Vector3d n = r * result.layers.layers[k].normal;
            if (n.dot(result.layers.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5))) > 0) n = -n;
            for (int c = 0; c < 3; ++c) normal_map.At(x, y, c) = static_cast<float>(n[c]);
          }
        }
        WriteColmapArray(workspace.DepthMapPath(name, "layered"), depth_map);
        WriteColmapArray(workspace.NormalMapPath(name, "layered"), normal_map);
      }
      spdlog::info("[layered_stereo] {}: {} planes found, {} layers chosen (held-out RMS by count: {}), {:.1f} s", name,
                   result.planes.size(), result.curve.chosen, nlohmann::json(result.curve.rms_error).dump(), result.seconds);
      nlohmann::json piece = {{"planes_found", result.planes.size()},
                              {"layers", result.curve.chosen},
                              {"heldout_rms_by_count", result.curve.rms_error},
                              {"seconds", result.seconds}};
      const std::string truth_depth_path = workspace.GroundTruthDepthPath(name);
      if (has_truth && fs::exists(truth_depth_path)) {
        const FloatMap true_depth = ReadColmapArray(truth_depth_path);
        if (true_depth.width == reference.depth.cols && true_depth.height == reference.depth.rows) {
          LayerView truth_view = reference;
          truth_view.depth = cv::Mat(true_depth.height, true_depth.width, CV_32F);
          for (int y = 0; y < true_depth.height; ++y)
            for (int x = 0; x < true_depth.width; ++x) truth_view.depth.at<float>(y, x) = true_depth.At(x, y);
          const std::vector<TruthPlane> visible =
              VisibleTruthPlanes(truth, truth_view, options.min_layer_fraction, reference.depth);
          const Eigen::Vector3d centre = CentreOf(reference_image);
          // Per visible true plane, the nearest layer: found when within 5 degrees and 5% of the
          // camera's distance to the plane, recovered when within 1 degree and 1%. Layers near
          // no true plane are the curved objects' approximations, counted apart. Planes that the
          // depth map covers on at least half their pixels are the ones the layers can find.
          // The share of the view with depth: RANSAC's samples come from it, so a plane needs
          // min_layer_fraction of it (its pixel_fraction x depth_coverage / depth_fraction) to
          // make a layer of its own. A LayerView's depth is finite, 0 where none (`load` above).
          const double depth_fraction = static_cast<double>(cv::countNonZero(reference.depth > 0)) /
                                        std::max(1, reference.depth.rows * reference.depth.cols);
          double worst_angle = 0, worst_offset = 0;
          size_t recovered = 0, found = 0, with_depth = 0, with_support = 0, recovered_with_support = 0;
          nlohmann::json errors = nlohmann::json::array();
          std::vector<TruthPlane> as_truth;  // the layers, to find the nearest layer of a true plane
          for (const SpriteLayer& layer : result.layers.layers) as_truth.push_back({{layer.normal, layer.offset, 0}, 0});
          auto near_enough = [](const PlaneError& e, double degrees, double relative) {
            return e.truth >= 0 && e.angle_deg <= degrees && e.offset_relative <= relative;
          };
          for (const TruthPlane& t : visible) {
            with_depth += t.depth_coverage >= 0.5;
            // The plane's share of the pixels with depth (RANSAC's samples).
            const double depth_share = depth_fraction > 0 ? t.pixel_fraction * t.depth_coverage / depth_fraction : 0.0;
            const bool supported = t.depth_coverage >= 0.5 && depth_share >= options.min_layer_fraction;
            with_support += supported;
            nlohmann::json entry = {{"pixel_fraction", t.pixel_fraction}, {"depth_coverage", t.depth_coverage}, {"depth_share", depth_share}};
            const PlaneError e = NearestTruthPlane(t.plane, as_truth, centre);
            // Relative to the camera's distance to the true plane, like NearestTruthPlane's.
            const PlaneError back = e.truth < 0 ? PlaneError() : NearestTruthPlane(as_truth[e.truth].plane, {t}, centre);
            if (near_enough(back, 5.0, 0.05)) {
              ++found;
              worst_angle = std::max(worst_angle, back.angle_deg);
              worst_offset = std::max(worst_offset, back.offset_relative);
              recovered += near_enough(back, 1.0, 0.01);
              recovered_with_support += supported && near_enough(back, 1.0, 0.01);
              entry.update({{"layer", e.truth}, {"angle_deg", back.angle_deg}, {"offset_relative", back.offset_relative}});
            } else {
              entry["layer"] = nullptr;  // not found
            }
            errors.push_back(entry);
          }
          size_t unmatched = 0;
          for (const TruthPlane& layer : as_truth) unmatched += !near_enough(NearestTruthPlane(layer.plane, visible, centre), 5.0, 0.05);
          piece["depth_fraction"] = depth_fraction;
          piece["truth_visible_planes"] = visible.size();
          piece["truth_planes_with_depth"] = with_depth;
          piece["truth_plane_errors"] = errors;
          piece["truth_found_planes"] = found;
          piece["truth_recovered_planes"] = recovered;
          // Those with depth on at least min_layer_fraction of the view's pixels with depth: the
          // planes large enough for a layer of their own.
          piece["truth_planes_with_layer_support"] = with_support;
          piece["truth_recovered_planes_with_layer_support"] = recovered_with_support;
          piece["layers_off_true_planes"] = unmatched;
          piece["truth_worst_angle_deg"] = worst_angle;
          piece["truth_worst_offset_relative"] = worst_offset;
          spdlog::info("[layered_stereo] {}: {} true planes cover >= {:.0f}% of the view each ({} with depth on half their pixels, "
                       "{} of those on {:.0f}% of the pixels with depth); {} found, {} within 1 deg and 1% ({} of the {}), "
                       "worst {:.2f} deg, {:.2f}%; {} layers on no true plane",
                       name, visible.size(), 100 * options.min_layer_fraction, with_depth, with_support,
                       100 * options.min_layer_fraction, found, recovered, recovered_with_support, with_support, worst_angle,
                       100 * worst_offset, unmatched);
        }
      }
      return piece;
    });
    nlohmann::json per_view = nlohmann::json::object();
    double layers = 0, seconds = 0, worst_angle = 0, worst_offset = 0;
    size_t with_truth = 0, count_matches = 0, count_matches_with_depth = 0;
    // Plane counts summed over the views, under the per-view keys: the visible true planes, those
    // with depth on half their pixels, those with a layer, those within 1 degree and 1%, and the
    // last two over the planes with layer support (min_layer_fraction of the depth samples).
    static constexpr const char* kSummedCounts[] = {"truth_visible_planes",   "truth_planes_with_depth",
                                                    "truth_found_planes",     "truth_recovered_planes",
                                                    "truth_planes_with_layer_support",
                                                    "truth_recovered_planes_with_layer_support"};
    std::map<std::string, size_t> totals;
    for (const auto& [name, piece] : summary.pieces) {
      per_view[name] = piece;
      layers += piece.value("layers", 0);
      seconds += piece.value("seconds", 0.0);
      if (piece.contains("truth_visible_planes")) {
        ++with_truth;
        count_matches += piece.value("truth_visible_planes", 0) == piece.value("layers", -1);
        count_matches_with_depth += piece.value("truth_planes_with_depth", 0) == piece.value("layers", -1);
        for (const char* key : kSummedCounts) totals[key] += piece.value(key, size_t{0});
        worst_angle = std::max(worst_angle, piece.value("truth_worst_angle_deg", 0.0));
        worst_offset = std::max(worst_offset, piece.value("truth_worst_offset_relative", 0.0));
      }
    }
    if (with_truth > 0) {
      context.metrics["truth_views"] = with_truth;
      context.metrics["truth_count_matches"] = count_matches;
      context.metrics["truth_count_matches_planes_with_depth"] = count_matches_with_depth;
      for (const char* key : kSummedCounts) context.metrics[key] = totals[key];
      context.metrics["truth_worst_angle_deg"] = worst_angle;  // over the found planes
      context.metrics["truth_worst_offset_relative"] = worst_offset;
    }
    nlohmann::json& m = context.metrics;
    m["views"] = names.size();
    m["mean_layers"] = names.empty() ? 0.0 : layers / names.size();
    m["seconds_per_view"] = names.empty() ? 0.0 : seconds / names.size();
    m["per_view"] = per_view;
  }

 private:
  static LayeredOptions ToOptions(const Params& params) {
    LayeredOptions o;
    o.max_layers = static_cast<int>(params.Int("max_layers"));
    o.plane_tolerance = params.Double("plane_tolerance");
    o.min_layer_fraction = params.Double("min_layer_fraction");
    o.ransac_iterations = static_cast<int>(params.Int("ransac_iterations"));
    o.sample_step = static_cast<int>(params.Int("sample_step"));
    o.edge_margin_px = static_cast<int>(params.Int("edge_margin_px"));
    o.residual_steps = static_cast<int>(params.Int("residual_steps"));
    o.max_residual = params.Double("max_residual");
    o.depth_weight = params.Double("depth_weight");
    o.smoothness = params.Double("smoothness");
    o.icm_sweeps = static_cast<int>(params.Int("icm_sweeps"));
    o.max_cost = params.Double("max_cost");
    o.extend_px = static_cast<int>(params.Int("extend_px"));
    o.count_tolerance = params.Double("count_tolerance");
    o.choose_count = params.Bool("choose_count") ? 1 : 0;
    o.selection_scale = params.Double("selection_scale");
    o.photometric_refinement = params.Bool("photometric_refinement") ? 1 : 0;
    return o;
  }
};

}  // namespace

void RegisterStage_layered_stereo(StageRegistry* registry) {
  RegisterTwoViewMethod("layered", LayeredTwoView);
  registry->Add(std::make_unique<LayeredStereoStage>());
}

}  // namespace ibmr
