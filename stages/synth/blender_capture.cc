// The synthetic object capture in NeRF's Blender layout (see blender_capture.h), and the command
// `ibmr synth-blender` that writes it.
#include "stages/synth/blender_capture.h"

#include <tbb/parallel_for.h>

#include <cmath>
#include <filesystem>
#include <iostream>
#include <mutex>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/rigid3.h"
#include "stages/synth/synth.h"

namespace fs = std::filesystem;

namespace ibmr {

bool BlenderCaptureOptions::Check(std::string* error) const {
  const auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (size < 16 || size > 4096) return fail("size: must be in [16, 4096], got " + std::to_string(size));
  if (train < 2 || train > 1000) return fail("train: must be in [2, 1000], got " + std::to_string(train));
  if (val < 0 || val > 1000) return fail("val: must be in [0, 1000], got " + std::to_string(val));
  if (test < 0 || test > 1000) return fail("test: must be in [0, 1000], got " + std::to_string(test));
  if (seed < 0) return fail("seed: must be >= 0");
  if (supersample < 1 || supersample > 8) return fail("supersample: must be in [1, 8]");
  if (!(camera_angle_x > 0.05 && camera_angle_x < 2.5)) return fail("camera_angle_x: must be in (0.05, 2.5) radians");
  if (radius != -1 && !(radius >= 2.5 && radius <= 100)) return fail("radius: must be -1 (automatic) or in [2.5, 100]");
  if (!(strength >= 0 && strength <= 1)) return fail("strength: must be in [0, 1]");
  if (thin_parts < 0 || thin_parts > 200) return fail("thin-parts: must be in [0, 200], got " + std::to_string(thin_parts));
  return true;
}

namespace {

struct Frame {
  std::string split;
  int index = 0;
  Eigen::Vector3d eye;
};

Eigen::Vector3d OnSphere(double radius, double azimuth, double elevation) {
  return radius * Eigen::Vector3d(std::cos(elevation) * std::cos(azimuth), std::cos(elevation) * std::sin(azimuth),
                                  std::sin(elevation));
}

std::vector<Frame> Frames(const BlenderCaptureOptions& options) {  // options.radius set
  constexpr double kDeg = M_PI / 180.0;
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  std::vector<Frame> frames;
  // Train: uniform by area over the band of elevations 5..75 degrees, golden-angle azimuths.
  const double low = std::sin(5 * kDeg), high = std::sin(75 * kDeg);
  for (int i = 0; i < options.train; ++i) {
    const double u = (i + 0.5) / options.train;
    frames.push_back({"train", i, OnSphere(options.radius, i * golden, std::asin(low + u * (high - low)))});
  }
  for (int i = 0; i < options.val; ++i) {
    frames.push_back({"val", i, OnSphere(options.radius, (i + 0.25) * 2 * M_PI / options.val, 20 * kDeg)});
  }
  for (int i = 0; i < options.test; ++i) {
    frames.push_back({"test", i, OnSphere(options.radius, (i + 0.5) * 2 * M_PI / options.test, 30 * kDeg)});
  }
  return frames;
}

}  // namespace

BlenderCaptureSummary WriteBlenderCapture(const std::string& folder, const BlenderCaptureOptions& options) {
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument(error);
  SynthOptions synth;
  synth.scene = SynthSceneKind::kObjectRing;
  synth.views = 2;  // replaced by the capture's frames below
  synth.width = synth.height = options.size;
  synth.seed = options.seed;
  synth.supersample = options.supersample;
  synth.sparse_points = 0;
  synth.degradation = options.degradation;
  synth.strength = options.strength;
  synth.thin_parts = options.thin_parts;
  SynthScene scene = BuildSynthScene(synth);
  const double focal = 0.5 * options.size / std::tan(0.5 * options.camera_angle_x);
  // Principal point at the image centre, as the layout's loaders assume.
  scene.camera = Camera::Pinhole(options.size, options.size, focal, focal, 0.5 * options.size, 0.5 * options.size);
  BlenderCaptureOptions placed = options;
  if (placed.radius < 0) {
    double bound = 0;  // the object's bounding sphere about the origin
    for (const Eigen::Vector3f& v : scene.mesh.vertices) bound = std::max(bound, static_cast<double>(v.norm()));
    placed.radius = bound / std::sin(0.75 * 0.5 * options.camera_angle_x);
  }
  const std::vector<Frame> frames = Frames(placed);
  scene.views.clear();
  for (size_t i = 0; i < frames.size(); ++i) {
    Image view;
    view.image_id = view.camera_id = static_cast<int>(i) + 1;
    view.name = frames[i].split + "/r_" + std::to_string(frames[i].index) + ".png";
    view.cam_from_world = LookAt(frames[i].eye, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ());
    scene.views.push_back(view);
  }
  for (const char* split : {"train", "val", "test"}) fs::create_directories(fs::path(folder) / split);

  std::vector<double> coverage(frames.size(), 0);
  tbb::parallel_for(size_t{0}, frames.size(), [&](size_t i) {
    const SynthView view = RenderSynthView(scene, static_cast<int>(i), synth);
    WriteImage((fs::path(folder) / scene.views[i].name).string(), view.rgba);
    std::vector<cv::Mat> channels;
    cv::split(view.rgba, channels);
    coverage[i] = static_cast<double>(cv::countNonZero(channels[3] > 127)) / channels[3].total();
  });

  const Eigen::Matrix4d flip = Eigen::Vector4d(1, -1, -1, 1).asDiagonal();  // OpenCV <-> OpenGL camera axes
  for (const char* split : {"train", "val", "test"}) {
    nlohmann::json top = {{"camera_angle_x", options.camera_angle_x}, {"frames", nlohmann::json::array()}};
    for (size_t i = 0; i < frames.size(); ++i) {
      if (frames[i].split != split) continue;
      const Rigid3d world_from_cam = scene.views[i].cam_from_world.Inverse();
      Eigen::Matrix4d cam_to_world = Eigen::Matrix4d::Identity();
      cam_to_world.topLeftCorner<3, 3>() = world_from_cam.R();
      cam_to_world.topRightCorner<3, 1>() = world_from_cam.translation;
      const Eigen::Matrix4d gl = cam_to_world * flip;
      nlohmann::json matrix = nlohmann::json::array();
      for (int r = 0; r < 4; ++r) matrix.push_back({gl(r, 0), gl(r, 1), gl(r, 2), gl(r, 3)});
      top["frames"].push_back({{"file_path", "./" + std::string(split) + "/r_" + std::to_string(frames[i].index)},
                               {"rotation", 0.012566370614359171},
                               {"transform_matrix", matrix}});
    }
    WriteFileAtomic((fs::path(folder) / ("transforms_" + std::string(split) + ".json")).string(), top.dump(4) + "\n");
  }
  BlenderCaptureSummary summary;
  summary.frames = static_cast<int>(frames.size());
  for (double c : coverage) summary.mean_alpha_coverage += c / std::max<size_t>(1, frames.size());
  return summary;
}

}  // namespace ibmr
