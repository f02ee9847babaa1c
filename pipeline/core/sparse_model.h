// A sparse reconstruction as in COLMAP's text model: cameras (intrinsics), images (pose, name,
// 2D observations) and 3D points with tracks. Plain data; I/O lives in colmap_text_io.h.
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

struct Point2D {
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();  // pixels, COLMAP convention
  int64_t point3D_id = -1;                       // -1: not triangulated
};

struct Image {
  int image_id = 0;
  int camera_id = 0;
  std::string name;  // file name relative to the image folder, e.g. "templeSR0001.png"
  Rigid3d cam_from_world;
  std::vector<Point2D> points2D;

  Eigen::Vector3d Center() const { return cam_from_world.Inverse().translation; }
  // Viewing direction (camera z axis) in world coordinates.
  Eigen::Vector3d ViewingDirection() const { return cam_from_world.rotation.conjugate() * Eigen::Vector3d::UnitZ(); }
};

struct TrackElement {
  int image_id = 0;
  int point2D_idx = 0;
};

struct Point3D {
  Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
  Eigen::Matrix<uint8_t, 3, 1> color = Eigen::Matrix<uint8_t, 3, 1>::Zero();
  double error = -1;  // mean reprojection error in pixels; -1 when unknown
  std::vector<TrackElement> track;
};

struct SparseModel {
  std::map<int, Camera> cameras;     // by camera_id
  std::map<int, Image> images;       // by image_id
  std::map<int64_t, Point3D> points; // by point3D_id

  // Image ids ordered by image name (the order of a sorted folder listing).
  std::vector<int> ImageIdsByName() const;
  // nullptr when no image has this name.
  const Image* FindImage(const std::string& name) const;
  const Camera& CameraOf(const Image& image) const { return cameras.at(image.camera_id); }
  // Empty when consistent; otherwise names the first image whose camera is missing, etc.
  std::string Validate() const;
};

// Removes the images named in `names` and every observation of them from the points' tracks;
// points left with fewer than two observations are dropped (they were triangulated with them).
void RemoveImages(const std::set<std::string>& names, SparseModel* model);

}  // namespace ibmr
