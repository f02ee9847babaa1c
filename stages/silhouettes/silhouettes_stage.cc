// Adapter of the silhouettes stage (seed 000 lines 4136-4200; see silhouettes.h). Role kScoring:
// it sees every view and the holdout set, and writes training views' masks to
// masks/<image name>.png and held-out views' masks to heldout/masks/<image name>.png, so that no
// reconstruction stage reading masks/ ever sees a held-out silhouette. Each folder gets a
// report.json: {"views": {"<image name>": {foreground_fraction, components_found,
// components_kept, holes_filled, touches_border}}, "mode": ...}.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_info.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/stage_api.h"
#include "stages/silhouettes/silhouette_corruption.h"
#include "stages/silhouettes/silhouettes.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const std::vector<std::string> kModeNames = {"threshold", "background", "user", "alpha"};
const char kHeldoutMasksDir[] = "heldout/masks";

nlohmann::json ReportJson(const SilhouetteReport& report) {
  return {{"foreground_fraction", report.foreground_fraction},
          {"components_found", report.components_found},
          {"components_kept", report.components_kept},
          {"holes_filled", report.holes_filled},
          {"touches_border", report.touches_border}};
}

SilhouetteReport ReportFromJson(const nlohmann::json& json) {
  SilhouetteReport report;
  report.foreground_fraction = json.at("foreground_fraction").get<double>();
  report.components_found = json.at("components_found").get<int>();
  report.components_kept = json.at("components_kept").get<int>();
  report.holes_filled = json.at("holes_filled").get<int>();
  report.touches_border = json.at("touches_border").get<bool>();
  return report;
}

// Removes <folder>/*.png whose image name is not in `keep` (e.g. a view that became held out).
void RemoveOtherMasks(const std::string& folder, const std::set<std::string>& keep) {
  std::error_code ec;
  if (!fs::is_directory(folder, ec)) return;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    const std::string file = entry.path().filename().string();
    if (file.size() < 4 || file.compare(file.size() - 4, 4, ".png") != 0) continue;
    if (keep.count(file.substr(0, file.size() - 4)) == 0) fs::remove(entry.path(), ec);
  }
}

class SilhouettesStage : public Stage {
 public:
  std::string Name() const override { return "silhouettes"; }
  std::string Summary() const override {
    return "foreground masks (threshold+morphology+components, background difference, user masks) into masks/";
  }
  std::string Version() const override { return "2"; }  // 2: mode alpha
  HoldoutRole Role() const override { return HoldoutRole::kScoring; }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"mode", ParamType::kString, "threshold",
         "threshold: max(R,G,B) > threshold; background: difference to `background`; user: copy `mask_folder`; alpha: "
         "the photos' alpha > 0.5 (import's alpha/)",
         kModeNames},
        {"threshold", ParamType::kDouble, "0.19", "intensity or difference threshold, fraction of full scale, in [0, 1)"},
        {"dilate_px", ParamType::kInt, "10", "dilation disc radius in pixels, in [0, 200]"},
        {"corrupt", ParamType::kString, "none",
         "wrong silhouettes on purpose (stability matrix): none, erode, dilate or holes, on the training masks only"},
        {"corrupt_strength", ParamType::kDouble, "0", "of the corruption, in [0, 1] (silhouette_corruption.h)"},
        {"erode_px", ParamType::kInt, "7", "erosion disc radius in pixels (after dilation), in [0, 200]"},
        {"max_components", ParamType::kInt, "1", "largest 8-connected components kept, >= 0 (0: all)"},
        {"min_component_px", ParamType::kInt, "0", "components smaller than this many pixels are dropped, >= 0"},
        {"max_hole_px", ParamType::kInt, "-1", "holes up to this many pixels are filled; -1: all, 0: none"},
        {"background", ParamType::kPath, "\"\"", "background image (mode background), same size as the views"},
        {"mask_folder", ParamType::kPath, "\"\"",
         "folder of user masks <image name>.png or <stem>.png (mode user); relative to the config, or "
         "workspace:<path> for a workspace folder such as workspace:ground_truth/masks"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    const std::string& mode = params.String("mode");
    if (mode == "background" && params.String("background").empty()) {
      return ParamError{"background", "mode background needs a background image"};
    }
    if (mode == "user" && params.String("mask_folder").empty()) {
      return ParamError{"mask_folder", "mode user needs a folder of masks"};
    }
    SilhouetteCorruption corruption;
    if (!SilhouetteCorruptionFromName(params.String("corrupt"), &corruption)) {
      return ParamError{"corrupt", "must be none, erode, dilate or holes, got \"" + params.String("corrupt") + "\""};
    }
    if (!(params.Double("corrupt_strength") >= 0 && params.Double("corrupt_strength") <= 1)) {
      return ParamError{"corrupt_strength", "must be in [0, 1]"};
    }
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.ImagesRelative(), context.workspace.SparseRelative()};
    const std::string& mode = context.params.String("mode");
    if (mode == "background") inputs.push_back(context.params.String("background"));
    if (mode == "user" || mode == "alpha") inputs.push_back(MaskFolderInput(context));
    return inputs;
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"masks", kHeldoutMasksDir}; }

  void Run(StageContext& context) const override {
    const SilhouetteOptions options = ToOptions(context.params);
    std::string error;
    if (!options.Check(&error)) throw InputError("silhouettes." + error);
    const SparseModel model = context.LoadModel();  // kScoring: every view
    std::vector<std::string> names;
    for (int id : model.ImageIdsByName()) names.push_back(model.images.at(id).name);
    if (names.empty()) throw InputError(context.workspace.SparseDir() + ": no images; run import or synth first");

    cv::Mat background;
    if (options.mode == SilhouetteMode::kBackground) background = ReadImageColor(context.params.String("background"));
    const std::string mask_folder = MaskFolder(context);
    if (options.mode == SilhouetteMode::kUserMask && !fs::is_directory(mask_folder)) {
      throw InputError("silhouettes.mask_folder: '" + mask_folder + "' is not a folder");
    }

    std::set<std::string> training, heldout;
    for (const std::string& name : names) (context.IsHeldOut(name) ? heldout : training).insert(name);
    fs::create_directories(context.workspace.MasksDir());
    fs::create_directories(context.workspace.Path(kHeldoutMasksDir));
    RemoveOtherMasks(context.workspace.MasksDir(), training);
    RemoveOtherMasks(context.workspace.Path(kHeldoutMasksDir), heldout);

    SilhouetteCorruption corruption = SilhouetteCorruption::kNone;
    SilhouetteCorruptionFromName(context.params.String("corrupt"), &corruption);
    const PerViewSummary summary = ForEachView(context, "silhouettes", names, [&](const std::string& name) -> nlohmann::json {
      const Image& image = *model.FindImage(name);
      const Camera& camera = model.CameraOf(image);
      cv::Mat input;
      std::string input_path;
      if (options.mode == SilhouetteMode::kUserMask) {
        if (context.params.String("mode") == "alpha" && !fs::exists(mask_folder + "/" + name + ".png")) {
          throw InputError("silhouettes.mode: alpha: no alpha for view " + name + " (" + mask_folder + "/" + name +
                           ".png): its photo had no alpha channel, or import.alpha was ignore; use mode threshold, "
                           "background or user");
        }
        input_path = FindUserMask(mask_folder, name);
        input = ReadImageUnchanged(input_path);
        if (input.depth() != CV_8U) input.convertTo(input, CV_8U, input.depth() == CV_16U ? 1.0 / 257.0 : 255.0);
      } else {
        input_path = context.workspace.ImagesDir() + "/" + name;
        input = ReadImageColor(input_path);
      }
      if (input.cols != camera.width || input.rows != camera.height) {
        throw InputError(input_path + ": is " + std::to_string(input.cols) + "x" + std::to_string(input.rows) +
                         " but view " + name + " is " + std::to_string(camera.width) + "x" +
                         std::to_string(camera.height) + " in sparse/cameras.txt; supply a mask of the image's size");
      }
      SilhouetteResult result;
      try {
        result = ExtractSilhouette(input, background, options);
      } catch (const std::invalid_argument& e) {
        throw InputError("view " + name + " (" + input_path + "): " + e.what());
      }
      const bool held_out = heldout.count(name) > 0;
      if (!held_out) CorruptSilhouette(corruption, context.params.Double("corrupt_strength"), name, &result.mask);
      WriteImage(held_out ? HeldoutMaskPath(context, name) : context.workspace.MaskPath(name), result.mask);
      return ReportJson(result.report);
    });

    // Every view's report, resumed ones from their pieces.
    nlohmann::json training_report = {{"mode", context.params.String("mode")}, {"views", nlohmann::json::object()}};
    nlohmann::json heldout_report = training_report;
    int empty = 0, border = 0;
    std::vector<double> fractions;
    for (const std::string& name : names) {
      const bool held_out = heldout.count(name) > 0;
      const nlohmann::json& piece = summary.pieces.at(name);
      const SilhouetteReport report = ReportFromJson(piece);
      (held_out ? heldout_report : training_report)["views"][name] = piece;
      if (report.foreground_fraction == 0.0) {
        ++empty;
        spdlog::warn("[silhouettes] view {}: the silhouette is empty (no foreground pixel); check the mode and "
                     "threshold, or leave the view out",
                     name);
      }
      if (report.touches_border) ++border;
      fractions.push_back(report.foreground_fraction);
    }
    WriteFileAtomic(context.workspace.Path("masks/report.json"), training_report.dump(2));
    WriteFileAtomic(context.workspace.Path(std::string(kHeldoutMasksDir) + "/report.json"), heldout_report.dump(2));
    std::sort(fractions.begin(), fractions.end());
    context.metrics["views"] = names.size();
    context.metrics["training_views"] = training.size();
    context.metrics["heldout_views"] = heldout.size();
    context.metrics["empty_silhouettes"] = empty;
    context.metrics["views_touching_border"] = border;
    context.metrics["median_foreground_fraction"] = fractions[fractions.size() / 2];
    spdlog::info("[silhouettes] {} masks ({} held out), median foreground {:.3f}, {} touch the border, {} empty",
                 names.size(), heldout.size(), fractions[fractions.size() / 2], border, empty);
    // Masks that fill their images bound nothing: the hull then reaches the cameras (noise above the
    // threshold, a background that is not dark). Said once, with what to try.
    if (fractions[fractions.size() / 2] > kFilledFraction) {
      spdlog::warn("[silhouettes] the median mask covers {:.0f}% of its image: these silhouettes will not bound the "
                   "object (raise silhouettes.threshold, use mode background, or supply masks)",
                   100 * fractions[fractions.size() / 2]);
    }
  }

  // A median foreground fraction above this means the masks fill their images.
  static constexpr double kFilledFraction = 0.9;

 private:
  static SilhouetteOptions ToOptions(const Params& params) {
    SilhouetteOptions options;
    const std::string& mode = params.String("mode");
    options.mode = mode == "background"                   ? SilhouetteMode::kBackground
                   : mode == "user" || mode == "alpha" ? SilhouetteMode::kUserMask  // alpha: user masks import wrote
                                                       : SilhouetteMode::kThreshold;
    options.threshold = params.Double("threshold");
    options.dilate_px = static_cast<int>(std::clamp<int64_t>(params.Int("dilate_px"), -1, 100000));
    options.erode_px = static_cast<int>(std::clamp<int64_t>(params.Int("erode_px"), -1, 100000));
    options.max_components = static_cast<int>(std::clamp<int64_t>(params.Int("max_components"), -1, 1 << 30));
    options.min_component_px = static_cast<int>(std::clamp<int64_t>(params.Int("min_component_px"), -1, 1 << 30));
    options.max_hole_px = static_cast<int>(std::clamp<int64_t>(params.Int("max_hole_px"), -2, 1 << 30));
    return options;
  }

  // mask_folder: "workspace:<relative>" names a workspace folder; otherwise an absolute path.
  static std::string MaskFolder(const StageContext& context) {
    if (context.params.String("mode") == "alpha") return context.workspace.Path(kAlphaFolder);
    const std::string& value = context.params.String("mask_folder");
    const size_t prefix = value.find("workspace:");
    if (prefix != std::string::npos) return context.workspace.Path(value.substr(prefix + 10));
    return value;
  }
  static std::string MaskFolderInput(const StageContext& context) {
    if (context.params.String("mode") == "alpha") return kAlphaFolder;
    const std::string& value = context.params.String("mask_folder");
    const size_t prefix = value.find("workspace:");
    return prefix != std::string::npos ? value.substr(prefix + 10) : value;
  }

  static std::string HeldoutMaskPath(const StageContext& context, const std::string& name) {
    return context.workspace.Path(std::string(kHeldoutMasksDir) + "/" + name + ".png");
  }

  static std::string FindUserMask(const std::string& folder, const std::string& name) {
    const std::string stem = fs::path(name).stem().string();
    for (const std::string& candidate : {folder + "/" + name + ".png", folder + "/" + stem + ".png", folder + "/" + name}) {
      if (fs::exists(candidate)) return candidate;
    }
    throw InputError("silhouettes.mask_folder: no mask for view " + name + " in " + folder + " (looked for " + name +
                     ".png, " + stem + ".png and " + name + ")");
  }
};

}  // namespace

void RegisterStage_silhouettes(StageRegistry* registry) { registry->Add(std::make_unique<SilhouettesStage>()); }

}  // namespace ibmr
