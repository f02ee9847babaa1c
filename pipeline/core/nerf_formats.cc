// transforms.json and poses_bounds.npy readers and writers (see nerf_formats.h).
#include "pipeline/core/nerf_formats.h"

#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <stdexcept>

#include "pipeline/core/errors.h"

namespace ibmr {

namespace {

// OpenGL camera axes (y up, z backwards) <-> OpenCV's (y down, z forward): flip y and z.
const Eigen::Matrix4d kFlipYZ = Eigen::Vector4d(1, -1, -1, 1).asDiagonal();

Eigen::Matrix4d CamToWorld(const Rigid3d& cam_from_world) {
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = world_from_cam.R();
  m.topRightCorner<3, 1>() = world_from_cam.translation;
  return m;
}

Rigid3d FromCamToWorld(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& center) {
  const Eigen::Matrix3d r = rotation.transpose();
  return Rigid3d(r, -r * center);
}

bool IsRotation(const Eigen::Matrix3d& r) {
  return r.allFinite() && (r * r.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-4 && r.determinant() > 0;
}

double Number(const nlohmann::json& object, const char* key, const std::string& where) {
  const auto it = object.find(key);
  if (it == object.end() || !it->is_number()) throw IoError(where + ": \"" + key + "\" missing or not a number");
  const double value = it->get<double>();
  if (!std::isfinite(value)) throw IoError(where + ": \"" + key + "\" is not finite");
  return value;
}

// A key of the frame, else of the file's top level; NaN when neither has it.
double Lookup(const nlohmann::json& frame, const nlohmann::json& top, const char* key) {
  for (const nlohmann::json* object : {&frame, &top}) {
    const auto it = object->find(key);
    if (it != object->end() && it->is_number()) return it->get<double>();
  }
  return std::nan("");
}

}  // namespace

SparseModel ParseTransformsJson(const std::string& text, const std::string& path,
                                const std::function<std::pair<int, int>(const std::string&)>& image_size,
                                std::vector<std::string>* names) {
  nlohmann::json top;
  try {
    top = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw IoError(path + ": not JSON (" + e.what() + ")");
  }
  if (!top.is_object() || !top.contains("frames") || !top["frames"].is_array() || top["frames"].empty()) {
    throw IoError(path + ": expected an object with a non-empty \"frames\" array");
  }
  SparseModel model;
  names->clear();
  std::map<std::vector<double>, int> camera_ids;  // identical intrinsics share a camera
  for (size_t i = 0; i < top["frames"].size(); ++i) {
    const nlohmann::json& frame = top["frames"][i];
    const std::string where = path + ": frame " + std::to_string(i);
    if (!frame.is_object() || !frame.contains("file_path") || !frame["file_path"].is_string()) {
      throw IoError(where + ": \"file_path\" missing");
    }
    std::string name = std::filesystem::path(frame["file_path"].get<std::string>()).lexically_normal().string();
    if (name.rfind("./", 0) == 0) name = name.substr(2);
    if (name.empty() || name.front() == '/' || name.rfind("..", 0) == 0) {
      throw IoError(where + ": \"file_path\" must be relative to the json's folder, got \"" + name + "\"");
    }
    if (std::filesystem::path(name).extension().empty()) name += ".png";  // the Blender layout
    // Pose: 4x4 (the last row 0 0 0 1 may be omitted).
    const auto& m = frame.value("transform_matrix", nlohmann::json());
    if (!m.is_array() || (m.size() != 4 && m.size() != 3)) throw IoError(where + ": \"transform_matrix\" must be 4x4");
    Eigen::Matrix4d gl = Eigen::Matrix4d::Identity();
    for (int r = 0; r < static_cast<int>(m.size()); ++r) {
      if (!m[r].is_array() || m[r].size() != 4) throw IoError(where + ": \"transform_matrix\" must be 4x4");
      for (int c = 0; c < 4; ++c) {
        if (!m[r][c].is_number()) throw IoError(where + ": \"transform_matrix\" holds a non-number");
        gl(r, c) = m[r][c].get<double>();
      }
    }
    const Eigen::Matrix4d cv = gl * kFlipYZ;
    if (!IsRotation(cv.topLeftCorner<3, 3>()) || !cv.topRightCorner<3, 1>().allFinite()) {
      throw IoError(where + ": \"transform_matrix\" is not a rigid camera-to-world transform");
    }
    // Intrinsics.
    double w = Lookup(frame, top, "w"), h = Lookup(frame, top, "h");
    if (!(w > 0 && h > 0)) {
      std::pair<int, int> size;
      try {
        size = image_size(name);
      } catch (const std::exception& e) {  // a missing or unreadable photo: say which frame names it
        throw IoError(where + " (\"" + name + "\"): " + e.what());
      }
      w = size.first;
      h = size.second;
    }
    if (!(w >= 1 && h >= 1 && w <= 1e6 && h <= 1e6) || w != std::floor(w) || h != std::floor(h)) {
      throw IoError(where + ": image size \"w\" x \"h\" must be whole pixels in [1, 1000000]");
    }
    double fx = Lookup(frame, top, "fl_x"), fy = Lookup(frame, top, "fl_y");
    double cx = Lookup(frame, top, "cx"), cy = Lookup(frame, top, "cy");
    if (std::isnan(fx)) {
      const double angle_x = Lookup(frame, top, "camera_angle_x");
      if (!(angle_x > 0 && angle_x < M_PI)) throw IoError(where + ": neither \"fl_x\" nor \"camera_angle_x\" in (0, pi)");
      fx = 0.5 * w / std::tan(0.5 * angle_x);
      const double angle_y = Lookup(frame, top, "camera_angle_y");
      fy = angle_y > 0 && angle_y < M_PI ? 0.5 * h / std::tan(0.5 * angle_y) : fx;
    }
    if (std::isnan(fy)) fy = fx;
    if (std::isnan(cx)) cx = w / 2;
    if (std::isnan(cy)) cy = h / 2;
    if (!(fx > 0 && fy > 0 && std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy))) {
      throw IoError(where + ": focal lengths must be > 0 and the principal point finite");
    }
    double k[4] = {0, 0, 0, 0};
    const char* const k_keys[4] = {"k1", "k2", "p1", "p2"};
    for (int j = 0; j < 4; ++j) {
      const double value = Lookup(frame, top, k_keys[j]);
      if (std::isfinite(value)) k[j] = value;
    }
    const bool distorted = k[0] != 0 || k[1] != 0 || k[2] != 0 || k[3] != 0;
    Camera camera;
    camera.width = static_cast<int>(w);
    camera.height = static_cast<int>(h);
    camera.model = distorted ? CameraModelId::kOpenCV : CameraModelId::kPinhole;
    camera.params = distorted ? std::vector<double>{fx, fy, cx, cy, k[0], k[1], k[2], k[3]}
                              : std::vector<double>{fx, fy, cx, cy};
    std::vector<double> key = camera.params;
    key.push_back(w);
    key.push_back(h);
    auto [it, fresh] = camera_ids.emplace(key, static_cast<int>(model.cameras.size()) + 1);
    if (fresh) {
      camera.camera_id = it->second;
      model.cameras[camera.camera_id] = camera;
    }
    Image image;
    image.image_id = static_cast<int>(model.images.size()) + 1;
    image.camera_id = it->second;
    image.name = name;
    image.cam_from_world = FromCamToWorld(cv.topLeftCorner<3, 3>(), cv.topRightCorner<3, 1>());
    if (model.FindImage(name)) throw IoError(where + ": \"" + name + "\" appears twice");
    model.images[image.image_id] = image;
    names->push_back(name);
  }
  return model;
}

std::string WriteTransformsJson(const SparseModel& model, const std::string& image_prefix) {
  const auto intrinsics = [](const Camera& camera) {
    nlohmann::json j = {{"w", camera.width}, {"h", camera.height}};
    const std::vector<double>& p = camera.params;
    switch (camera.model) {
      case CameraModelId::kSimplePinhole: j.update({{"fl_x", p[0]}, {"fl_y", p[0]}, {"cx", p[1]}, {"cy", p[2]}}); break;
      case CameraModelId::kPinhole: j.update({{"fl_x", p[0]}, {"fl_y", p[1]}, {"cx", p[2]}, {"cy", p[3]}}); break;
      case CameraModelId::kSimpleRadial:
        j.update({{"fl_x", p[0]}, {"fl_y", p[0]}, {"cx", p[1]}, {"cy", p[2]}, {"k1", p[3]}, {"k2", 0.0}, {"p1", 0.0}, {"p2", 0.0}});
        break;
      case CameraModelId::kRadial:
        j.update({{"fl_x", p[0]}, {"fl_y", p[0]}, {"cx", p[1]}, {"cy", p[2]}, {"k1", p[3]}, {"k2", p[4]}, {"p1", 0.0}, {"p2", 0.0}});
        break;
      case CameraModelId::kOpenCV:
        j.update({{"fl_x", p[0]}, {"fl_y", p[1]}, {"cx", p[2]}, {"cy", p[3]}, {"k1", p[4]}, {"k2", p[5]}, {"p1", p[6]}, {"p2", p[7]}});
        break;
      default:
        throw std::invalid_argument("transforms.json cannot hold a " + CameraModelName(camera.model) + " camera");
    }
    return j;
  };
  nlohmann::json top = nlohmann::json::object();
  bool distorted = false;
  for (const auto& [id, camera] : model.cameras) {
    distorted = distorted || (camera.model != CameraModelId::kPinhole && camera.model != CameraModelId::kSimplePinhole);
  }
  top["camera_model"] = distorted ? "OPENCV" : "PINHOLE";
  const bool shared = model.cameras.size() == 1;
  if (shared) top.update(intrinsics(model.cameras.begin()->second));
  top["frames"] = nlohmann::json::array();
  for (const int id : model.ImageIdsByName()) {
    const Image& image = model.images.at(id);
    const Eigen::Matrix4d gl = CamToWorld(image.cam_from_world) * kFlipYZ;
    nlohmann::json matrix = nlohmann::json::array();
    for (int r = 0; r < 4; ++r) matrix.push_back({gl(r, 0), gl(r, 1), gl(r, 2), gl(r, 3)});
    nlohmann::json frame = {{"file_path", image_prefix + image.name}, {"transform_matrix", matrix}};
    if (!shared) frame.update(intrinsics(model.CameraOf(image)));
    top["frames"].push_back(frame);
  }
  return top.dump(2) + "\n";
}

SparseModel ParsePosesBounds(const std::string& bytes, const std::string& path, const std::vector<std::string>& names,
                             int downscale, std::vector<std::pair<double, double>>* bounds) {
  // .npy: "\x93NUMPY", version, header length (uint16 for 1.x, uint32 for 2.x/3.x), a dict.
  if (bytes.size() < 10 || bytes.compare(0, 6, "\x93NUMPY") != 0) throw IoError(path + ": not a .npy file");
  const int major = static_cast<unsigned char>(bytes[6]);
  size_t header_length = 0, start = 0;
  if (major == 1) {
    header_length = static_cast<unsigned char>(bytes[8]) | (static_cast<unsigned char>(bytes[9]) << 8);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (bytes.size() < 12) throw IoError(path + ": truncated .npy header");
    for (int b = 0; b < 4; ++b) header_length |= static_cast<size_t>(static_cast<unsigned char>(bytes[8 + b])) << (8 * b);
    start = 12;
  } else {
    throw IoError(path + ": unsupported .npy version " + std::to_string(major));
  }
  if (start + header_length > bytes.size()) throw IoError(path + ": truncated .npy header");
  const std::string header = bytes.substr(start, header_length);
  if (header.find("'descr': '<f8'") == std::string::npos || header.find("'fortran_order': False") == std::string::npos) {
    throw IoError(path + ": expected little-endian float64 ('<f8') in C order; header " + header);
  }
  std::smatch shape;
  static const std::regex kShape(R"('shape': \((\d+), (\d+)\))");
  if (!std::regex_search(header, shape, kShape)) throw IoError(path + ": expected a 2-D array; header " + header);
  const size_t rows = std::stoul(shape[1].str()), cols = std::stoul(shape[2].str());
  if (cols != 17) throw IoError(path + ": expected 17 columns (3x5 pose and 2 bounds), got " + std::to_string(cols));
  if (rows != names.size()) {
    throw IoError(path + ": " + std::to_string(rows) + " poses for " + std::to_string(names.size()) + " images");
  }
  const size_t data_start = start + header_length;
  if (rows > (bytes.size() - data_start) / (17 * sizeof(double))) throw IoError(path + ": truncated data");
  if (!(downscale >= 1)) throw IoError(path + ": downscale must be >= 1");
  SparseModel model;
  if (bounds) bounds->clear();
  for (size_t i = 0; i < rows; ++i) {
    double v[17];
    std::memcpy(v, bytes.data() + data_start + i * sizeof(v), sizeof(v));
    const std::string where = path + ": row " + std::to_string(i) + " (" + names[i] + ")";
    for (const double x : v) {
      if (!std::isfinite(x)) throw IoError(where + ": not a finite number");
    }
    Eigen::Matrix3d llff;  // columns: down, right, backwards
    Eigen::Vector3d center;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) llff(r, c) = v[r * 5 + c];
      center[r] = v[r * 5 + 3];
    }
    Eigen::Matrix3d rotation;  // OpenCV camera to world: right, down, forward
    rotation.col(0) = llff.col(1);
    rotation.col(1) = llff.col(0);
    rotation.col(2) = -llff.col(2);
    if (!IsRotation(rotation)) throw IoError(where + ": the 3x3 part is not a rotation in LLFF's [down, right, back] order");
    const double h = v[4] / downscale, w = v[9] / downscale, f = v[14] / downscale;
    if (!(w >= 1 && h >= 1 && w <= 1e6 && h <= 1e6 && f > 0)) throw IoError(where + ": bad height, width or focal");
    Camera camera = Camera::Pinhole(static_cast<int>(std::lround(w)), static_cast<int>(std::lround(h)), f, f, w / 2, h / 2);
    camera.camera_id = static_cast<int>(i) + 1;
    model.cameras[camera.camera_id] = camera;
    Image image;
    image.image_id = image.camera_id = camera.camera_id;
    image.name = names[i];
    image.cam_from_world = FromCamToWorld(rotation, center);
    model.images[image.image_id] = image;
    if (bounds) bounds->emplace_back(v[15], v[16]);
  }
  return model;
}

std::string WritePosesBounds(const SparseModel& model, const std::vector<std::string>& names,
                             const std::vector<std::pair<double, double>>& bounds) {
  if (bounds.size() != names.size()) throw std::invalid_argument("one (near, far) pair per image");
  std::string data;
  for (size_t i = 0; i < names.size(); ++i) {
    const Image* image = model.FindImage(names[i]);
    if (!image) throw std::invalid_argument("no image " + names[i]);
    const Camera& camera = model.CameraOf(*image);
    const double fx = camera.FocalX(), fy = camera.FocalY();
    if (std::abs(fx - fy) > 1e-9 * fx || std::abs(camera.PrincipalX() - camera.width / 2.0) > 1e-9 ||
        std::abs(camera.PrincipalY() - camera.height / 2.0) > 1e-9 || camera.HasDistortion()) {
      throw std::invalid_argument(names[i] + ": poses_bounds.npy needs one focal length and the principal point at "
                                             "the image centre, without distortion");
    }
    const Eigen::Matrix4d m = CamToWorld(image->cam_from_world);
    Eigen::Matrix3d llff;
    llff.col(0) = m.block<3, 1>(0, 1);   // down
    llff.col(1) = m.block<3, 1>(0, 0);   // right
    llff.col(2) = -m.block<3, 1>(0, 2);  // backwards
    double v[17];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) v[r * 5 + c] = llff(r, c);
      v[r * 5 + 3] = m(r, 3);
    }
    v[4] = camera.height;
    v[9] = camera.width;
    v[14] = fx;
    v[15] = bounds[i].first;
    v[16] = bounds[i].second;
    data.append(reinterpret_cast<const char*>(v), sizeof(v));
  }
  std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (" + std::to_string(names.size()) + ", 17), }";
  // Padded with spaces and a newline so that the data starts at a multiple of 64 bytes.
  const size_t total = 10 + header.size() + 1;
  header.append((64 - total % 64) % 64, ' ');
  header += '\n';
  std::string out = std::string("\x93NUMPY\x01\x00", 8);
  out += static_cast<char>(header.size() & 0xFF);
  out += static_cast<char>(header.size() >> 8);
  return out + header + data;
}

}  // namespace ibmr
