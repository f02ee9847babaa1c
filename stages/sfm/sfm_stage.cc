// Adapter of the sfm stage: runs COLMAP (sfm.h) on the workspace's images and writes the model it
// recovers into sfm/sparse/, which the stages after it read (Stage::WritesModel). Its input model,
// sparse/ (what import or synth wrote), stays as it was: one writer per file, so a new import
// re-runs sfm, and the known cameras of Middlebury, Strecha or synthetic captures stay there for
// eval_poses. From the input only the intrinsics are read (known_intrinsics: true), never poses.
// Its inputs for the cache are images/, image_list.txt and sparse/ (import's outputs).
//
// Holdout: the role is kAllViews: held-out views need cameras too (render and score use them),
// so they are registered with the rest; reconstruction stages drop them through LoadModel().
//
// On failure (too few views registered) with on_failure: keep_input, the known cameras of the
// input are written to sfm/sparse/ and the failure is reported in the metrics (which views, why);
// with on_failure: error the stage fails with that message.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/stage_api.h"
#include "stages/sfm/sfm.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const std::vector<std::string> kMatchers = {"exhaustive", "sequential"};

// Reads the shared camera of a cameras.txt (any COLMAP model, FULL_OPENCV included). Empty model
// when the file is absent, has no camera, or its cameras differ.
KnownIntrinsics ReadSharedIntrinsics(const std::string& path, std::string* why) {
  KnownIntrinsics known;
  std::ifstream in(path);
  if (!in) {
    *why = path + " is absent";
    return known;
  }
  std::string line, first;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream fields(line);
    std::string id, model, rest;
    int width = 0, height = 0;
    fields >> id >> model >> width >> height;
    std::getline(fields, rest);
    const std::string key = model + rest;
    if (first.empty()) {
      first = key;
      known.model = model;
      std::istringstream params(rest);
      double value;
      while (params >> value) known.params.push_back(value);
    } else if (key != first) {
      *why = path + ": cameras differ; intrinsics are estimated";
      return KnownIntrinsics();
    }
  }
  if (known.model.empty()) *why = path + " holds no camera";
  return known;
}

bool HasPoses(const std::string& folder) {
  if (!fs::exists(folder + "/images.txt")) return false;
  try {
    return !ReadSparseModelText(folder).images.empty();
  } catch (const std::exception&) {
    return false;  // e.g. a FULL_OPENCV camera from calibrate: no poses to keep anyway
  }
}

class SfmStage : public Stage {
 public:
  static constexpr const char* kModel = "sfm/sparse";
  std::string Name() const override { return "sfm"; }
  std::string Summary() const override {
    return "Structure from motion with the COLMAP command line (known intrinsics held fixed, retries) into sfm/sparse/";
  }
  std::string Version() const override { return "2"; }  // 2: writes sfm/sparse/, leaves sparse/ as it was
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"colmap", ParamType::kString, "colmap", "COLMAP executable (name on PATH or path)", {}, false},
        {"known_intrinsics", ParamType::kBool, "true", "Hold the intrinsics of sparse/cameras.txt fixed (one shared camera)"},
        {"known_poses", ParamType::kBool, "false",
         "Keep the imported cameras and poses of sparse/ and only triangulate points (COLMAP point_triangulator), "
         "so that COLMAP's dense tools find overlapping views"},
        {"camera_model", ParamType::kString, "SIMPLE_RADIAL", "COLMAP camera model when intrinsics are estimated",
         {"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"}},
        {"matcher", ParamType::kString, "exhaustive", "Feature matcher", kMatchers},
        {"max_image_size", ParamType::kInt, "3200", "Longest image side for feature extraction (px); >= 100"},
        {"max_num_features", ParamType::kInt, "8192", "SIFT features per image, first attempt; >= 100"},
        {"max_attempts", ParamType::kInt, "3", "Attempts with stronger settings while views stay unregistered; 1..5"},
        {"filter_max_reproj_error", ParamType::kDouble, "4.0",
         "Drop observations reprojecting farther than this (px) between bundle adjustments; (0, 100]"},
        {"global_refinements", ParamType::kInt, "5", "Filter-and-adjust rounds of each global bundle adjustment; 1..100"},
        {"register_remaining", ParamType::kBool, "true", "Register views the mapper left out (image_registrator + BA)"},
        {"min_registered_fraction", ParamType::kDouble, "0.5", "Below this fraction of views the run has failed; (0, 1]"},
        {"on_failure", ParamType::kString, "error", "On failure: error, or keep_input (write the known cameras back)",
         {"error", "keep_input"}},
        {"num_threads", ParamType::kInt, "-1", "COLMAP threads; -1 all cores", {}, false},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    const double fraction = params.Double("min_registered_fraction");
    if (!(fraction > 0 && fraction <= 1)) return ParamError{"min_registered_fraction", "must be in (0, 1]"};
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.ImagesRelative(), "image_list.txt", context.workspace.SparseRelative()};
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"sfm"}; }
  ModelFolders WritesModel() const override { return {kModel, ""}; }

  void Run(StageContext& context) const override {
    const Workspace& ws = context.workspace;
    const std::string known = ws.SparseDir();  // the input model: known cameras, when import had them
    const std::string output = ws.Path(kModel);
    const bool has_truth = HasPoses(known);
    if (context.params.Has("known_poses") && context.params.Bool("known_poses")) {
      if (!has_truth) throw InputError("sfm.known_poses: " + known + " has no posed images; import posed cameras first");
      const SfmResult result = TriangulateKnownPoses(ws.ImagesDir(), ReadSparseModelText(known), ws.Path("sfm/work"),
                                                     ws.LogsDir(), ToOptions(context.params), context.progress);
      FillMetrics(result, KnownIntrinsics(), result.registered.size(), &context.metrics);
      context.metrics["status"] = "known poses, points triangulated";
      context.metrics["points"] = result.model.points.size();
      spdlog::info("[sfm] known poses kept; {} points triangulated over {} views", result.model.points.size(),
                   result.model.images.size());
      WriteSparseModelText(output, result.model);
      return;
    }
    KnownIntrinsics intrinsics;
    std::string why;
    if (context.params.Bool("known_intrinsics")) {
      intrinsics = ReadSharedIntrinsics(known + "/cameras.txt", &why);
      if (intrinsics.model.empty()) spdlog::warn("[sfm] known_intrinsics: {}; estimating them", why);
    }
    const std::vector<std::string> names = ImageNames(ws);
    SfmOptions options = ToOptions(context.params);
    const std::map<std::string, int> sizes = PhotoSizes(known);
    if (sizes.size() > 1 && intrinsics.model.empty()) {
      std::string listed;
      for (const auto& [size, count] : sizes) listed += (listed.empty() ? "" : ", ") + size + ": " + std::to_string(count);
      spdlog::info("[sfm] photos of {} sizes ({}): one camera per photo", sizes.size(), listed);
      options.single_camera = false;
    }
    const SfmResult result = RunColmapSfm(ws.ImagesDir(), names, intrinsics, ws.Path("sfm/work"), ws.LogsDir(),
                                          options, context.progress);
    FillMetrics(result, intrinsics, names.size(), &context.metrics);

    const double fraction = static_cast<double>(result.registered.size()) / names.size();
    if (fraction < context.params.Double("min_registered_fraction")) {
      std::string message = "sfm: " + std::to_string(result.registered.size()) + " of " + std::to_string(names.size()) +
                            " views registered: " + result.failure + ". Unregistered:";
      for (const std::string& name : result.unregistered) message += " " + name;
      context.metrics["status"] = "failed";
      context.metrics["failure"] = message;
      if (context.params.String("on_failure") == "keep_input" && has_truth) {
        spdlog::error("[{}] {}; on_failure: keep_input, {} gets the known cameras", Name(), message, kModel);
        WriteSparseModelText(output, ReadSparseModelText(known));
        context.metrics["fallback"] = "known cameras (" + ws.SparseRelative() + ") written to " + kModel;
        return;
      }
      throw InputError(message + (has_truth ? "; set sfm.on_failure: keep_input to fall back to the known cameras" : ""));
    }
    context.metrics["status"] = result.unregistered.empty() ? "all registered" : "partial";
    WriteSparseModelText(output, result.model);
  }

 private:
  static SfmOptions ToOptions(const Params& params) {
    SfmOptions options;
    options.colmap = params.String("colmap");
    options.camera_model = params.String("camera_model");
    options.matcher = params.String("matcher") == "sequential" ? SfmMatcher::kSequential : SfmMatcher::kExhaustive;
    options.max_image_size = static_cast<int>(params.Int("max_image_size"));
    options.max_num_features = static_cast<int>(params.Int("max_num_features"));
    options.max_attempts = static_cast<int>(params.Int("max_attempts"));
    options.register_remaining = params.Bool("register_remaining");
    options.filter_max_reproj_error = params.Double("filter_max_reproj_error");
    options.global_refinements = static_cast<int>(std::clamp<int64_t>(params.Int("global_refinements"), -1, 1000));
    options.num_threads = static_cast<int>(params.Int("num_threads"));
    return options;
  }

  // "WIDTHxHEIGHT" -> number of cameras of the input model with that size (empty when unreadable).
  static std::map<std::string, int> PhotoSizes(const std::string& model_dir) {
    std::map<std::string, int> sizes;
    try {
      for (const auto& [id, camera] : ReadCamerasText(model_dir)) {
        ++sizes[std::to_string(camera.width) + "x" + std::to_string(camera.height)];
      }
    } catch (const std::exception&) {
    }
    return sizes;
  }

  static std::vector<std::string> ImageNames(const Workspace& ws) {
    std::vector<std::string> names;
    if (!fs::is_directory(ws.ImagesDir())) throw InputError("sfm: " + ws.ImagesDir() + " is missing; run import first");
    for (const auto& entry : fs::directory_iterator(ws.ImagesDir())) {
      if (entry.is_regular_file()) names.push_back(entry.path().filename().string());
    }
    std::sort(names.begin(), names.end());
    return names;
  }

  static void FillMetrics(const SfmResult& result, const KnownIntrinsics& intrinsics, size_t total, nlohmann::json* m) {
    (*m)["images"] = total;
    (*m)["registered"] = result.registered.size();
    (*m)["unregistered_images"] = result.unregistered;
    (*m)["models"] = result.num_models;
    (*m)["attempts"] = result.attempts;
    (*m)["attempt_summaries"] = result.attempt_summaries;
    (*m)["intrinsics"] = intrinsics.model.empty() ? "estimated" : "known, fixed (" + intrinsics.model + ")";
    (*m)["points3D"] = result.model.points.size();
    if (!result.failure.empty()) (*m)["failure"] = result.failure;
    nlohmann::json steps = nlohmann::json::array();
    for (const SfmStep& step : result.steps) {
      steps.push_back({{"step", step.attempt_step}, {"wall_seconds", step.wall_seconds},
                       {"peak_memory_mb", step.peak_memory_mb}, {"exit_code", step.exit_code}});
    }
    (*m)["steps"] = steps;
    nlohmann::json features = nlohmann::json::object();
    for (const auto& [name, count] : result.features_per_image) features[name] = count;
    (*m)["features_per_image"] = features;
    if (!result.unregistered.empty()) {
      std::string list;
      for (const std::string& name : result.unregistered) {
        auto it = result.features_per_image.find(name);
        list += " " + name + (it != result.features_per_image.end() ? " (" + std::to_string(it->second) + " features)" : "");
      }
      spdlog::warn("[sfm] unregistered:{}", list);
    }
  }
};

}  // namespace

void RegisterStage_sfm(StageRegistry* registry) { registry->Add(std::make_unique<SfmStage>()); }

}  // namespace ibmr
