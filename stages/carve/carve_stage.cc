// Adapter of the carve stage (seed 000 lines 4136-4258, Lumigraph 14700-14740; see carve.h).
// Role kTrainingOnly: the octree is carved from the training views' masks/ only
// (context.LoadModel() has already dropped the held-out images). Held-out silhouettes
// (heldout/masks/, written by `silhouettes`) are read in one place, ValidateOnHeldOut(), after the
// octree is final, to measure per level how well the hull predicts views it never saw, and to
// choose the level by "model no more than a scene needs": the smallest level whose mean held-out
// IoU is within `level_tolerance` of the best level's.
//
// Carving volume (`volume`): `bbox` from the config ([xmin, ymin, zmin, xmax, ymax, zmax]);
// `sparse` from the sparse points (1st-99th percentile per axis); `frustums` from the views
// themselves: a cube around the point nearest to all optical axes, half-side the median camera
// distance, carved at level min(levels, 6) and shrunk to the hull's box plus one cell; `auto`
// is bbox when given, else frustums. The box grows by `volume_margin` of its largest side on every
// side and becomes the root cube (side = largest side).
//
// Outputs: hull/octree.bin (layout in carve.h), hull/hull.ply (binary PLY, comment
// "ibmr conservative_hull 1"), hull/levels.json (per level: nodes, empty/full/partial,
// held-out IoU; at the finest level the partial leaves kept and dropped by the centre test, see
// `leaf_test` in carve.h; chosen level), hull/depth_bounds.json ({"<image>": {"near": z, "far": z}} per
// training view, z along the optical axis, from the finest hull); with level_meshes N, also
// hull/hull_level<L>.ply for the N levels below the meshed one (smaller models for select).
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <filesystem>
#include <numeric>

#include "pipeline/core/median.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/rasterizer.h"
#include "stages/carve/carve.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const std::vector<std::string> kOutsideNames = {"auto", "unknown", "empty"};
const std::vector<std::string> kLeafTestNames = {"centre", "box"};
const std::vector<std::string> kVolumeNames = {"auto", "bbox", "sparse", "frustums"};

double Mean(const std::vector<double>& values) {
  return values.empty() ? 0.0 : std::accumulate(values.begin(), values.end(), 0.0) / values.size();
}

// The point nearest (least squares) to every optical axis.
Eigen::Vector3d NearestToAxes(const std::vector<CarveView>& views) {
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  for (const CarveView& view : views) {
    const Eigen::Vector3d center = view.cam_from_world.Inverse().translation;
    const Eigen::Vector3d axis = view.cam_from_world.rotation.conjugate() * Eigen::Vector3d::UnitZ();
    const Eigen::Matrix3d projector = Eigen::Matrix3d::Identity() - axis * axis.transpose();
    a += projector;
    b += projector * center;
  }
  return a.ldlt().solve(b);
}

// Held-out validation, kept apart from carving: the hull's silhouette at every level against each
// held-out view's mask from heldout/masks/. Returns per level the per-view IoUs (name -> IoU).
std::vector<std::map<std::string, double>> ValidateOnHeldOut(const StageContext& context, const Octree& octree,
                                                            const std::vector<std::vector<HullCell>>& surface) {
  std::vector<std::map<std::string, double>> per_level(octree.levels.size());
  if (context.heldout_images.empty()) return per_level;
  // Only the held-out cameras are taken from the full model; their photos are never read.
  const SparseModel full = ReadSparseModelText(context.workspace.SparseDir());
  struct HeldOutView {
    std::string name;
    const Image* image;
    cv::Mat mask;
  };
  std::vector<HeldOutView> views;
  for (const std::string& name : context.heldout_images) {
    const Image* image = full.FindImage(name);
    const std::string path = context.workspace.Path("heldout/masks/" + name + ".png");
    if (!image || !fs::exists(path)) {
      spdlog::warn("[carve] held-out view {}: no {} (run silhouettes with the same holdout); not validated", name,
                   path);
      continue;
    }
    cv::Mat mask = ReadImageUnchanged(path);
    const Camera& camera = full.CameraOf(*image);
    if (mask.cols != camera.width || mask.rows != camera.height || mask.type() != CV_8UC1) {
      spdlog::warn("[carve] held-out view {}: {} is not a {}x{} 8-bit mask; not validated", name, path, camera.width,
                   camera.height);
      continue;
    }
    views.push_back({name, image, mask});
  }
  for (size_t level = 0; level < octree.levels.size(); ++level) {
    const std::vector<HullCell>& cells = surface[level];
    std::vector<double> ious(views.size());
    tbb::parallel_for(size_t{0}, views.size(), [&](size_t i) {
      const Camera& camera = full.CameraOf(*views[i].image);
      ious[i] = MaskIou(ProjectHullSurface(octree, static_cast<int>(level), cells, camera, views[i].image->cam_from_world),
                        views[i].mask);
    });
    for (size_t i = 0; i < views.size(); ++i) per_level[level][views[i].name] = ious[i];
  }
  return per_level;
}

class CarveStage : public Stage {
 public:
  std::string Name() const override { return "carve"; }
  std::string Summary() const override {
    return "octree visual hull from silhouettes (O(1) distance-map test), smoothed hull mesh, depth bounds";
  }
  std::string Version() const override { return "3"; }  // 3: mesh IoU in the record, timings out of levels.json
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  bool SkippedWithItsInputs() const override { return true; }  // no hull without the silhouettes' masks

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"levels", ParamType::kInt, "7", "finest octree level (root cube = 0, cells of side/2^levels), in [1, 10]"},
        {"outside", ParamType::kString, "auto",
         "out-of-image space: auto (empty unless the silhouette touches the border), unknown, empty", kOutsideNames},
        {"leaf_test", ParamType::kString, "centre",
         "partial cells of the finest level: centre (kept when the centre projects into every silhouette, the "
         "visual hull on the grid) or box (all kept, a conservative hull)",
         kLeafTestNames},
        {"volume", ParamType::kString, "auto", "carving volume: auto (bbox if given, else frustums), bbox, sparse, frustums",
         kVolumeNames},
        {"bbox", ParamType::kDoubleList, "[]", "carving box [xmin, ymin, zmin, xmax, ymax, zmax], world units"},
        {"volume_margin", ParamType::kDouble, "0.05", "margin added on every side, fraction of the box's largest side, in [0, 2]"},
        {"exclude_views", ParamType::kStringList, "[]", "training views whose silhouettes are not used (bad masks)"},
        {"smooth_iterations", ParamType::kInt, "10", "Taubin lambda|mu pairs on the hull mesh, in [0, 1000]"},
        {"smooth_lambda", ParamType::kDouble, "0.5", "Taubin lambda, in (0, 1)"},
        {"smooth_mu", ParamType::kDouble, "-0.53", "Taubin mu, in (-1, 0), |mu| > lambda"},
        {"max_displacement", ParamType::kDouble, "0.5", "largest vertex move while smoothing, cells, in [0, 1)"},
        {"max_mesh_level", ParamType::kInt, "8", "the mesh is built at min(chosen level, this), in [1, 9]"},
        {"level_meshes", ParamType::kInt, "0",
         "also write hull/hull_level<L>.ply for this many levels coarser than the meshed one (smaller models for "
         "select), in [0, 6]",
         {}},
        {"mesh_dilation", ParamType::kInt, "1",
         "cells the hull is dilated by before meshing: 1 encloses the hull, 0 fits the silhouettes closer, in [0, 2]"},
        {"mesh_at_finest", ParamType::kBool, "false", "mesh the finest level instead of the chosen one"},
        {"level_tolerance", ParamType::kDouble, "0.005",
         "chosen level: smallest whose held-out IoU is within this of the best level's, in [0, 1]"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    const std::vector<double> box = params.DoubleList("bbox");
    if (!box.empty() && (box.size() != 6 || !(box[0] < box[3] && box[1] < box[4] && box[2] < box[5]))) {
      return ParamError{"bbox", "must be [xmin, ymin, zmin, xmax, ymax, zmax] with min < max"};
    }
    if (params.String("volume") == "bbox" && box.empty()) return ParamError{"bbox", "volume: bbox needs a bbox"};
    const double margin = params.Double("volume_margin");
    if (!(margin >= 0 && margin <= 2)) return ParamError{"volume_margin", "must be in [0, 2]"};
    if (params.Has("level_meshes") && (params.Int("level_meshes") < 0 || params.Int("level_meshes") > 6)) {
      return ParamError{"level_meshes", "must be in [0, 6]"};
    }
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.SparseRelative(), "masks", "heldout/masks"};
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"hull"}; }

  void Run(StageContext& context) const override {
    const CarveOptions options = ToOptions(context.params);
    std::string error;
    if (!options.Check(&error)) throw InputError("carve." + error);
    const SparseModel model = context.LoadModel();  // held-out images already removed
    std::vector<CarveView> views = LoadViews(context, model);

    // Carving volume.
    Eigen::AlignedBox3d box = CarvingBox(context, model, views, options);
    const double margin = context.params.Double("volume_margin") * box.sizes().maxCoeff();
    box.min().array() -= margin;
    box.max().array() += margin;
    const double size = box.sizes().maxCoeff();
    const Eigen::Vector3d origin = box.center() - Eigen::Vector3d::Constant(0.5 * size);

    CarveResult carved = CarveOctree(views, origin, size, options, context.progress);
    for (const std::string& name : carved.views_not_seeing_volume) {
      spdlog::warn("[carve] view {}: the carving volume lies outside this view's image (or behind the camera); "
                   "the view is not used. Check its pose or the carving volume (carve.bbox / carve.volume)",
                   name);
    }
    if (carved.views_not_seeing_volume.size() == views.size()) {
      throw InputError("carve: no training view sees the carving volume (origin " + Format(origin) + ", side " +
                       std::to_string(size) + "); check carve.bbox / carve.volume and the poses in sparse/");
    }
    const Octree& octree = carved.octree;
    const int finest = octree.MaxLevel();
    const std::vector<HullCell> finest_cells = HullCells(octree, finest);
    if (finest_cells.empty()) {
      throw InputError("carve: the hull is empty: the training silhouettes share no volume. Check masks/ (a view "
                       "whose silhouette misses the object, or wrong poses); list bad views in carve.exclude_views");
    }

    // Validation on held-out silhouettes (never used above), and the level choice.
    // Each level's surface cells, what the views see of its hull (SurfaceHullCells), once.
    std::vector<std::vector<HullCell>> surface(octree.levels.size());
    for (size_t level = 0; level < surface.size(); ++level) surface[level] = SurfaceHullCells(octree, static_cast<int>(level));
    const auto heldout_ious = ValidateOnHeldOut(context, octree, surface);
    nlohmann::json levels_json = nlohmann::json::array();
    std::vector<double> level_seconds;
    std::vector<double> heldout_mean(octree.levels.size(), 0.0);
    const bool validated = !heldout_ious.empty() && !heldout_ious[0].empty();
    for (size_t level = 0; level < octree.levels.size(); ++level) {
      std::vector<double> values;
      for (const auto& [name, iou] : heldout_ious[level]) values.push_back(iou);
      heldout_mean[level] = Mean(values);
    }
    int chosen = finest;
    std::string rule = "no held-out views: finest level";
    if (validated) {
      const double best = *std::max_element(heldout_mean.begin(), heldout_mean.end());
      chosen = 0;
      while (heldout_mean[chosen] < best - options.level_tolerance) ++chosen;
      rule = "smallest level whose mean held-out IoU is within " + std::to_string(options.level_tolerance) +
             " of the best (" + std::to_string(best) + ")";
    }

    // Training-view agreement of the chosen and the finest hull.
    const std::vector<HullCell>& finest_surface = surface[finest];
    const std::vector<HullCell>& chosen_surface = surface[chosen];
    std::vector<double> train_iou_chosen(views.size(), -1.0), train_iou_finest(views.size(), -1.0);
    std::vector<bool> used(views.size(), true);
    for (const std::string& name : carved.views_not_seeing_volume) {
      for (size_t i = 0; i < views.size(); ++i) used[i] = used[i] && views[i].name != name;
    }
    tbb::parallel_for(size_t{0}, views.size(), [&](size_t i) {
      if (!used[i]) return;
      train_iou_finest[i] =
          MaskIou(ProjectHullSurface(octree, finest, finest_surface, views[i].camera, views[i].cam_from_world), views[i].mask);
      train_iou_chosen[i] = chosen == finest ? train_iou_finest[i]
                                              : MaskIou(ProjectHullSurface(octree, chosen, chosen_surface, views[i].camera,
                                                                    views[i].cam_from_world), views[i].mask);
    });
    std::vector<double> finest_values, chosen_values;
    nlohmann::json per_view = nlohmann::json::object();
    for (size_t i = 0; i < views.size(); ++i) {
      if (!used[i]) continue;
      finest_values.push_back(train_iou_finest[i]);
      chosen_values.push_back(train_iou_chosen[i]);
      per_view[views[i].name] = {{"iou_finest", train_iou_finest[i]},
                                 {"iou_chosen", train_iou_chosen[i]},
                                 {"outside_empty", static_cast<bool>(carved.outside_empty[i])}};
    }

    for (size_t level = 0; level < octree.levels.size(); ++level) {
      const LevelStats& s = carved.stats[level];
      nlohmann::json entry = {{"level", s.level},    {"nodes", s.nodes},     {"empty", s.empty},
                              {"full", s.full},      {"partial", s.partial}, {"unseen", s.unseen},
                              {"cell_size", octree.CellSize(static_cast<int>(level))}};
      // Timings go to the record only: outputs stay byte-identical from run to run.
      level_seconds.push_back(s.seconds);
      if (s.leaves_kept_by_centre + s.leaves_dropped_by_centre > 0) {
        entry["leaves_kept_by_centre"] = s.leaves_kept_by_centre;
        entry["leaves_dropped_by_centre"] = s.leaves_dropped_by_centre;
      }
      if (level > 0 && carved.stats[level - 1].nodes > 0) {
        entry["node_ratio"] = static_cast<double>(s.nodes) / carved.stats[level - 1].nodes;
      }
      if (validated) {
        entry["heldout_iou_mean"] = heldout_mean[level];
        entry["heldout_iou"] = heldout_ious[level];
      }
      levels_json.push_back(entry);
    }

    // Mesh (chosen level) and depth bounds (finest hull: the tightest conservative bounds).
    HullMeshStats mesh_stats;
    const int meshed_level = options.mesh_at_finest ? finest : chosen;
    const TriangleMesh mesh = HullMesh(octree, meshed_level, options, &mesh_stats);
    if (mesh.faces.empty()) throw InputError("carve: the hull mesh has no face");
    // How well the mesh fits the silhouettes it was carved from: its projection against each
    // training mask (the octree cells' own fit is training_iou_*).
    std::vector<double> mesh_ious(views.size(), 0.0);
    tbb::parallel_for(size_t{0}, views.size(), [&](size_t i) {
      const DepthMap depth = Rasterize(mesh, views[i].camera, views[i].cam_from_world).depth;
      cv::Mat silhouette(views[i].camera.height, views[i].camera.width, CV_8UC1, cv::Scalar(0));
      for (int y = 0; y < silhouette.rows; ++y) {
        for (int x = 0; x < silhouette.cols; ++x) silhouette.at<uint8_t>(y, x) = IsValidDepth(depth.At(x, y)) ? 255 : 0;
      }
      mesh_ious[i] = MaskIou(silhouette, views[i].mask);
    });
    nlohmann::json bounds = nlohmann::json::object();
    for (size_t i = 0; i < views.size(); ++i) {
      double near_z = 0, far_z = 0;
      if (HullDepthBounds(finest_cells, views[i].camera, views[i].cam_from_world, &near_z, &far_z)) {
        bounds[views[i].name] = {{"near", near_z}, {"far", far_z}};
      } else {
        spdlog::warn("[carve] view {}: no part of the hull is in front of this camera and in its image; no depth "
                     "bounds",
                     views[i].name);
      }
    }
    const int mesh_level = std::min({meshed_level, finest, options.max_mesh_level});
    const nlohmann::json summary = {
        {"origin", {origin.x(), origin.y(), origin.z()}},
        {"size", size},
        {"finest_level", finest},
        {"chosen_level", chosen},
        {"chosen_rule", rule},
        {"mesh_level", mesh_level},
        {"levels", levels_json},
        {"training_views", per_view},
        {"training_iou_median_finest", Median(finest_values)},
        {"training_iou_median_chosen", Median(chosen_values)},
        {"views_not_seeing_volume", carved.views_not_seeing_volume},
    };
    WriteFileAtomic(context.workspace.Path("hull/octree.bin"), SerializeOctree(octree));
    WriteMeshPly(context.workspace.Path("hull/hull.ply"), mesh);
    // Coarser hulls, for model selection (how much hull the held-out views need).
    const int level_meshes = context.params.Has("level_meshes") ? static_cast<int>(context.params.Int("level_meshes")) : 0;
    for (const auto& entry : fs::directory_iterator(context.workspace.Path("hull"))) {
      if (entry.path().filename().string().rfind("hull_level", 0) == 0) fs::remove(entry.path());
    }
    const int built_level = std::min({meshed_level, finest, options.max_mesh_level});  // HullMesh's own cap
    for (int k = 1; k <= level_meshes && built_level - k >= 1; ++k) {
      const int level = built_level - k;
      const TriangleMesh coarse = HullMesh(octree, level, options, nullptr);
      if (!coarse.faces.empty()) {
        WriteMeshPly(context.workspace.Path("hull/hull_level" + std::to_string(level) + ".ply"), coarse);
      }
    }
    WriteFileAtomic(context.workspace.Path("hull/levels.json"), summary.dump(2));
    WriteFileAtomic(context.workspace.Path("hull/depth_bounds.json"), bounds.dump(2));

    auto& metrics = context.metrics;
    metrics["views_used"] = finest_values.size();
    metrics["mesh_iou_median"] = Median(mesh_ious);
    metrics["mesh_iou_min"] = mesh_ious.empty() ? 0.0 : *std::min_element(mesh_ious.begin(), mesh_ious.end());
    metrics["seconds_per_level"] = level_seconds;
    metrics["finest_level"] = finest;
    metrics["chosen_level"] = chosen;
    metrics["chosen_rule"] = rule;
    metrics["training_iou_median_finest"] = Median(finest_values);
    metrics["training_iou_median_chosen"] = Median(chosen_values);
    metrics["training_iou_min_finest"] = finest_values.empty() ? 0.0 : *std::min_element(finest_values.begin(), finest_values.end());
    nlohmann::json nodes = nlohmann::json::array(), ratios = nlohmann::json::array(), heldout = nlohmann::json::array();
    for (size_t level = 0; level < octree.levels.size(); ++level) {
      nodes.push_back(carved.stats[level].nodes);
      if (level > 0) ratios.push_back(levels_json[level].value("node_ratio", 0.0));
      if (validated) heldout.push_back(heldout_mean[level]);
    }
    metrics["nodes_per_level"] = nodes;
    metrics["node_ratios"] = ratios;
    if (validated) {
      metrics["heldout_iou_mean_per_level"] = heldout;
      // The hull against the held-out views' own silhouettes, which reconstruction never saw: its
      // error where the training masks are wrong (the stability matrix).
      metrics["heldout_iou_chosen"] = heldout_mean[chosen];
    }
    metrics["hull_cells_finest"] = finest_cells.size();
    metrics["mesh_vertices"] = mesh.vertices.size();
    metrics["mesh_faces"] = mesh.faces.size();
    metrics["mesh_duplicated_vertices"] = mesh_stats.duplicated_vertices;
    metrics["volume_origin"] = {origin.x(), origin.y(), origin.z()};
    metrics["volume_size"] = size;
    metrics["views_not_seeing_volume"] = carved.views_not_seeing_volume;
    spdlog::info("[carve] {} views, level {} ({} hull cells), chosen level {} ({}), training IoU median {:.4f}, "
                 "mesh {} faces",
                 finest_values.size(), finest, finest_cells.size(), chosen, rule, Median(finest_values), mesh.faces.size());
  }

 private:
  static CarveOptions ToOptions(const Params& params) {
    CarveOptions options;
    options.levels = static_cast<int>(std::clamp<int64_t>(params.Int("levels"), -1, 1000));
    const std::string& outside = params.String("outside");
    options.outside = outside == "unknown" ? OutsideImage::kUnknown
                      : outside == "empty" ? OutsideImage::kEmpty
                                           : OutsideImage::kAuto;
    options.leaf_test = params.String("leaf_test") == "box" ? LeafTest::kBox : LeafTest::kCentre;
    options.smooth_iterations = static_cast<int>(std::clamp<int64_t>(params.Int("smooth_iterations"), -1, 100000));
    options.smooth_lambda = params.Double("smooth_lambda");
    options.smooth_mu = params.Double("smooth_mu");
    options.max_displacement = params.Double("max_displacement");
    options.max_mesh_level = static_cast<int>(std::clamp<int64_t>(params.Int("max_mesh_level"), -1, 1000));
    options.mesh_dilation = static_cast<int>(std::clamp<int64_t>(params.Int("mesh_dilation"), -1, 100));
    options.mesh_at_finest = params.Bool("mesh_at_finest");
    options.level_tolerance = params.Double("level_tolerance");
    return options;
  }

  static std::string Format(const Eigen::Vector3d& v) {
    return "(" + std::to_string(v.x()) + ", " + std::to_string(v.y()) + ", " + std::to_string(v.z()) + ")";
  }

  // Training views with their masks; bad masks are errors (wrong size, missing) or skipped with a
  // warning (empty silhouette).
  std::vector<CarveView> LoadViews(StageContext& context, const SparseModel& model) const {
    const std::vector<std::string> excluded = context.params.StringList("exclude_views");
    std::vector<CarveView> views;
    nlohmann::json skipped = nlohmann::json::array();
    for (const std::string& name : context.TrainingImageNames(model)) {
      if (std::find(excluded.begin(), excluded.end(), name) != excluded.end()) continue;
      const Image& image = *model.FindImage(name);
      const Camera& camera = model.CameraOf(image);
      const std::string path = context.workspace.MaskPath(name);
      if (!fs::exists(path)) {
        throw InputError("carve: view " + name + " has no mask " + path + "; run the silhouettes stage first");
      }
      cv::Mat mask = ReadImageUnchanged(path);
      if (mask.channels() != 1 || mask.depth() != CV_8U) {
        throw InputError("carve: view " + name + ": " + path + " is not an 8-bit one-channel mask");
      }
      if (mask.cols != camera.width || mask.rows != camera.height) {
        throw InputError("carve: view " + name + ": the mask " + path + " is " + std::to_string(mask.cols) + "x" +
                         std::to_string(mask.rows) + " but the camera is " + std::to_string(camera.width) + "x" +
                         std::to_string(camera.height) + "; re-run silhouettes or fix the mask");
      }
      if (cv::countNonZero(mask) == 0) {
        spdlog::warn("[carve] view {}: the silhouette {} is empty; the view is skipped (it would carve everything)",
                     name, path);
        skipped.push_back(name);
        continue;
      }
      views.push_back(CarveView{name, camera, image.cam_from_world, mask});
    }
    context.metrics["skipped_empty_silhouettes"] = skipped;
    if (views.empty()) {
      throw InputError("carve: no training view with a non-empty silhouette in masks/ (" +
                       std::to_string(skipped.size()) + " empty, " + std::to_string(excluded.size()) + " excluded)");
    }
    return views;
  }

  Eigen::AlignedBox3d CarvingBox(StageContext& context, const SparseModel& model, const std::vector<CarveView>& views,
                                 const CarveOptions& options) const {
    const std::vector<double> bbox = context.params.DoubleList("bbox");
    std::string volume = context.params.String("volume");
    if (volume == "auto") volume = bbox.empty() ? "frustums" : "bbox";
    context.metrics["volume"] = volume;
    if (volume == "bbox") {
      return Eigen::AlignedBox3d(Eigen::Vector3d(bbox[0], bbox[1], bbox[2]), Eigen::Vector3d(bbox[3], bbox[4], bbox[5]));
    }
    if (volume == "sparse") {
      if (model.points.size() < 10) {
        throw InputError("carve.volume: sparse needs sparse points, sparse/points3D.txt has " +
                         std::to_string(model.points.size()) + "; use volume: frustums or give carve.bbox");
      }
      Eigen::AlignedBox3d box;
      for (int axis = 0; axis < 3; ++axis) {
        std::vector<double> values;
        for (const auto& [id, point] : model.points) values.push_back(point.xyz[axis]);
        std::sort(values.begin(), values.end());
        box.min()[axis] = values[values.size() / 100];
        box.max()[axis] = values[values.size() - 1 - values.size() / 100];
      }
      return box;
    }
    // Frustums: a cube around the point nearest to the optical axes, carved coarsely.
    const Eigen::Vector3d center = NearestToAxes(views);
    std::vector<double> distances;
    for (const CarveView& view : views) distances.push_back((view.cam_from_world.Inverse().translation - center).norm());
    const double half = Median(distances);
    CarveOptions coarse = options;
    coarse.levels = std::min(options.levels, 6);
    coarse.leaf_test = LeafTest::kBox;  // the box must contain the conservative hull
    const CarveResult result =
        CarveOctree(views, center - Eigen::Vector3d::Constant(half), 2 * half, coarse, context.progress);
    const std::vector<HullCell> cells = HullCells(result.octree, coarse.levels);
    if (cells.empty()) {
      throw InputError("carve.volume: frustums: the silhouettes share no volume near the point the cameras look at " +
                       Format(center) + "; give carve.bbox");
    }
    Eigen::AlignedBox3d box;
    for (const HullCell& cell : cells) {
      box.extend(cell.min - Eigen::Vector3d::Constant(cell.size));
      box.extend(cell.min + Eigen::Vector3d::Constant(2 * cell.size));
    }
    return box;
  }
};

}  // namespace

void RegisterStage_carve(StageRegistry* registry) { registry->Add(std::make_unique<CarveStage>()); }

}  // namespace ibmr
