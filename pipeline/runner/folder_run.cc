// `ibmr run FOLDER` (see folder_run.h).
#include "pipeline/runner/folder_run.h"

#include <spdlog/spdlog.h>
#include <stdlib.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace fs = std::filesystem;

namespace ibmr {

extern const char kConfig_photos[];
extern const char kConfig_llff[];
extern const char kConfig_blender[];

namespace {

bool IsPhoto(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".tif" || ext == ".tiff" || ext == ".bmp";
}

size_t CountPhotos(const fs::path& folder) {
  size_t count = 0;
  std::error_code ec;
  for (auto it = fs::directory_iterator(folder, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    if (it->is_regular_file(ec) && IsPhoto(it->path())) ++count;
  }
  return count;
}

bool HasParFile(const fs::path& folder) {
  std::error_code ec;
  for (auto it = fs::directory_iterator(folder, ec); !ec && it != fs::directory_iterator(); it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() > 8 && name.compare(name.size() - 8, 8, "_par.txt") == 0) return true;
  }
  return false;
}

// photos.yaml for a capture that brings its cameras: import reads them (format auto), no sfm;
// undistort makes pinhole views of its model as after sfm.
std::string PosedConfig(const std::string& description) {
  YAML::Node root = YAML::Load(kConfig_photos);
  YAML::Node stages(YAML::NodeType::Sequence);
  for (const YAML::Node& entry : root["stages"]) {
    const std::string name = entry.IsMap() ? entry.begin()->first.Scalar() : entry.Scalar();
    if (name == "sfm") continue;
    if (name == "import") {
      YAML::Node import;
      import["import"]["format"] = "auto";
      stages.push_back(import);
      continue;
    }
    stages.push_back(entry);
  }
  root["stages"] = stages;
  YAML::Emitter out;
  out << root;
  return "# configs/photos.yaml without sfm, for " + description +
         ": import reads the cameras (format auto).\n" + std::string(out.c_str()) + "\n";
}

}  // namespace

FolderPlan PlanForFolder(const std::string& folder) {
  const fs::path root(folder);
  if (!fs::is_directory(root)) throw InputError(folder + ": not a folder; give a folder of photos or a capture folder");
  FolderPlan plan;
  if (fs::exists(root / "transforms_train.json")) {
    plan = {"blender", "NeRF's Blender layout (transforms_train.json)", "blender.yaml", kConfig_blender};
  } else if (fs::exists(root / "poses_bounds.npy")) {
    plan = {"llff", "an LLFF capture (poses_bounds.npy)", "llff.yaml", kConfig_llff};
  } else if (fs::exists(root / "transforms.json") || fs::exists(root / "images.txt") ||
             fs::is_directory(root / "gt_dense_cameras") || HasParFile(root)) {
    const std::string what = fs::exists(root / "transforms.json")   ? "transforms.json"
                             : fs::exists(root / "images.txt")      ? "a COLMAP model"
                             : fs::is_directory(root / "gt_dense_cameras") ? "Strecha's gt_dense_cameras/"
                                                                     : "a Middlebury _par.txt";
    plan = {"posed", "a capture with its cameras (" + what + ")", "photos.yaml", ""};
    plan.config_text = PosedConfig(plan.description);
  } else if (const size_t photos = CountPhotos(root) + CountPhotos(root / "images"); photos > 0) {
    plan = {"photos", "a folder of " + std::to_string(photos) + " photos without poses", "photos.yaml", kConfig_photos};
  } else {
    throw InputError(folder + ": no photos (jpg, png, tif, bmp) and no capture file (transforms.json, "
                     "poses_bounds.npy, images.txt) here; give the folder that holds them, or a config file");
  }
  return plan;
}

std::string DefaultWorkspaceFor(const std::string& folder) {
  fs::path path = fs::absolute(folder).lexically_normal();
  if (path.filename().empty()) path = path.parent_path();  // "photos/" -> "photos"
  return path.string() + ".ibmr";
}

std::string PrepareFolderRun(const std::string& folder, const std::string& workspace, const FolderPlan& plan,
                             bool dry_run) {
  std::string config = (fs::path(workspace) / "config.yaml").string();
  if (dry_run && !fs::exists(config)) {  // a dry run leaves no workspace behind
    config = (fs::temp_directory_path() / ("ibmr_folder_config_" + std::to_string(::getpid()) + ".yaml")).string();
    WriteFileAtomic(config, plan.config_text);
    spdlog::info("{}: {}; would run configs/{} in {}", folder, plan.description, plan.config_name, workspace);
  } else if (fs::exists(config)) {
    spdlog::info("{}: {}; running the workspace's config.yaml (written by an earlier run; edit it or delete it for "
                 "the shipped {})",
                 folder, plan.description, plan.config_name);
  } else {
    fs::create_directories(workspace);
    WriteFileAtomic(config, "# Written by `ibmr run " + folder + "` from configs/" + plan.config_name +
                                " for " + plan.description + ".\n# Edit it and run again: `ibmr run " +
                                folder + "` runs it.\n" + plan.config_text);
    spdlog::info("{}: {}; running configs/{} (written to {})", folder, plan.description, plan.config_name, config);
  }
  ::setenv("IBMR_IMAGES", fs::absolute(folder).lexically_normal().string().c_str(), 1);
  ::setenv("IBMR_WORKSPACE", workspace.c_str(), 1);
  return config;
}

}  // namespace ibmr
