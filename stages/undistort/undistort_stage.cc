// Adapter of the undistort stage: sparse/ + images/ -> dense/images/ (undistorted) and
// dense/sparse/ (PINHOLE cameras), the inputs of the dense stages, as COLMAP's image_undistorter.
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

namespace fs = std::filesystem;

namespace ibmr {

namespace {

class UndistortStage : public Stage {
 public:
  std::string Name() const override { return "undistort"; }
  std::string Summary() const override { return "Undistorted images and PINHOLE cameras into dense/images, dense/sparse"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.SparseRelative(), context.workspace.ImagesRelative()};
  }
  ModelFolders WritesModel() const override { return {"dense/sparse", "dense/images"}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"dense/images", "dense/sparse"}; }

  void Run(StageContext& context) const override {
    const SparseModel model = ReadSparseModelText(context.workspace.SparseDir());
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
      if (it == maps.end()) {
        fs::create_directories(fs::path(target).parent_path());
        WriteImage(target, ReadImageUnchanged(source));
      } else {
        WriteImage(target, UndistortImage(ReadImageUnchanged(source), it->second.first, it->second.second));
      }
      return {};
    });
    WriteSparseModelText(context.workspace.Path("dense/sparse"), UndistortModel(model));
    context.metrics["images"] = names.size();
    context.metrics["cameras_with_distortion"] = maps.size();
    spdlog::info("[undistort] {} images, {} distorted cameras resampled", names.size(), maps.size());
  }
};

}  // namespace

void RegisterStage_undistort(StageRegistry* registry) { registry->Add(std::make_unique<UndistortStage>()); }

}  // namespace ibmr
