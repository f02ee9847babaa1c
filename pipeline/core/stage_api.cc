// The stage registry and the context's holdout-aware model loading.
#include "pipeline/core/stage_api.h"

#include <algorithm>
#include <filesystem>
#include <stdexcept>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/sparse_image_names.h"

namespace ibmr {


SparseModel StageContext::LoadModel() const {
  SparseModel model = ReadSparseModelText(workspace.SparseDir());
  if (model.images.empty()) {
    // Import of a folder of photos writes their cameras (intrinsics) and no poses: sfm gives them.
    size_t photos = 0;
    std::error_code ec;
    for (auto it = std::filesystem::directory_iterator(workspace.ImagesDir(), ec);
         !ec && it != std::filesystem::directory_iterator(); it.increment(ec)) {
      photos += it->is_regular_file(ec) || it->is_symlink(ec);
    }
    if (photos > 0) {
      throw InputError(workspace.SparseDir() + ": the " + std::to_string(photos) + " photos in " +
                       workspace.ImagesRelative() + "/ have no poses yet (a folder of photos brings none); " +
                       "add an sfm stage after import, which gives them poses (configs/photos.yaml does), or import "
                       "a capture that brings its cameras (import.format llff, transforms, middlebury, strecha)");
    }
    throw InputError(workspace.SparseDir() + ": no posed images; run import (or synth) first");
  }
  if (role == HoldoutRole::kTrainingOnly) RemoveImages(heldout_images, &model);
  return model;
}

namespace {

// `sorted` without the views a kTrainingOnly stage must not see.
std::vector<std::string> TrainingOf(const StageContext& context, const std::vector<std::string>& sorted) {
  std::vector<std::string> names;
  for (const std::string& name : sorted) {
    if (context.role == HoldoutRole::kTrainingOnly && context.IsHeldOut(name)) continue;
    names.push_back(name);
  }
  return names;
}

}  // namespace

std::vector<std::string> StageContext::TrainingImageNames(const SparseModel& model) const {
  std::vector<std::string> sorted;
  for (int id : model.ImageIdsByName()) sorted.push_back(model.images.at(id).name);
  return TrainingOf(*this, sorted);
}

std::vector<std::string> StageContext::TrainingImageNamesIfReadable() const {
  // Asked for by every stage's declared inputs and outputs: the names are read once per version of
  // the model's files.
  const SparseImageNames model = ReadSparseImageNamesCached(workspace.SparseDir());
  return model.readable ? TrainingOf(*this, model.names) : std::vector<std::string>();
}

const std::string* StageContext::SkippedBy(const std::string& path) const {
  if (skipped_outputs.empty()) return nullptr;
  const std::string resolved = workspace.Resolve(path);
  for (const auto& [output, reason] : skipped_outputs) {
    if (PathWithin(resolved, output)) return &reason;
  }
  return nullptr;
}

ImageSize LargestTrainingImage(const StageContext& context) {
  if (!std::filesystem::exists(context.workspace.SparseDir() + "/images.txt")) return {};
  try {
    const SparseModel model = context.LoadModel();
    ImageSize largest;
    for (const std::string& name : context.TrainingImageNames(model)) {
      const Camera& camera = model.CameraOf(*model.FindImage(name));
      const ImageSize size{camera.width, camera.height};
      if (size.Pixels() > largest.Pixels()) largest = size;
    }
    return largest;
  } catch (const std::exception&) {
    return {};
  }
}

void StageRegistry::Add(std::unique_ptr<Stage> stage) {
  if (Find(stage->Name())) throw std::logic_error("stage '" + stage->Name() + "' registered twice");
  stages_.push_back(std::move(stage));
}

const Stage* StageRegistry::Find(const std::string& name) const {
  for (const auto& stage : stages_) {
    if (stage->Name() == name) return stage.get();
  }
  return nullptr;
}

std::vector<std::string> StageRegistry::Names() const {
  std::vector<std::string> names;
  for (const auto& stage : stages_) names.push_back(stage->Name());
  return names;
}

}  // namespace ibmr
