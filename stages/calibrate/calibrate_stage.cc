// Adapter of the calibrate stage: reads the target images of a folder, calibrates (calibrate.h),
// writes calibration/camera.yml (OpenCV YAML) and calibration/cameras.txt (COLMAP, pixel centre
// (0.5, 0.5); import.cameras gives it to a folder's photos), and optionally undistorts a folder of
// images into calibration/undistorted/. Per-view errors and rejection reasons go into the record's metrics.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <regex>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/calibrate/calibrate.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const std::vector<std::string> kPatternNames = {"chessboard", "circles", "asymmetric_circles"};
const std::vector<std::string> kModelNames = {"PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"};

bool IsImageFile(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
  return ext == ".png" || ext == ".jpg" || ext == ".jpeg" || ext == ".tif" || ext == ".tiff" || ext == ".bmp";
}

std::vector<std::string> ListImages(const std::string& folder, const std::string& filter) {
  if (!fs::is_directory(folder)) throw InputError("calibrate.source: '" + folder + "' is not a folder");
  const std::regex pattern(filter);
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(folder)) {
    const std::string name = entry.path().filename().string();
    if (entry.is_regular_file() && IsImageFile(entry.path()) && std::regex_match(name, pattern)) names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  if (names.empty()) throw InputError("calibrate.source: no image in '" + folder + "' matches name_filter '" + filter + "'");
  return names;
}

class CalibrateStage : public Stage {
 public:
  std::string Name() const override { return "calibrate"; }
  std::string Summary() const override {
    return "Planar-target calibration (chessboard / circle grids, OpenCV) into calibration/cameras.txt and OpenCV YAML";
  }
  std::string Version() const override { return "2"; }  // 2: calibration/cameras.txt only (import.cameras reads it)
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"source", ParamType::kPath, "\"\"", "Folder of target images; empty: the config's inputs.calibration"},
        {"name_filter", ParamType::kString, "\".*\"", "Regular expression the image file names must match"},
        {"pattern", ParamType::kString, "chessboard", "Target type", kPatternNames},
        {"pattern_cols", ParamType::kInt, "9", "Inner corners (circles) per row; >= 2"},
        {"pattern_rows", ParamType::kInt, "6", "Inner corners (circles) per column; >= 2"},
        {"square_size", ParamType::kDouble, "0.025", "Corner / circle spacing in target units (m); > 0"},
        {"camera_model", ParamType::kString, "FULL_OPENCV", "Distortion model (COLMAP name)", kModelNames},
        {"fix_aspect_ratio", ParamType::kBool, "true", "Keep fx == fy"},
        {"subpixel_radius", ParamType::kInt, "11", "cornerSubPix half window in pixels (window 2r+1); >= 1"},
        {"outlier_factor", ParamType::kDouble, "3.0", "Reject views above this x median view error; > 1, 0 = off"},
        {"outlier_min_error", ParamType::kDouble, "0.5", "Never reject views below this error (px); >= 0"},
        {"min_views", ParamType::kInt, "3", "Views needed after rejection; >= 1"},
        {"undistort_source", ParamType::kPath, "\"\"", "Folder to undistort into calibration/undistorted/; empty: none"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    try {
      std::regex check(params.String("name_filter"));
    } catch (const std::regex_error& e) {
      return ParamError{"name_filter", std::string("not a valid regular expression: ") + e.what()};
    }
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs{Source(context)};
    if (!context.params.String("undistort_source").empty()) inputs.push_back(context.params.String("undistort_source"));
    return inputs;
  }
  std::vector<std::string> Outputs(const StageContext& context) const override {
    std::vector<std::string> outputs{"calibration/camera.yml", "calibration/cameras.txt"};
    if (!context.params.String("undistort_source").empty()) outputs.push_back("calibration/undistorted");
    return outputs;
  }

  void Run(StageContext& context) const override {
    const std::string source = Source(context);
    if (source.empty()) throw InputError("calibrate.source: empty; set calibrate.source or inputs.calibration");
    const CalibrateOptions options = ToOptions(context.params);
    std::vector<CalibrationView> views;
    for (const std::string& name : ListImages(source, context.params.String("name_filter"))) {
      views.push_back({name, ReadImageUnchanged(source + "/" + name)});
    }
    const CalibrationResult result = CalibratePlanar(views, options, context.progress);
    WriteOutputs(context, result);
    FillMetrics(result, &context.metrics);
    const std::string undistort = context.params.String("undistort_source");
    if (!undistort.empty()) Undistort(context, undistort, result);
  }

 private:
  static CalibrateOptions ToOptions(const Params& params) {
    CalibrateOptions options;
    const auto index = [](const std::vector<std::string>& names, const std::string& value) {
      return static_cast<int>(std::find(names.begin(), names.end(), value) - names.begin());
    };
    options.pattern = static_cast<CalibrationPattern>(index(kPatternNames, params.String("pattern")));
    options.model = static_cast<DistortionModel>(index(kModelNames, params.String("camera_model")));
    options.pattern_cols = static_cast<int>(params.Int("pattern_cols"));
    options.pattern_rows = static_cast<int>(params.Int("pattern_rows"));
    options.square_size = params.Double("square_size");
    options.fix_aspect_ratio = params.Bool("fix_aspect_ratio");
    options.subpixel_radius = static_cast<int>(params.Int("subpixel_radius"));
    options.outlier_factor = params.Double("outlier_factor");
    options.outlier_min_error = params.Double("outlier_min_error");
    options.min_views = static_cast<int>(params.Int("min_views"));
    return options;
  }

  static std::string Source(const StageContext& context) {
    if (!context.params.String("source").empty()) return context.params.String("source");
    auto it = context.inputs.find("calibration");
    return it != context.inputs.end() ? it->second : "";
  }

  static void WriteOutputs(const StageContext& context, const CalibrationResult& result) {
    const std::string cameras = CalibrationToColmapCameras(result);
    WriteFileAtomic(context.workspace.Path("calibration/camera.yml"), CalibrationToOpenCvYaml(result));
    WriteFileAtomic(context.workspace.Path("calibration/cameras.txt"), cameras);
  }

  static void FillMetrics(const CalibrationResult& result, nlohmann::json* metrics) {
    const cv::Mat& k = result.camera_matrix;
    (*metrics)["fx"] = k.at<double>(0, 0);
    (*metrics)["fy"] = k.at<double>(1, 1);
    (*metrics)["cx_opencv"] = k.at<double>(0, 2);
    (*metrics)["cy_opencv"] = k.at<double>(1, 2);
    (*metrics)["distortion"] = std::vector<double>(result.distortion.begin<double>(), result.distortion.end<double>());
    (*metrics)["rms_px"] = result.rms;
    (*metrics)["camera_model"] = result.colmap_model_name;
    nlohmann::json views = nlohmann::json::array(), rejected = nlohmann::json::array();
    int used = 0;
    for (const CalibrationViewResult& view : result.views) {
      views.push_back({{"name", view.name}, {"detected", view.detected}, {"used", view.used},
                       {"rms_error_px", view.rms_error}, {"reason", view.reason}});
      if (view.used) ++used;
      else rejected.push_back({{"name", view.name}, {"reason", view.reason}});
      if (!view.used) spdlog::warn("[calibrate] {} not used: {}", view.name, view.reason);
    }
    (*metrics)["views"] = views;
    (*metrics)["rejected"] = rejected;
    (*metrics)["used_views"] = used;
    spdlog::info("[calibrate] {} fx {:.2f} fy {:.2f} cx {:.2f} cy {:.2f}, RMS {:.3f} px over {} of {} views",
                 result.colmap_model_name, k.at<double>(0, 0), k.at<double>(1, 1), k.at<double>(0, 2),
                 k.at<double>(1, 2), result.rms, used, result.views.size());
  }

  static void Undistort(StageContext& context, const std::string& folder, const CalibrationResult& result) {
    const std::vector<std::string> names = ListImages(folder, ".*");
    context.progress->Begin("undistorting", names.size());
    for (const std::string& name : names) {
      const cv::Mat image = ReadImageUnchanged(folder + "/" + name);
      WriteImage(context.workspace.Path("calibration/undistorted/" + name), UndistortWithCalibration(image, result));
      context.progress->Advance(1, name);
    }
    context.progress->End();
    context.metrics["undistorted_images"] = names.size();
  }
};

}  // namespace

void RegisterStage_calibrate(StageRegistry* registry) { registry->Add(std::make_unique<CalibrateStage>()); }

}  // namespace ibmr
