// Parsers for the capture formats the import stage reads (see import.h).
#include "stages/import/import.h"

#include <Eigen/Core>
#include <filesystem>
#include <cmath>
#include <sstream>

#include "pipeline/core/errors.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// Reads `count` numbers from a line; throws naming file, line and what was expected.
std::vector<double> Numbers(std::istringstream& in, int count, const std::string& where, const std::string& what) {
  std::vector<double> values(count);
  for (int i = 0; i < count; ++i) {
    if (!(in >> values[i])) throw IoError(where + ": expected " + what + " (" + std::to_string(count) + " numbers)");
  }
  return values;
}

bool IsRotation(const Eigen::Matrix3d& r) {
  return (r * r.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-4 && r.determinant() > 0;
}

}  // namespace

bool ImportOptions::Check(std::string* error) const {
  if (focal_prior <= 0) {
    *error = "focal_prior: must be > 0 (a multiple of the larger image side, e.g. 1.2)";
    return false;
  }
  CameraModelId model;
  if (!CameraModelFromName(folder_camera_model, &model)) {
    *error = "folder_camera_model: unknown camera model '" + folder_camera_model +
             "'; use SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV or FULL_OPENCV";
    return false;
  }
  return true;
}

SparseModel ParseMiddleburyPar(const std::string& text, const std::string& path,
                               const std::function<std::pair<int, int>(const std::string&)>& image_size) {
  std::istringstream lines(text);
  std::string line;
  int line_number = 0;
  int declared = -1;
  SparseModel model;
  while (std::getline(lines, line)) {
    ++line_number;
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    const std::string where = path + ":" + std::to_string(line_number);
    std::istringstream in(line);
    if (declared < 0) {  // the first line holds the number of views
      if (!(in >> declared) || declared <= 0) throw IoError(where + ": expected the number of views on the first line");
      continue;
    }
    std::string name;
    in >> name;
    const std::vector<double> k = Numbers(in, 9, where, "k11..k33 after the image name");
    const std::vector<double> r = Numbers(in, 9, where, "r11..r33");
    const std::vector<double> t = Numbers(in, 3, where, "t1 t2 t3");
    Eigen::Matrix3d rotation;
    rotation << r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8];
    if (!IsRotation(rotation)) throw IoError(where + ": r11..r33 of '" + name + "' is not a rotation matrix");
    const auto [width, height] = image_size(name);
    Camera camera = Camera::Pinhole(width, height, k[0], k[4], k[2] + 0.5, k[5] + 0.5);
    camera.camera_id = static_cast<int>(model.cameras.size()) + 1;
    // Views share a camera when their intrinsics are identical (Middlebury rings have one).
    for (const auto& [id, existing] : model.cameras) {
      if (existing.params == camera.params && existing.width == width && existing.height == height) {
        camera.camera_id = id;
      }
    }
    model.cameras[camera.camera_id] = camera;
    Image image;
    image.image_id = static_cast<int>(model.images.size()) + 1;
    image.camera_id = camera.camera_id;
    image.name = name;
    image.cam_from_world = Rigid3d(rotation, Eigen::Vector3d(t[0], t[1], t[2]));
    model.images[image.image_id] = image;
  }
  if (declared < 0) throw IoError(path + ": empty file; expected a Middlebury _par.txt");
  if (static_cast<int>(model.images.size()) != declared) {
    throw IoError(path + ": the first line declares " + std::to_string(declared) + " views but " +
                  std::to_string(model.images.size()) + " follow");
  }
  return model;
}

void ParseStrechaCamera(const std::string& text, const std::string& path, Camera* camera, Rigid3d* cam_from_world) {
  std::istringstream in(text);
  auto read = [&](int count, const std::string& what) {
    std::vector<double> v(count);
    for (int i = 0; i < count; ++i) {
      if (!(in >> v[i])) throw IoError(path + ": expected " + what + " (" + std::to_string(count) + " numbers)");
    }
    return v;
  };
  const std::vector<double> k = read(9, "the 3x3 calibration matrix on lines 1-3");
  const std::vector<double> distortion = read(3, "the distortion line (line 4)");
  const std::vector<double> r = read(9, "the camera-to-world rotation on lines 5-7");
  const std::vector<double> c = read(3, "the camera centre on line 8");
  const std::vector<double> size = read(2, "'width height' on line 9");
  if (distortion[0] != 0 || distortion[1] != 0 || distortion[2] != 0) {
    throw IoError(path + ": non-zero distortion is not supported for Strecha cameras; undistort the images first");
  }
  Eigen::Matrix3d world_from_cam;
  world_from_cam << r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8];
  if (!IsRotation(world_from_cam)) throw IoError(path + ": lines 5-7 are not a rotation matrix");
  for (const double v : {k[0], k[2], k[4], k[5], c[0], c[1], c[2]}) {
    if (!std::isfinite(v)) throw IoError(path + ": a calibration or centre value is not a finite number");
  }
  if (!(k[0] > 0 && k[4] > 0)) throw IoError(path + ": focal lengths (K[0][0], K[1][1]) must be > 0");
  // Whole pixel counts in a plausible range: a cast of anything else to int is undefined.
  for (const double v : size) {
    if (!(v >= 1 && v <= 1e6) || v != std::floor(v)) {
      throw IoError(path + ": line 9 must be 'width height' in whole pixels (1 to 1000000)");
    }
  }
  *camera = Camera::Pinhole(static_cast<int>(size[0]), static_cast<int>(size[1]), k[0], k[4], k[2] + 0.5, k[5] + 0.5);
  const Eigen::Matrix3d rotation = world_from_cam.transpose();
  *cam_from_world = Rigid3d(rotation, -rotation * Eigen::Vector3d(c[0], c[1], c[2]));
}

Camera FolderCamera(int width, int height, double exif_focal_pixels, const ImportOptions& options) {
  const double focal = exif_focal_pixels > 0 ? exif_focal_pixels : options.focal_prior * std::max(width, height);
  Camera camera;
  CameraModelFromName(options.folder_camera_model, &camera.model);
  camera.width = width;
  camera.height = height;
  const double cx = width / 2.0;
  const double cy = height / 2.0;
  switch (camera.model) {
    case CameraModelId::kSimplePinhole: camera.params = {focal, cx, cy}; break;
    case CameraModelId::kPinhole: camera.params = {focal, focal, cx, cy}; break;
    case CameraModelId::kSimpleRadial: camera.params = {focal, cx, cy, 0}; break;
    case CameraModelId::kRadial: camera.params = {focal, cx, cy, 0, 0}; break;
    case CameraModelId::kOpenCV: camera.params = {focal, focal, cx, cy, 0, 0, 0, 0}; break;
    case CameraModelId::kFullOpenCV: camera.params = {focal, focal, cx, cy, 0, 0, 0, 0, 0, 0, 0, 0}; break;
  }
  return camera;
}

ImportFormat DetectFormat(const std::string& folder) {
  if (fs::exists(fs::path(folder) / "cameras.txt") && fs::exists(fs::path(folder) / "images.txt")) {
    return ImportFormat::kColmap;
  }
  if (fs::is_directory(fs::path(folder) / "gt_dense_cameras")) return ImportFormat::kStrecha;
  if (fs::exists(fs::path(folder) / "transforms.json") || fs::exists(fs::path(folder) / "transforms_train.json")) {
    return ImportFormat::kTransforms;
  }
  if (fs::exists(fs::path(folder) / "poses_bounds.npy")) return ImportFormat::kLlff;
  for (const auto& entry : fs::directory_iterator(folder)) {
    const std::string name = entry.path().filename().string();
    if (name.size() > 8 && name.compare(name.size() - 8, 8, "_par.txt") == 0) return ImportFormat::kMiddlebury;
  }
  return ImportFormat::kFolder;
}

}  // namespace ibmr
