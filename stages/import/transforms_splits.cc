// Reading NeRF-world captures with their train / val / test splits (see transforms_splits.h).
#include "stages/import/transforms_splits.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/nerf_formats.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// A frame's file path as ParseTransformsJson names it ("./train/r_0" -> "train/r_0.png").
std::string NormalName(const std::string& file_path) {
  std::string name = fs::path(file_path).lexically_normal().string();
  if (name.rfind("./", 0) == 0) name = name.substr(2);
  if (fs::path(name).extension().empty()) name += ".png";
  return name;
}

// Every frame's photo exists (where the json gave its size, the parser did not open it).
void CheckPhotosExist(const std::string& folder, const std::string& json_path, const std::vector<std::string>& names) {
  for (size_t i = 0; i < names.size(); ++i) {
    if (!fs::exists(fs::path(folder) / names[i])) {
      throw InputError(json_path + ": frame " + std::to_string(i) + " names \"" + names[i] + "\", which is not in " +
                       folder + "; fix the frame's file_path or restore the photo");
    }
  }
}

// Appends `part` (one split's model) to `out`, sharing cameras with equal intrinsics and size.
void Append(const SparseModel& part, const std::vector<std::string>& names, const std::string& split,
            const std::string& json_path, SplitCapture* out) {
  std::map<int, int> camera_id_of;  // part's camera id -> out's
  for (const auto& [id, camera] : part.cameras) {
    int found = 0;
    for (const auto& [out_id, out_camera] : out->model.cameras) {
      if (out_camera.model == camera.model && out_camera.params == camera.params && out_camera.width == camera.width &&
          out_camera.height == camera.height) {
        found = out_id;
      }
    }
    if (found == 0) {
      found = static_cast<int>(out->model.cameras.size()) + 1;
      Camera copy = camera;
      copy.camera_id = found;
      out->model.cameras[found] = copy;
    }
    camera_id_of[id] = found;
  }
  for (size_t i = 0; i < names.size(); ++i) {
    const Image* image = part.FindImage(names[i]);
    if (out->model.FindImage(names[i])) {
      throw InputError(json_path + ": frame " + std::to_string(i) + " names \"" + names[i] + "\", which the " +
                       out->splits.at(names[i]) + " split names too; a photo belongs to one split");
    }
    Image copy = *image;
    copy.image_id = static_cast<int>(out->model.images.size()) + 1;
    copy.camera_id = camera_id_of.at(image->camera_id);
    out->model.images[copy.image_id] = copy;
    out->names.push_back(names[i]);
    out->splits[names[i]] = split;
  }
}

SplitCapture ReadNerfstudio(const std::string& folder, const std::vector<std::string>& wanted,
                            const std::function<std::pair<int, int>(const std::string&)>& image_size) {
  const std::string json_path = (fs::path(folder) / "transforms.json").string();
  const std::string text = ReadFile(json_path);
  std::vector<std::string> names;
  const SparseModel model = ParseTransformsJson(text, json_path, image_size, &names);
  CheckPhotosExist(folder, json_path, names);
  SplitCapture capture;
  std::map<std::string, std::string> listed;  // name -> split, from the *_filenames lists
  const nlohmann::json top = nlohmann::json::parse(text);
  for (const char* split : {"train", "val", "test"}) {
    const std::string key = std::string(split) + "_filenames";
    if (!top.contains(key)) continue;
    if (!top[key].is_array()) throw IoError(json_path + ": \"" + key + "\" must be a list of file paths");
    for (const nlohmann::json& entry : top[key]) {
      if (!entry.is_string()) throw IoError(json_path + ": \"" + key + "\" holds a non-string");
      listed[NormalName(entry.get<std::string>())] = split;
    }
  }
  if (listed.empty()) {  // no split lists: every frame, no splits.json
    capture.model = model;
    capture.names = names;
    return capture;
  }
  for (const auto& [name, split] : listed) {
    if (!model.FindImage(name)) {
      throw InputError(json_path + ": \"" + split + "_filenames\" names \"" + name + "\", which no frame has");
    }
  }
  SparseModel kept;
  kept.cameras = model.cameras;
  std::vector<std::string> kept_names;
  for (const std::string& name : names) {
    const auto it = listed.find(name);
    const std::string split = it == listed.end() ? "train" : it->second;
    if (std::find(wanted.begin(), wanted.end(), split) == wanted.end()) continue;
    Image image = *model.FindImage(name);
    image.image_id = static_cast<int>(kept.images.size()) + 1;
    kept.images[image.image_id] = image;
    kept_names.push_back(name);
    capture.splits[name] = split;
  }
  capture.model = kept;
  capture.names = kept_names;
  return capture;
}

}  // namespace

SplitCapture ReadTransformsCapture(const std::string& folder, const std::vector<std::string>& wanted,
                                   const std::function<std::pair<int, int>(const std::string&)>& image_size) {
  if (std::find(wanted.begin(), wanted.end(), "train") == wanted.end()) {
    throw InputError("import.splits: must include train (the views the models are made from)");
  }
  if (fs::exists(fs::path(folder) / "transforms.json")) return ReadNerfstudio(folder, wanted, image_size);
  SplitCapture capture;
  std::string first_frame;  // "transforms_train.json frame 0 (train/r_0.png)", the size the others must have
  std::pair<int, int> first_size{0, 0};
  for (const std::string& split : wanted) {
    const std::string json_path = (fs::path(folder) / ("transforms_" + split + ".json")).string();
    if (!fs::exists(json_path)) {
      if (split == "train") {
        throw InputError(folder + ": neither transforms.json nor transforms_train.json; import.format transforms reads "
                                  "NeRF's Blender layout or a nerfstudio folder");
      }
      spdlog::warn("[import] {}: no transforms_{}.json; the capture has no {} split", folder, split, split);
      continue;
    }
    std::vector<std::string> names;
    const SparseModel part = ParseTransformsJson(ReadFile(json_path), json_path, image_size, &names);
    CheckPhotosExist(folder, json_path, names);
    for (size_t i = 0; i < names.size(); ++i) {
      const Camera& camera = part.CameraOf(*part.FindImage(names[i]));
      const std::pair<int, int> size{camera.width, camera.height};
      const std::pair<int, int> stored = image_size(names[i]);
      const auto text = [](std::pair<int, int> s) { return std::to_string(s.first) + "x" + std::to_string(s.second); };
      if (stored != size) {
        throw InputError(json_path + ": frame " + std::to_string(i) + " (" + names[i] + "): the photo is " + text(stored) +
                         " but the frame says " + text(size) + " (\"w\", \"h\"); fix the json or the photo");
      }
      if (first_frame.empty()) {
        first_frame = fs::path(json_path).filename().string() + " frame 0 (" + names[i] + ")";
        first_size = size;
      } else if (size != first_size) {
        throw InputError(json_path + ": frame " + std::to_string(i) + " (" + names[i] + ") is " + text(size) + " but " +
                         first_frame + " is " + text(first_size) +
                         "; the Blender layout has one image size: resize the photos alike");
      }
    }
    Append(part, names, split, json_path, &capture);
  }
  return capture;
}

}  // namespace ibmr
