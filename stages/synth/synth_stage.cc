// The synth stage adapter: maps YAML keys to SynthOptions, builds the scene, renders every view in
// parallel (resumable) and writes the workspace: images/, ground_truth/masks/, sparse/ (true cameras and
// sparse points) and ground_truth/ (depth/<image>.bin, mesh.ply, scene.json, pose_error.json). Test-data
// generation; follows no seed-paper section.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <climits>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <set>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/synth/blender_capture.h"
#include "stages/synth/synth.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int ClampToInt(int64_t value) { return static_cast<int>(std::clamp<int64_t>(value, INT_MIN, INT_MAX)); }

// Fills `options` from the keys present in `params` and checks them; the error names the key.
std::optional<ParamError> OptionsFromParams(const Params& params, SynthOptions* options) {
  if (params.Has("scene") && !SynthSceneKindFromName(params.String("scene"), &options->scene)) {
    return ParamError{"scene", "must be object_ring, room or forward_facing, got \"" + params.String("scene") + "\""};
  }
  const std::pair<const char*, int*> ints[] = {{"views", &options->views},
                                               {"width", &options->width},
                                               {"height", &options->height},
                                               {"supersample", &options->supersample},
                                               {"subdivision", &options->subdivision},
                                               {"sparse_points", &options->sparse_points},
                                               {"thin_parts", &options->thin_parts}};
  for (const auto& [key, field] : ints) {
    if (params.Has(key)) *field = ClampToInt(params.Int(key));
  }
  const std::pair<const char*, double*> doubles[] = {{"noise", &options->noise},
                                                     {"fov_deg", &options->fov_deg},
                                                     {"elevation_deg", &options->elevation_deg},
                                                     {"ring_radius", &options->ring_radius},
                                                     {"baseline", &options->baseline},
                                                     {"texture_frequency", &options->texture_frequency}};
  for (const auto& [key, field] : doubles) {
    if (params.Has(key)) *field = params.Double(key);
  }
  if (params.Has("seed")) options->seed = params.Int("seed");
  if (params.Has("strength")) options->strength = params.Double("strength");
  if (params.Has("degradation") && !SynthDegradationFromName(params.String("degradation"), &options->degradation)) {
    return ParamError{"degradation", "must be one of " + SynthDegradationNames() + ", got \"" +
                                         params.String("degradation") + "\""};
  }
  if (params.Has("textureless_wall")) options->textureless_wall = params.Bool("textureless_wall");
  std::string error;
  if (options->Check(&error)) return std::nullopt;
  // Check() starts its message with the key: split it off.
  const size_t space = error.find(' ');
  return ParamError{error.substr(0, space), space == std::string::npos ? error : error.substr(space + 1)};
}

// Removes renders of an earlier run with more views ("view_*" files not in `names`), so that
// images/, ground_truth/masks/ and ground_truth/depth/ hold exactly this scene's views.
void RemoveStaleViews(const Workspace& workspace, const std::vector<std::string>& names) {
  const std::set<std::string> keep(names.begin(), names.end());
  const std::pair<std::string, std::string> folders[] = {
      {workspace.ImagesDir(), ""}, {workspace.Path("ground_truth/masks"), ".png"}, {workspace.Path("ground_truth/depth"), ".bin"}};
  for (const auto& [folder, suffix] : folders) {
    std::error_code ec;
    if (!fs::is_directory(folder, ec)) continue;
    for (const fs::directory_entry& entry : fs::directory_iterator(folder, ec)) {
      const std::string file = entry.path().filename().string();
      if (file.rfind("view_", 0) != 0 || file.size() < suffix.size() ||
          file.compare(file.size() - suffix.size(), suffix.size(), suffix) != 0) {
        continue;
      }
      if (keep.count(file.substr(0, file.size() - suffix.size())) == 0) {
        spdlog::info("synth: removing stale {}", entry.path().string());
        fs::remove(entry.path(), ec);
      }
    }
  }
}

class SynthStage : public Stage {
 public:
  std::string Name() const override { return "synth"; }
  std::string Summary() const override {
    return "renders synthetic scenes (object ring, room) with true cameras, depth, masks and mesh";
  }
  // 2: ground_truth/pose_error.json (how far each written camera is off); pose_outliers
  std::string Version() const override { return "4"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"scene", ParamType::kString, "object_ring",
         "object_ring: one object, ring of cameras, plain background; room: box room with objects, "
         "forward-facing cameras on a line; forward_facing: the room with thin occluders, a grid of cameras "
         "with parallel axes (LLFF-like)", {"object_ring", "room", "forward_facing"}},
        {"views", ParamType::kInt, "24", "number of cameras, in [2, 10000]", {}},
        {"width", ParamType::kInt, "320", "image width in pixels, in [16, 8192]", {}},
        {"height", ParamType::kInt, "240", "image height in pixels, in [16, 8192]", {}},
        {"noise", ParamType::kDouble, "0", "Gaussian image noise sigma in 8-bit levels, in [0, 64]", {}},
        {"seed", ParamType::kInt, "1", "seeds shape, texture, sparse points and noise, >= 0", {}},
        {"supersample", ParamType::kInt, "2", "anti-aliasing sub-samples per pixel side, in [1, 8]", {}},
        {"fov_deg", ParamType::kDouble, "-1",
         "horizontal field of view in degrees, in (1, 150); -1: object fills 80% (object_ring), 60 (room)", {}},
        {"elevation_deg", ParamType::kDouble, "20", "object_ring: camera elevation in degrees, in [-80, 80]", {}},
        {"ring_radius", ParamType::kDouble, "4",
         "object_ring: camera distance to the object centre (object radius ~1), in [2.5, 100]", {}},
        {"baseline", ParamType::kDouble, "1", "room: length of the camera line; forward_facing: width of the camera grid; scene units, in (0, 4]", {}},
        {"textureless_wall", ParamType::kBool, "false", "room: leave the left wall untextured", {}},
        {"subdivision", ParamType::kInt, "5", "icosphere levels of the star-shaped objects (20*4^n faces), in [1, 7]",
         {}},
        {"sparse_points", ParamType::kInt, "1000", "sparse points sampled on the visible surface, in [0, 1000000]", {}},
        {"texture_frequency", ParamType::kDouble, "3",
         "cycles per scene unit of the coarsest texture octave, in (0, 64]", {}},
        {"degradation", ParamType::kString, "none",
         "for the stability matrix: none, textureless, specular, repetitive, few_views, camera_noise, image_noise, "
         "exposure, pose_outliers, or hand_held (forward_facing made hard: turned axes, pose noise, gains, "
         "highlights, sensor noise, fronds; stages/synth/synth_degradations.h)",
         {}},
        {"strength", ParamType::kDouble, "0", "of the degradation: 0 clean, 1 a hard case, in [0, 1]", {}},
        {"thin_parts", ParamType::kInt, "0",
         "object_ring: thin blades standing out of the object (fine structure, 7.5 mm to 3 cm wide on an object "
         "of radius about 1), in [0, 200]", {}},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    SynthOptions options;
    return OptionsFromParams(params, &options);
  }

  std::vector<std::string> Inputs(const StageContext&) const override { return {}; }
  ModelFolders WritesModel() const override { return {"sparse", "images"}; }
  std::vector<std::string> Outputs(const StageContext&) const override {
    return {"images", "sparse", "ground_truth"};
  }

  void Run(StageContext& context) const override {
    SynthOptions options;
    if (const auto error = OptionsFromParams(context.params, &options)) {
      throw InputError("synth." + error->key + " " + error->message);
    }
    const Workspace& workspace = context.workspace;
    spdlog::info("synth: scene {}, {} views of {}x{}, seed {}, noise {}, supersample {}",
                 SynthSceneKindName(options.scene), options.views, options.width, options.height, options.seed,
                 options.noise, options.supersample);

    auto start = std::chrono::steady_clock::now();
    const SynthScene scene = BuildSynthScene(options);
    const double build_seconds = SecondsSince(start);
    spdlog::info("synth: scene built in {:.3f}s ({} vertices, {} triangles)", build_seconds,
                 scene.mesh.vertices.size(), scene.mesh.faces.size());
    std::vector<std::string> names;
    std::map<std::string, int> index_of;
    for (size_t i = 0; i < scene.views.size(); ++i) {
      names.push_back(scene.views[i].name);
      index_of[scene.views[i].name] = static_cast<int>(i);
    }
    RemoveStaleViews(workspace, names);
    WriteMeshPly(workspace.GroundTruthMeshPath(), scene.mesh);
    WriteFileAtomic(workspace.Path("ground_truth/scene.json"), SynthSceneJson(scene, options).dump(2) + "\n");

    start = std::chrono::steady_clock::now();
    const PerViewSummary summary = ForEachView(context, "render", names, [&](const std::string& name) -> nlohmann::json {
      const SynthView view = RenderSynthView(scene, index_of.at(name), options);
      WriteImage(workspace.ImagesDir() + "/" + name, view.image);
      WriteImage(workspace.GroundTruthMaskPath(name), view.mask);
      WriteColmapArray(workspace.GroundTruthDepthPath(name), view.depth);
      return nlohmann::json{{"foreground", static_cast<double>(cv::countNonZero(view.mask)) / view.mask.total()}};
    });
    const double render_seconds = SecondsSince(start);
    spdlog::info("synth: rendered {} views in {:.3f}s ({} resumed)", summary.computed, render_seconds,
                 summary.resumed);

    start = std::chrono::steady_clock::now();
    SparseModel model = BuildSynthSparseModel(scene, options, context.progress);
    const SparseModel true_model = model;
    scene.degradation.PerturbCameras(&model);  // camera_noise, pose_outliers, hand_held: the images keep the true cameras
    WriteSparseModelText(workspace.SparseDir(), model);
    nlohmann::json pose_error = {{"views", nlohmann::json::object()}};
    for (const auto& [name, px] : PoseDisplacementsPx(true_model, model)) pose_error["views"][name] = {{"displacement_px", px}};
    WriteFileAtomic(workspace.GroundTruthPoseErrorPath(), pose_error.dump(1) + "\n");
    const double sparse_seconds = SecondsSince(start);
    size_t observations = 0;
    for (const auto& [id, point] : model.points) observations += point.track.size();
    spdlog::info("synth: {} sparse points, {} observations in {:.3f}s", model.points.size(), observations,
                 sparse_seconds);

    double foreground = 0;  // over all views, including ones an earlier run rendered (their pieces)
    for (const std::string& name : names) foreground += summary.pieces.at(name).at("foreground").get<double>();
    context.metrics["views"] = names.size();
    context.metrics["triangles"] = scene.mesh.faces.size();
    context.metrics["sparse_points"] = model.points.size();
    context.metrics["mean_track_length"] = model.points.empty() ? 0.0 : double(observations) / model.points.size();
    context.metrics["foreground_fraction"] = foreground / names.size();
    context.metrics["build_seconds"] = build_seconds;
    context.metrics["render_seconds"] = render_seconds;
    context.metrics["sparse_seconds"] = sparse_seconds;
  }
};

}  // namespace

namespace {

// `ibmr synth-blender OUT [--size N] [--train N] [--val N] [--test N] [--seed N] [--supersample N]
// [--degradation NAME] [--strength X] [--thin-parts N]`: the synthetic object capture in NeRF's Blender layout.
int SynthBlenderCommand(const std::vector<std::string>& args) {
  const std::string usage =
      "usage: ibmr synth-blender OUT [--size 800] [--train 100] [--val 100] [--test 200] [--seed 1] [--supersample 3]\n"
      "                          [--degradation none|specular|...] [--strength 0] [--thin-parts 0]\n"
      "Writes a synthetic object on a transparent background in NeRF's Blender layout (transforms_{train,val,test}.json,\n"
      "train/ val/ test/ RGBA PNGs) into OUT; import it with format transforms.\n";
  if (args.empty() || args[0] == "--help" || args[0] == "-h") {
    std::cout << usage;
    return args.empty() ? 2 : 0;
  }
  BlenderCaptureOptions options;
  try {
    for (size_t i = 1; i < args.size(); i += 2) {
      const std::string& flag = args[i];
      if (i + 1 >= args.size()) throw std::invalid_argument(flag + " needs a value");
      const std::string& value = args[i + 1];
      size_t used = 0;
      if (flag == "--size") options.size = std::stoi(value, &used);
      else if (flag == "--train") options.train = std::stoi(value, &used);
      else if (flag == "--val") options.val = std::stoi(value, &used);
      else if (flag == "--test") options.test = std::stoi(value, &used);
      else if (flag == "--seed") options.seed = std::stoll(value, &used);
      else if (flag == "--supersample") options.supersample = std::stoi(value, &used);
      else if (flag == "--strength") options.strength = std::stod(value, &used);
      else if (flag == "--thin-parts") options.thin_parts = std::stoi(value, &used);
      else if (flag == "--degradation") {
        if (!SynthDegradationFromName(value, &options.degradation)) {
          throw std::invalid_argument("--degradation: one of " + SynthDegradationNames() + ", got '" + value + "'");
        }
        used = value.size();
      } else {
        throw std::invalid_argument("unknown option '" + flag + "'");
      }
      if (used != value.size()) throw std::invalid_argument(flag + ": not a number: '" + value + "'");
    }
    const auto start = std::chrono::steady_clock::now();
    const BlenderCaptureSummary summary = WriteBlenderCapture(args[0], options);
    std::cout << "wrote " << summary.frames << " frames (" << options.train << " train, " << options.val << " val, "
              << options.test << " test) of " << options.size << "x" << options.size << " to " << args[0]
              << "; mean alpha coverage " << summary.mean_alpha_coverage << ", "
              << std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count() << " s\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "synth-blender: " << e.what() << "\n" << usage;
    return 1;
  }
}

}  // namespace

void RegisterStage_synth(StageRegistry* registry) {
  registry->Add(std::make_unique<SynthStage>());
  registry->AddCommand({"synth-blender", "Write a synthetic object capture in NeRF's Blender layout (RGBA, splits)",
                        SynthBlenderCommand});
}

}  // namespace ibmr
