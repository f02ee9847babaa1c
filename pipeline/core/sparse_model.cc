// SparseModel queries (images by name) and the consistency check run after reading a model:
// ids match their keys, every image has a camera, observations and tracks point at existing
// entries.
#include "pipeline/core/sparse_model.h"

#include <algorithm>
#include <set>
#include <sstream>

namespace ibmr {
namespace {

std::string ValidateCameras(const SparseModel& model) {
  for (const auto& [camera_id, camera] : model.cameras) {
    if (camera.camera_id != camera_id) {
      std::ostringstream error;
      error << "camera stored under id " << camera_id << " says camera_id " << camera.camera_id;
      return error.str();
    }
    const std::string camera_error = camera.Validate();
    if (!camera_error.empty()) return camera_error;
  }
  return "";
}

std::string ValidateImage(const SparseModel& model, int image_id, const Image& image) {
  std::ostringstream error;
  error << "image " << image_id << " '" << image.name << "': ";
  if (image.image_id != image_id) {
    error << "stored under id " << image_id << " but says image_id " << image.image_id;
  } else if (model.cameras.count(image.camera_id) == 0) {
    error << "camera " << image.camera_id << " is missing from the cameras";
  } else {
    for (size_t i = 0; i < image.points2D.size(); ++i) {
      const int64_t point_id = image.points2D[i].point3D_id;
      if (point_id != -1 && model.points.count(point_id) == 0) {
        error << "observation " << i << " refers to missing 3D point " << point_id;
        return error.str();
      }
    }
    return "";
  }
  return error.str();
}

std::string ValidateTrack(const SparseModel& model, int64_t point_id, const Point3D& point) {
  for (const TrackElement& element : point.track) {
    const auto image = model.images.find(element.image_id);
    std::ostringstream error;
    error << "3D point " << point_id << ": track element (" << element.image_id << ", "
          << element.point2D_idx << ") ";
    if (image == model.images.end()) {
      error << "refers to a missing image";
      return error.str();
    }
    if (element.point2D_idx < 0 ||
        element.point2D_idx >= static_cast<int>(image->second.points2D.size())) {
      error << "has an observation index out of range (image has "
            << image->second.points2D.size() << " observations)";
      return error.str();
    }
  }
  return "";
}

}  // namespace

std::vector<int> SparseModel::ImageIdsByName() const {
  std::vector<int> ids;
  ids.reserve(images.size());
  for (const auto& [image_id, image] : images) ids.push_back(image_id);
  // Ties (equal names, which Validate rejects) keep id order so the result is deterministic.
  std::stable_sort(ids.begin(), ids.end(),
                   [this](int a, int b) { return images.at(a).name < images.at(b).name; });
  return ids;
}

const Image* SparseModel::FindImage(const std::string& name) const {
  for (const auto& [image_id, image] : images) {
    if (image.name == name) return &image;
  }
  return nullptr;
}

std::string SparseModel::Validate() const {
  std::string error = ValidateCameras(*this);
  if (!error.empty()) return error;
  std::set<std::string> names;
  for (const auto& [image_id, image] : images) {
    error = ValidateImage(*this, image_id, image);
    if (!error.empty()) return error;
    if (!names.insert(image.name).second) {
      return "image " + std::to_string(image_id) + ": name '" + image.name +
             "' is used by another image";
    }
  }
  for (const auto& [point_id, point] : points) {
    error = ValidateTrack(*this, point_id, point);
    if (!error.empty()) return error;
  }
  return "";
}

// Removes held-out images and every observation of them from the points' tracks; points left
// with fewer than two observations are dropped (they were triangulated with held-out views).
void RemoveImages(const std::set<std::string>& names, SparseModel* model) {
  std::set<int> removed;
  for (auto it = model->images.begin(); it != model->images.end();) {
    if (names.count(it->second.name)) {
      removed.insert(it->first);
      it = model->images.erase(it);
    } else {
      ++it;
    }
  }
  if (removed.empty()) return;
  for (auto it = model->points.begin(); it != model->points.end();) {
    auto& track = it->second.track;
    track.erase(std::remove_if(track.begin(), track.end(),
                               [&](const TrackElement& e) { return removed.count(e.image_id) > 0; }),
                track.end());
    if (track.size() < 2) {
      for (auto& [id, image] : model->images) {
        for (Point2D& p : image.points2D) {
          if (p.point3D_id == it->first) p.point3D_id = -1;
        }
      }
      it = model->points.erase(it);
    } else {
      ++it;
    }
  }
}


}  // namespace ibmr
