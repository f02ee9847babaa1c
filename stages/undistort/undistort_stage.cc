// Adapter of the undistort stage: sparse/ + images/ -> dense/images/ (undistorted) and
// dense/sparse/ (PINHOLE cameras), the inputs of the dense stages, as COLMAP's image_undistorter:
// images larger than max_image_size are downscaled (area averaging) with their cameras.
// Every view (held-out ones too: scoring compares against undistorted photos) is processed.
#include <spdlog/spdlog.h>

#include <filesystem>
#include <map>
#include <mutex>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/stage_api.h"
#include "stages/undistort/undistort.h"

#include <opencv2/imgproc.hpp>

namespace fs = std::filesystem;

namespace ibmr {

namespace {

class UndistortStage : public Stage {
 public:
  std::string Name() const override { return "undistort"; }
  std::string Summary() const override { return "Undistorted images and PINHOLE cameras into dense/images, dense/sparse"; }
  std::string Version() const override { return "2"; }  // 2: max_image_size
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override {
    return {{"max_image_size", ParamType::kInt, "1600",
             "Longest side of the undistorted images, px (COLMAP's name); larger are downscaled with their cameras; "
             "0: as they are"}};
  }
  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    return std::nullopt;
  }
  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.SparseRelative(), context.workspace.ImagesRelative()};
  }
  ModelFolders WritesModel() const override { return {"dense/sparse", "dense/images"}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"dense/images", "dense/sparse"}; }

  void Run(StageContext& context) const override {
    const UndistortOptions options = ToOptions(context.params);
    const SparseModel model = ReadSparseModelText(context.workspace.SparseDir());
    const SparseModel undistorted = UndistortModel(model, options);
    if (model.images.empty()) throw InputError("undistort: " + context.workspace.SparseDir() + " has no posed images; run sfm or import first");
    std::map<int, std::pair<cv::Mat, cv::Mat>> maps;
    for (const auto& [id, camera] : model.cameras) {
      const std::string invalid = camera.Validate();
      if (!invalid.empty()) throw InputError("undistort: camera " + std::to_string(id) + " in " + context.workspace.SparseDir() + "/cameras.txt: " + invalid);
      if (camera.HasDistortion()) UndistortMaps(camera, &maps[id].first, &maps[id].second);
    }
    std::map<std::string, const Image*> by_name;
    std::vector<std::string> names;
    for (const auto& [id, image] : model.images) {
      by_name[image.name] = &image;
      names.push_back(image.name);
    }
    ForEachView(context, "undistorting", names, [&](const std::string& name) -> nlohmann::json {
      const Image& image = *by_name.at(name);
      const std::string source = context.workspace.ImagesDir() + "/" + name;
      const std::string target = context.workspace.Path("dense/images/" + name);
      const auto it = maps.find(image.camera_id);
      const Camera& output = undistorted.cameras.at(image.camera_id);
      cv::Mat pixels = ReadImageUnchanged(source);
      if (it != maps.end()) pixels = UndistortImage(pixels, it->second.first, it->second.second);
      if (pixels.cols != output.width || pixels.rows != output.height) {
        cv::Mat smaller;
        cv::resize(pixels, smaller, cv::Size(output.width, output.height), 0, 0, cv::INTER_AREA);
        pixels = smaller;
      }
      fs::create_directories(fs::path(target).parent_path());
      WriteImage(target, pixels);
      return {};
    });
    WriteSparseModelText(context.workspace.Path("dense/sparse"), undistorted);
    size_t resized = 0;
    for (const auto& [id, camera] : undistorted.cameras) resized += camera.width != model.cameras.at(id).width;
    context.metrics["max_image_size"] = options.max_image_size;
    context.metrics["cameras_downscaled"] = resized;
    context.metrics["images"] = names.size();
    context.metrics["cameras_with_distortion"] = maps.size();
    spdlog::info("[undistort] {} images, {} distorted cameras resampled", names.size(), maps.size());
  }

 private:
  static UndistortOptions ToOptions(const Params& params) {
    UndistortOptions options;
    if (params.Has("max_image_size")) options.max_image_size = static_cast<int>(params.Int("max_image_size"));
    return options;
  }
};

}  // namespace

void RegisterStage_undistort(StageRegistry* registry) { registry->Add(std::make_unique<UndistortStage>()); }

}  // namespace ibmr
