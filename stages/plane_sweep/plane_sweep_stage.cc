// Adapter of the plane_sweep stage: for every training view, picks neighbours, depth bounds
// (hull/depth_bounds.json, else sparse/depth_bounds.json (the LLFF import's per-view bounds from
// poses_bounds.npy), else the sparse points, else the config's bounding box or depth range) and, with hull/hull.ply, per-pixel near bounds (the hull's nearest surface along each
// pixel's ray, rasterized), runs the plane sweep (plane_sweep.h) and writes COLMAP maps:
//   dense/stereo/depth_maps/<image>.photometric.bin       z depth, 0 = no estimate
//   dense/stereo/normal_maps/<image>.photometric.bin      3 channels, camera frame
//   dense/stereo/confidence_maps/<image>.photometric.bin  1 channel in [0, 1]
// Also registers `ibmr stereo-pair LEFT RIGHT --max-disparity N --out DISP.pfm` (two-view mode).
// Method: seed 000 lines 3659-3760, 5300-5525, 4352-4453 (see plane_sweep.h).
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <tbb/parallel_for.h>
#include <tbb/global_control.h>
#include <tbb/task_arena.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <mutex>
#include <new>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_stereo_config.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/rasterizer.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/undistorted_cameras.h"
#include "pipeline/core/view_cache.h"
#include "pipeline/core/two_view_methods.h"
#include "stages/plane_sweep/plane_sweep.h"
#include "stages/plane_sweep/sweep_engine.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const std::vector<std::string> kCostNames = {"census", "sad", "zncc"};
const std::vector<std::string> kAggregationNames = {"box", "semi_global"};

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}

// Grey image of a view, checked against its camera's size, and downscaled (area averaging) when its
// longest side exceeds `max_size` (> 0); `scaled` is the camera of the result.
cv::Mat LoadGray(const std::string& path, const Camera& camera, int max_size, Camera* scaled) {
  const cv::Mat color = ReadImageColor(path);
  if (color.cols != camera.width || color.rows != camera.height) {
    throw InputError(path + ": image is " + std::to_string(color.cols) + "x" + std::to_string(color.rows) +
                     " but its camera in sparse/cameras.txt is " + std::to_string(camera.width) + "x" +
                     std::to_string(camera.height) + "; re-run import");
  }
  cv::Mat gray;
  cv::cvtColor(color, gray, cv::COLOR_BGR2GRAY);
  *scaled = camera;
  const int longest = std::max(gray.cols, gray.rows);
  if (max_size <= 0 || longest <= max_size) return gray;
  *scaled = camera.Scaled(static_cast<double>(max_size) / longest);
  cv::Mat smaller;
  cv::resize(gray, smaller, cv::Size(scaled->width, scaled->height), 0, 0, cv::INTER_AREA);
  return smaller;
}

class PlaneSweepStage : public Stage {
 public:
  std::string Name() const override { return "plane_sweep"; }
  std::string Summary() const override {
    return "CPU plane-sweep stereo (census, best-k, semi-global) to COLMAP depth/normal/confidence maps";
  }
  // 2: hull bounds that reach the camera are not used; 3: fixed-point bilinear census weights (1/256 px),
  // per-pixel near bounds from hull/hull.ply
  // 4: pixels too untextured to keep a depth are not matched; 5: the census cost interpolated along
  // the epipolar lines (census_sampling: epipolar); 6: the confidence's peak-ratio factor
  // (peak_ratio_scale); 7: confidence_threshold compares the confidence without the peak ratio (an
  // ambiguous match keeps its depth at its lowered confidence); 8: a neighbour held upside down
  // against the reference has its census bits reversed (sweep_engine.h, ReverseCensusBits)
  std::string Version() const override { return "8"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  bool Shardable() const override { return true; }
  double ViewMemoryMb(const StageContext& context) const override {
    ImageSize size = LargestTrainingImage(context);
    const int max_size = context.params.Has("max_image_size") ? static_cast<int>(context.params.Int("max_image_size")) : 0;
    if (max_size > 0 && std::max(size.width, size.height) > max_size) {  // matched at this size
      const double factor = static_cast<double>(max_size) / std::max(size.width, size.height);
      size = {static_cast<int>(std::lround(size.width * factor)), static_cast<int>(std::lround(size.height * factor))};
    }
    const double pixels = size.Pixels();
    const PlaneSweepOptions o = ToOptions(context.params);
    // The cost volumes (the data cost and the semi-global sums: 16 bits per pixel and plane) of
    // the largest band, the images and maps of the whole view, the census codes of the reference
    // and its neighbours and as many more kept in the cache (8 bytes a pixel each), and the
    // program itself (100 MB). 640x480 with 128 planes: 289 MB estimated; templeRing's stage, two
    // views in flight, peaked at 460 MB.
    const int bands = SweepBands(size.width, size.height, o);
    const int band_rows = bands == 1 ? size.height : (size.height + bands - 1) / bands + 2 * kBandContextRows;
    const double bytes = SweepVolumeBytesPerRow(size.width, o.num_planes) * std::min(size.height, band_rows) +
                         SweepFixedBytesPerPixel(o.num_neighbors) * pixels + 2.0 * 8.0 * (o.num_neighbors + 1) * pixels;
    return pixels > 0 ? bytes / 1048576.0 + 100.0 : 0.0;
  }

  std::vector<ParamSpec> Parameters() const override {
    const PlaneSweepOptions d;
    auto s = [](double v) { std::ostringstream o; o << v; return o.str(); };
    return {
        {"num_planes", ParamType::kInt, s(d.num_planes), "Depth hypotheses, uniform in inverse depth, [2, 1024]"},
        {"num_neighbors", ParamType::kInt, s(d.num_neighbors), "Neighbour views per reference view, [1, 16]"},
        {"best_k", ParamType::kInt, s(d.best_k), "Neighbour costs averaged per pixel and plane (lowest k), [1, num_neighbors]"},
        {"cost", ParamType::kString, "census", "Matching cost", kCostNames},
        {"census_radius_x", ParamType::kInt, s(d.census_radius_x), "Census half width, pixels"},
        {"census_radius_y", ParamType::kInt, s(d.census_radius_y), "Census half height, pixels"},
        {"census_sampling", ParamType::kString, "epipolar",
         "Census cost between pixels: linear along the epipolar line (2 codes) or bilinear (4 codes; slower with AVX-512)",
         {"epipolar", "bilinear"}},
        {"window_radius", ParamType::kInt, s(d.window_radius), "Box window radius of the cost, pixels, [0, 15]"},
        {"aggregation", ParamType::kString, "semi_global", "Cost aggregation after the box window", kAggregationNames},
        {"sgm_paths", ParamType::kInt, s(d.sgm_paths), "Semi-global paths, 4 or 8"},
        {"p1", ParamType::kInt, s(d.p1), "Small-jump penalty, cost units (1000 ~ worst match)"},
        {"p2", ParamType::kInt, s(d.p2), "Large-jump penalty, cost units, [p1, 6000]"},
        {"p2_gamma", ParamType::kDouble, s(d.p2_gamma), "P2 divided by 1 + |grey step|/gamma; 0: constant"},
        {"confidence_scale", ParamType::kDouble, s(d.confidence_scale), "Margin factor of the confidence = scale * (mean cost - winner cost) / mean cost, clipped"},
        {"peak_ratio_scale", ParamType::kDouble, s(d.peak_ratio_scale),
         "Peak-ratio factor of the confidence = scale * (1 - winner cost / next local minimum), clipped, [0, 100]; 0: off"},
        {"texture_scale", ParamType::kDouble, s(d.texture_scale),
         "Grey std. dev. over the census window giving full confidence; 0: no texture factor"},
        {"noise_snr", ParamType::kDouble, s(d.noise_snr),
         "Texture factor at most the window's signal deviation over noise_snr times the photo's estimated noise "
         "deviation, [0, 100]; 0: the noise is not estimated"},
        {"confidence_threshold", ParamType::kDouble, s(d.confidence_threshold),
         "Depth dropped (0) where the confidence without its peak-ratio factor < this, [0, 1]"},
        {"min_depth", ParamType::kDouble, "-1", "Fallback near depth, scene units; -1: none"},
        {"max_depth", ParamType::kDouble, "-1", "Fallback far depth, scene units; -1: none"},
        {"bounding_box", ParamType::kDoubleList, "[]",
         "Fallback scene box [xmin, ymin, zmin, xmax, ymax, zmax] (world); depth bounds from its corners"},
        {"max_image_size", ParamType::kInt, "1600",
         "Longest side the views are matched at, px (COLMAP's name): larger ones are downscaled and their maps are "
         "written at that size; 0: as they are"},
        {"max_view_memory_mb", ParamType::kInt, s(d.max_view_memory_mb),
         "Memory of one view's sweep, MB; larger images are swept in bands of rows (0: unlimited)"},
        {"depth_margin", ParamType::kDouble, s(d.depth_margin), "Relative margin around sparse-point, box or per-pixel hull depths"},
        {"near_quantile", ParamType::kDouble, s(d.near_quantile),
         "Quantile of a view's sparse-point depths that sets its near bound, [0, 0.5]; "
         "forward-facing captures: 0.001 (LLFF's), so that thin occluders near the cameras are swept"},
        {"hull_ranges", ParamType::kBool, "true",
         "With hull/hull.ply: each pixel the hull covers sweeps only the planes from the hull's nearest surface "
         "(- depth_margin) to the view's far bound; pixels outside the hull sweep every plane"},
        {"min_angle_deg", ParamType::kDouble, s(d.min_angle_deg), "Smallest neighbour triangulation angle, degrees"},
        {"max_angle_deg", ParamType::kDouble, s(d.max_angle_deg), "Largest neighbour triangulation angle, degrees"},
        {"target_angle_deg", ParamType::kDouble, s(d.target_angle_deg), "Preferred triangulation angle, degrees"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    const std::vector<double> box = params.DoubleList("bounding_box");
    if (!box.empty() && (box.size() != 6 || box[0] >= box[3] || box[1] >= box[4] || box[2] >= box[5])) {
      return ParamError{"bounding_box", "must be empty or [xmin, ymin, zmin, xmax, ymax, zmax] with min < max"};
    }
    const int64_t max_size = params.Has("max_image_size") ? params.Int("max_image_size") : 0;
    if (max_size != 0 && (max_size < 16 || max_size > 100000)) {
      return ParamError{"max_image_size", "must be 0 (as they are) or in [16, 100000], got " + std::to_string(max_size)};
    }
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.ImagesRelative(), context.workspace.SparseRelative(), "hull/depth_bounds.json", "hull/hull.ply"};
  }
  // The photometric maps of each training view (multi_depth writes the geometric ones beside them);
  // before the model exists, the folders (for dependency order only).
  std::vector<std::string> Outputs(const StageContext& context) const override {
    const std::vector<std::string> names = context.TrainingImageNamesIfReadable();
    if (names.empty()) {
      return {"dense/stereo/depth_maps", "dense/stereo/normal_maps", "dense/stereo/confidence_maps", kPatchMatchConfig};
    }
    std::vector<std::string> outputs = {kPatchMatchConfig};
    for (const std::string& name : names) {
      outputs.push_back("dense/stereo/depth_maps/" + name + ".photometric.bin");
      outputs.push_back("dense/stereo/normal_maps/" + name + ".photometric.bin");
      outputs.push_back(Workspace::ConfidenceMapRelative(name, "photometric"));
    }
    return outputs;
  }

  void Run(StageContext& context) const override {
    const auto start = std::chrono::steady_clock::now();
    const PlaneSweepOptions options = ToOptions(context.params);
    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.size() < 2) throw InputError("plane_sweep: needs at least 2 posed training views in sparse/, found " + std::to_string(names.size()));
    std::vector<int> ids;
    for (const std::string& name : names) ids.push_back(model.FindImage(name)->image_id);

    // Views, loaded once (grey, scaled to max_image_size) when first needed: a shard loads its own
    // views and their neighbours only, and an unreadable image fails just the views that need it.
    std::vector<SweepView> views(names.size());
    std::vector<std::once_flag> loaded(names.size());  // a load that throws is tried again
    auto view = [&](size_t i) -> const SweepView& {
      std::call_once(loaded[i], [&] {
        const Image& image = model.images.at(ids[i]);
        const Camera& camera = model.CameraOf(image);
        const std::string problem = camera.Validate();
        if (!problem.empty()) throw InputError(context.workspace.SparseDir() + "/cameras.txt: camera of " + image.name + ": " + problem);
        // The depth maps of a distorted photo would lie on a grid that multi_depth, fuse and the
        // renderers cannot tell from the photo's own; COLMAP's dense steps, too, take undistorted
        // images.
        RequireUndistorted(camera, image.name, context.workspace.SparseDir() + "/cameras.txt", "plane_sweep");
        views[i].name = image.name;
        views[i].cam_from_world = image.cam_from_world;
        views[i].gray = LoadGray(context.workspace.ImagesDir() + "/" + image.name, camera,
                                 static_cast<int>(context.params.Has("max_image_size") ? context.params.Int("max_image_size") : 0), &views[i].camera);
      });
      return views[i];
    };
    const nlohmann::json hull_bounds = ReadViewBounds(context.workspace.Path("hull/depth_bounds.json"), "carve");
    // Per-view bounds an import recorded (LLFF's poses_bounds.npy), hashed with the sparse folder.
    const nlohmann::json capture_bounds = ReadViewBounds(context.workspace.Path("sparse/depth_bounds.json"), "import");
    const std::string hull_path = context.workspace.Path("hull/hull.ply");
    const bool hull_ranges = (!context.params.Has("hull_ranges") || context.params.Bool("hull_ranges")) && fs::exists(hull_path);
    const TriangleMesh hull = hull_ranges ? ReadMeshPly(hull_path) : TriangleMesh();
    for (const char* dir : {"depth_maps", "normal_maps", "confidence_maps"})
      fs::create_directories(context.workspace.Path(std::string("dense/stereo/") + dir));

    // Census codes of the views a reference is matched against: each view serves as a neighbour
    // of several references, so its codes stay in a cache sized for the views in flight.
    ViewCache<std::vector<uint64_t>> census(CapacityForViewsInFlight(options.num_neighbors + 1),
                                            [&](const std::string& other) {
                                              const size_t i = std::find(names.begin(), names.end(), other) - names.begin();
                                              return sweep::CensusTransform(view(i).gray, options.census_radius_x,
                                                                            options.census_radius_y);
                                            });
    const bool census_cost = context.params.String("cost") == "census";
    // This run's own work (the views it computed), for its speed: the evaluations, and the
    // thread-seconds of the parts of a view's work that are timed (metrics: thread_seconds).
    struct Work {
      int64_t evaluations = 0;
      double evaluation_seconds = 0, box_filter = 0, aggregation = 0, writing_maps = 0;
    };
    Work work_here;
    std::mutex work_mutex;
    const PerViewSummary summary = ForEachView(context, "plane_sweep", names, [&](const std::string& name) {
      const int index = static_cast<int>(std::find(names.begin(), names.end(), name) - names.begin());
      const Image& image = model.images.at(ids[index]);
      double near = 0, far = 0;
      const SweepView& key = view(index);
      const std::string source = DepthBounds(hull_bounds, capture_bounds, model, image, key, context.params, options, &near, &far);
      const std::vector<int> chosen = SelectNeighbors(model, ids, index, 0.5 * (near + far), options);
      if (chosen.empty()) {
        // The nearest other view, by the angle its centre and this one's subtend at the scene
        // point this view looks at: what the user would have to allow, or add views near.
        const Eigen::Vector3d at = image.Center() + image.ViewingDirection() * 0.5 * (near + far);
        double nearest = 180;
        for (size_t j = 0; j < ids.size(); ++j) {
          if (static_cast<int>(j) == index) continue;
          const Eigen::Vector3d u = (image.Center() - at).normalized(), v = (model.images.at(ids[j]).Center() - at).normalized();
          nearest = std::min(nearest, std::acos(std::clamp(u.dot(v), -1.0, 1.0)) * 180.0 / M_PI);
        }
        spdlog::warn("[plane_sweep] {}: no neighbour view within {}..{} degrees (the nearest is {:.1f} degrees away: "
                     "plane_sweep.min_angle_deg / max_angle_deg, or add photos between); no depth map",
                     name, options.min_angle_deg, options.max_angle_deg, nearest);
      }
      PlaneSweepResult result;
      if (chosen.empty()) {
        result.depth = DepthMap(key.gray.cols, key.gray.rows, 1, 0.f);
        result.normals = FloatMap(result.depth.width, result.depth.height, 3, 0.f);
        result.confidence = FloatMap(result.depth.width, result.depth.height, 1, 0.f);
      } else {
        std::vector<SweepView> neighbours;
        for (int j : chosen) {
          neighbours.push_back(view(j));
          if (census_cost) neighbours.back().census = census.Get(names[j]);
        }
        SweepView reference = key;
        if (census_cost) reference.census = census.Get(name);
        PlaneSweepOptions view_options = options;
        view_options.best_k = std::min<int>(options.best_k, static_cast<int>(neighbours.size()));
        // One view at a time (the memory budget): its semi-global passes take both cores.
        if (context.max_views_in_flight == 1 && tbb::this_task_arena::max_concurrency() >= 2) view_options.sgm_threads = 2;
        PixelDepthBounds bounds;
        const bool per_pixel = hull_ranges && source == "hull" && !hull.faces.empty();
        if (per_pixel) {
          // The hull's front only: nothing of the object lies in front of it, but behind its back
          // the background can show (between templeRing's columns: the lit backdrop, -0.25 dB on
          // the held-out photos when the back bounded the sweep too).
          RasterizeOptions raster;
          raster.near_z = 0.5 * near;
          bounds.near = Rasterize(hull, key.camera, key.cam_from_world, raster).depth;
        }
        result = PlaneSweep(reference, neighbours, near, far, view_options, per_pixel ? &bounds : nullptr);
      }
      // The writes run outside any parallel loop: the wall clock around them is this thread's
      // time in them, the waits for the disk (the atomic writes' fsync) included.
      const auto writes_started = std::chrono::steady_clock::now();
      WriteColmapArray(context.workspace.DepthMapPath(name, "photometric"), result.depth);
      WriteColmapArray(context.workspace.NormalMapPath(name, "photometric"), result.normals);
      WriteColmapArray(context.workspace.ConfidenceMapPath(name, "photometric"), result.confidence);
      const double writing = std::chrono::duration<double>(std::chrono::steady_clock::now() - writes_started).count();
      {
        std::lock_guard<std::mutex> lock(work_mutex);
        work_here.evaluations += result.evaluations;
        work_here.evaluation_seconds += result.evaluation_seconds;
        work_here.box_filter += result.box_filter_seconds;
        work_here.aggregation += result.aggregation_seconds;
        work_here.writing_maps += writing;
      }
      std::vector<std::string> neighbour_names;
      for (int j : chosen) neighbour_names.push_back(names[j]);
      return nlohmann::json{{"near", near}, {"far", far}, {"bounds_from", source}, {"neighbors", neighbour_names},
                            {"valid_fraction", result.valid_fraction}, {"evaluations", result.evaluations},
                            {"full_evaluations", result.full_evaluations}, {"cost_volume_mb", result.volume_bytes / 1048576.0},
                            {"bands", result.bands}, {"noise_sigma", result.noise_sigma}};
    });
    // Totals over every view (resumed and sharded ones too), in name order.
    int64_t evaluations = 0, full_evaluations = 0;
    double valid_sum = 0, volume_max = 0;
    int bands_max = 1;
    std::map<std::string, int> bound_sources;
    std::map<std::string, std::vector<std::string>> sources;  // for COLMAP's patch-match.cfg
    nlohmann::json per_view = nlohmann::json::object();
    for (const auto& [name, piece] : summary.pieces) {
      evaluations += piece.at("evaluations").get<int64_t>();
      full_evaluations += piece.value("full_evaluations", piece.at("evaluations").get<int64_t>());
      valid_sum += piece.at("valid_fraction").get<double>();
      volume_max = std::max(volume_max, piece.at("cost_volume_mb").get<double>());
      bands_max = std::max(bands_max, piece.value("bands", 1));
      ++bound_sources[piece.at("bounds_from").get<std::string>()];
      sources[name] = piece.at("neighbors").get<std::vector<std::string>>();
      per_view[name] = {{"near", piece["near"]}, {"far", piece["far"]}, {"bounds_from", piece["bounds_from"]},
                        {"neighbors", piece["neighbors"]}, {"valid_fraction", piece["valid_fraction"]}};
      if (piece.value("noise_sigma", 0.0) > 0) per_view[name]["noise_sigma"] = piece["noise_sigma"];
    }
    WriteFileAtomic(context.workspace.Path(kPatchMatchConfig), FormatPatchMatchConfig(sources));
    const double peak_rss = PeakRssMb();
    sweep::ReleaseBufferPool();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    size_t without_neighbours = 0;
    for (const auto& [name, piece] : summary.pieces) without_neighbours += piece.at("neighbors").empty();
    context.metrics["views_without_neighbours"] = without_neighbours;
    if (without_neighbours == names.size() && !names.empty()) {
      spdlog::warn("[plane_sweep] none of the {} views has a neighbour within {}..{} degrees: no depth map at all, "
                   "so nothing downstream (multi_depth, fuse, surfels) has points to work from",
                   names.size(), options.min_angle_deg, options.max_angle_deg);
    }
    context.metrics["views"] = names.size();
    context.metrics["wall_seconds"] = seconds;
    context.metrics["evaluations"] = evaluations;
    // Without per-pixel hull bounds every pixel would sweep every plane: the work they saved.
    context.metrics["evaluations_without_pixel_bounds"] = full_evaluations;
    context.metrics["evaluations_per_second"] = work_here.evaluations / seconds;
    // The evaluations alone, as if every thread spent all its time on them: the matching cost's
    // own speed, which the stage's figure above dilutes with everything else a view needs
    // (aggregation, winners, files).
    const double threads = static_cast<double>(std::min<size_t>(
        static_cast<size_t>(tbb::this_task_arena::max_concurrency()),
        tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
    const double per_core = work_here.evaluation_seconds > 0 ? work_here.evaluations / work_here.evaluation_seconds : 0.0;
    context.metrics["evaluations_per_second_per_thread"] = per_core;
    context.metrics["evaluation_threads"] = threads;
    context.metrics["evaluations_per_second_all_threads"] = per_core * threads;
    // Where the threads' time went, summed over the views this run computed: the evaluations and
    // the box filter (the threads' CPU time in those loops), the semi-global passes and winners
    // (the view's own thread), writing the three maps (wall, waits included); `wall_times_threads`
    // is what the threads had, the rest (loading, census codes, bounds, the volume's set-up,
    // normals, idle ends) the difference.
    context.metrics["thread_seconds"] = {{"evaluations", work_here.evaluation_seconds},
                                         {"box_filter", work_here.box_filter},
                                         {"semi_global_and_winners", work_here.aggregation},
                                         {"writing_maps", work_here.writing_maps},
                                         {"wall_times_threads", seconds * threads}};
    context.metrics["mean_valid_fraction"] = names.empty() ? 0.0 : valid_sum / names.size();
    context.metrics["cost_volume_mb_per_view"] = volume_max;
    context.metrics["bands_per_view"] = bands_max;  // > 1: swept in bands of rows within max_view_memory_mb
    context.metrics["peak_rss_mb"] = peak_rss;
    context.metrics["bounds_from"] = bound_sources;
    context.metrics["per_view"] = per_view;
    spdlog::info("[plane_sweep] {} views in {:.2f} s ({:.0f} M evaluations/s), mean kept fraction {:.3f}", names.size(),
                 seconds, context.metrics["evaluations_per_second"].get<double>() / 1e6, context.metrics["mean_valid_fraction"].get<double>());
  }

  static PlaneSweepOptions ToOptions(const Params& p) {
    PlaneSweepOptions o;
    o.num_planes = static_cast<int>(p.Int("num_planes"));
    o.num_neighbors = static_cast<int>(p.Int("num_neighbors"));
    o.best_k = static_cast<int>(p.Int("best_k"));
    const std::string& cost = p.String("cost");
    o.cost = cost == "sad" ? MatchCost::kSad : cost == "zncc" ? MatchCost::kZncc : MatchCost::kCensus;
    o.census_radius_x = static_cast<int>(p.Int("census_radius_x"));
    o.census_radius_y = static_cast<int>(p.Int("census_radius_y"));
    o.census_bilinear = p.String("census_sampling") == "bilinear";
    o.window_radius = static_cast<int>(p.Int("window_radius"));
    o.aggregation = p.String("aggregation") == "box" ? CostAggregation::kBox : CostAggregation::kSemiGlobal;
    o.sgm_paths = static_cast<int>(p.Int("sgm_paths"));
    o.p1 = static_cast<int>(p.Int("p1"));
    o.p2 = static_cast<int>(p.Int("p2"));
    o.p2_gamma = p.Double("p2_gamma");
    o.confidence_scale = p.Double("confidence_scale");
    o.peak_ratio_scale = p.Double("peak_ratio_scale");
    o.confidence_threshold = p.Double("confidence_threshold");
    o.texture_scale = p.Double("texture_scale");
    o.noise_snr = p.Double("noise_snr");
    o.min_depth = p.Double("min_depth");
    o.max_depth = p.Double("max_depth");
    o.depth_margin = p.Double("depth_margin");
    o.near_quantile = p.Double("near_quantile");
    if (p.Has("max_view_memory_mb")) o.max_view_memory_mb = static_cast<int>(p.Int("max_view_memory_mb"));
    o.min_angle_deg = p.Double("min_angle_deg");
    o.max_angle_deg = p.Double("max_angle_deg");
    o.target_angle_deg = p.Double("target_angle_deg");
    return o;
  }

 private:
  // Per-view {near, far} bounds of `path`, written by stage `producer` (empty when absent).
  static nlohmann::json ReadViewBounds(const std::string& path, const std::string& producer) {
    if (!fs::exists(path)) return nlohmann::json::object();
    std::ifstream in(path);
    try {
      nlohmann::json j = nlohmann::json::parse(in);
      if (!j.is_object()) throw InputError(path + ": expected an object {\"<image>\": {\"near\": z, \"far\": z}}");
      return j;
    } catch (const nlohmann::json::exception& e) {
      throw InputError(path + ": not valid JSON (" + e.what() + "); re-run the " + producer + " stage or delete the file");
    }
  }

  // Hull bounds with near <= this fraction of far are degenerate (the hull reaches the camera).
  static constexpr double kMinHullNearFraction = 1e-3;

  // Sets near/far and returns where they came from.
  static std::string DepthBounds(const nlohmann::json& hull, const nlohmann::json& capture, const SparseModel& model, const Image& image,
                                 const SweepView& view, const Params& params, const PlaneSweepOptions& o,
                                 double* near, double* far) {
    if (hull.contains(image.name)) {
      const auto& b = hull[image.name];
      if (!b.contains("near") || !b.contains("far") || !b["near"].is_number() || !b["far"].is_number() ||
          !(b["near"].get<double>() > 0) || !(b["far"].get<double>() > b["near"].get<double>())) {
        throw InputError("hull/depth_bounds.json: entry of " + image.name + " needs numbers 0 < near < far");
      }
      // A hull that reaches the camera (silhouettes that fill the image: noise above the threshold,
      // a wrong background) bounds nothing: its near depth is ~0, and planes spaced in inverse depth
      // from there all crowd at the camera but the last, which then wins every pixel with high
      // confidence (found by the stability matrix at image noise sigma 12). Such a view falls back
      // to the sparse points, a box or the config's range.
      if (b["near"].get<double>() > kMinHullNearFraction * b["far"].get<double>()) {
        *near = b["near"].get<double>();
        *far = b["far"].get<double>();
        return "hull";
      }
      spdlog::warn("[plane_sweep] view {}: the hull reaches the camera (near {:.3g}, far {:.3g}); its depth bounds "
                   "are not used (check the silhouettes)",
                   image.name, b["near"].get<double>(), b["far"].get<double>());
    }
    if (capture.contains(image.name)) {
      const auto& b = capture[image.name];
      if (!b.contains("near") || !b.contains("far") || !b["near"].is_number() || !b["far"].is_number() ||
          !(b["near"].get<double>() > 0) || !(b["far"].get<double>() > b["near"].get<double>())) {
        throw InputError("sparse/depth_bounds.json: entry of " + image.name + " needs numbers 0 < near < far; re-run import");
      }
      *near = b["near"].get<double>() * (1 - o.depth_margin);
      *far = b["far"].get<double>() * (1 + o.depth_margin);
      return "capture_bounds";
    }
    if (DepthBoundsFromPoints(model, image, o.depth_margin, o.near_quantile, near, far)) return "sparse_points";
    const std::vector<double> box = params.DoubleList("bounding_box");
    if (box.size() == 6) {
      double lo = 1e300, hi = -1e300;
      for (int c = 0; c < 8; ++c) {
        const Eigen::Vector3d corner(box[(c & 1) ? 3 : 0], box[(c & 2) ? 4 : 1], box[(c & 4) ? 5 : 2]);
        const double z = (image.cam_from_world * corner).z();
        lo = std::min(lo, z);
        hi = std::max(hi, z);
      }
      if (hi > 0) {
        *far = hi * (1 + o.depth_margin);
        *near = std::max(lo * (1 - o.depth_margin), 1e-3 * *far);
        return "bounding_box";
      }
    }
    if (o.min_depth > 0 && o.max_depth > 0) {
      *near = o.min_depth;
      *far = o.max_depth;
      return "config";
    }
    throw InputError("plane_sweep: no depth range for view " + view.name +
                     ": no hull/depth_bounds.json or sparse/depth_bounds.json entry, fewer than 8 sparse points in view, and neither "
                     "plane_sweep.bounding_box nor plane_sweep.min_depth/max_depth set in the config");
  }
};

int StereoPairMain(const std::vector<std::string>& args) {
  CLI::App app{"Two-view stereo on a rectified pair (census + semi-global plane sweep); writes the left disparity"};
  std::string left, right, out;
  int max_disparity = 64;
  PlaneSweepOptions options;
  std::string cost = "census";
  std::string method = "plane_sweep";
  app.add_option("LEFT", left, "Left (reference) image")->required();
  app.add_option("RIGHT", right, "Right image")->required();
  app.add_option("--max-disparity", max_disparity, "Disparities searched: 0 .. N-1")->check(CLI::Range(1, 4096));
  app.add_option("--out", out, "Output disparity, PFM (<= 0 where no estimate)")->required();
  app.add_option("--method", method, "plane_sweep (this stage's), or another stage's two-view method (layered)");
  app.add_option("--cost", cost, "census, sad or zncc")->check(CLI::IsMember(kCostNames));
  app.add_option("--window-radius", options.window_radius, "Box window radius, pixels");
  app.add_option("--p1", options.p1, "Small-jump penalty, cost units");
  app.add_option("--p2", options.p2, "Large-jump penalty, cost units");
  bool no_lr = false, no_fill = false;
  app.add_flag("--no-lr-check", no_lr, "Keep pixels that fail the left-right check");
  app.add_flag("--no-fill", no_fill, "Leave rejected pixels empty (no hole filling)");
  std::vector<std::string> reversed(args.rbegin(), args.rend());
  try {
    app.parse(reversed);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  options.cost = cost == "sad" ? MatchCost::kSad : cost == "zncc" ? MatchCost::kZncc : MatchCost::kCensus;
  options.lr_check = !no_lr;
  options.fill_holes = !no_fill;
  std::string error;
  if (!options.Check(&error)) {
    std::cerr << "stereo-pair: --" << error << "\n";
    return 2;
  }
  cv::Size size;  // of the pair, for an out-of-memory message
  try {
    const cv::Mat l = ReadImageColor(left), r = ReadImageColor(right);
    size = l.size();
    if (l.size() != r.size()) {
      std::cerr << "stereo-pair: " << left << " and " << right << " differ in size; a rectified pair has equal sizes\n";
      return 1;
    }
    if (method != "plane_sweep") {
      const TwoViewMethod other = FindTwoViewMethod(method);
      if (!other) {
        std::string known;
        for (const std::string& name : TwoViewMethodNames()) known += " " + name;
        std::cerr << "stereo-pair: --method " << method << " is not a two-view method; known:" << known << "\n";
        return 2;
      }
      const auto start = std::chrono::steady_clock::now();
      const TwoViewOutput result = other(l, r, max_disparity, {});
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      WritePfm(out, result.disparity);
      std::cout << "stereo-pair: " << out << " (" << l.cols << "x" << l.rows << ", " << max_disparity << " disparities, "
                << method << ", " << seconds * 1e3 << " ms)\n";
      return 0;
    }
    const StereoPairResult result = StereoPair(l, r, max_disparity, options);
    WritePfm(out, result.disparity);
    std::cout << "stereo-pair: " << out << " (" << l.cols << "x" << l.rows << ", " << max_disparity << " disparities, "
              << result.seconds * 1e3 << " ms, unfilled " << result.unfilled_fraction << ")\n";
  } catch (const std::bad_alloc&) {
    // The cost volume and the two semi-global sums: 16-bit costs, disparities in multiples of 16.
    const double gb = 3.0 * size.width * size.height * ((max_disparity + 15) / 16 * 16) * 2 / 1e9;
    std::cerr << "stereo-pair: out of memory: " << size.width << "x" << size.height << " with " << max_disparity
              << " disparities needs about " << gb
              << " GB for its cost volumes; lower --max-disparity or downscale the pair\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "stereo-pair: " << e.what() << "\n";
    return 1;
  }
  return 0;
}

}  // namespace

// The two-view method for other stages: stereo-pair's defaults; options "fill" and "lr_check"
// ("true"/"false") and "cost" (census, sad, zncc).
static TwoViewOutput PlaneSweepTwoView(const cv::Mat& left, const cv::Mat& right, int max_disparity, const TwoViewOptions& given) {
  PlaneSweepOptions options;
  auto flag = [](const std::string& key, const std::string& value) {
    if (value == "true") return true;
    if (value == "false") return false;
    throw std::invalid_argument("plane_sweep two-view option " + key + ": expected true or false, got '" + value + "'");
  };
  for (const auto& [key, value] : given) {
    if (key == "fill") {
      options.fill_holes = flag(key, value);
    } else if (key == "lr_check") {
      options.lr_check = flag(key, value);
    } else if (key == "cost") {
      if (value != "census" && value != "sad" && value != "zncc") {
        throw std::invalid_argument("plane_sweep two-view option cost: census, sad or zncc, got '" + value + "'");
      }
      options.cost = value == "sad" ? MatchCost::kSad : value == "zncc" ? MatchCost::kZncc : MatchCost::kCensus;
    } else {
      throw std::invalid_argument("plane_sweep two-view: unknown option '" + key + "' (fill, lr_check, cost)");
    }
  }
  const StereoPairResult result = StereoPair(left, right, max_disparity, options);
  return {result.disparity, {{"seconds", result.seconds}, {"unfilled_fraction", result.unfilled_fraction},
                             {"evaluations", result.evaluations}}};
}

void RegisterStage_plane_sweep(StageRegistry* registry) {
  RegisterTwoViewMethod("plane_sweep", PlaneSweepTwoView);
  registry->Add(std::make_unique<PlaneSweepStage>());
  registry->AddCommand({"stereo-pair", "Two-view stereo on a rectified pair: LEFT RIGHT --max-disparity N --out DISP.pfm",
                        StereoPairMain});
}

}  // namespace ibmr
