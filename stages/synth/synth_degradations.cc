// Degradations of the synthetic scenes (see synth_degradations.h).
#include "stages/synth/synth_degradations.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <random>

#include "stages/synth/synth_scenes.h"

namespace ibmr {

namespace {

constexpr std::pair<SynthDegradation, const char*> kNames[] = {
    {SynthDegradation::kNone, "none"},
    {SynthDegradation::kTextureless, "textureless"},
    {SynthDegradation::kSpecular, "specular"},
    {SynthDegradation::kRepetitive, "repetitive"},
    {SynthDegradation::kFewViews, "few_views"},
    {SynthDegradation::kCameraNoise, "camera_noise"},
    {SynthDegradation::kImageNoise, "image_noise"},
    {SynthDegradation::kExposure, "exposure"},
    {SynthDegradation::kPoseOutliers, "pose_outliers"},
    {SynthDegradation::kHandHeld, "hand_held"},
};

// A smooth value in [0, 1] varying over about 1 / frequency scene units (sum of sines).
double Smooth(const Eigen::Vector3d& p, double frequency, uint64_t seed) {
  const double phase = static_cast<double>(seed % 1000) * 0.001 * 6.283185307;
  const double v = std::sin(frequency * 2.1 * p.x() + phase) + std::sin(frequency * 1.7 * p.y() + 2 * phase) +
                   std::sin(frequency * 2.3 * p.z() + 3 * phase) + std::sin(frequency * 1.3 * (p.x() + p.y() - p.z()));
  return 0.5 + v / 8.0;
}

}  // namespace

bool SynthDegradationFromName(const std::string& name, SynthDegradation* degradation) {
  for (const auto& [kind, text] : kNames) {
    if (name == text) {
      *degradation = kind;
      return true;
    }
  }
  return false;
}

std::string SynthDegradationName(SynthDegradation degradation) {
  for (const auto& [kind, text] : kNames) {
    if (kind == degradation) return text;
  }
  return "none";
}

std::string SynthDegradationNames() {
  std::string names;
  for (const auto& [kind, text] : kNames) names += (names.empty() ? "" : ", ") + std::string(text);
  return names;
}

int Degradation::Views(int views) const {
  if (!Active(SynthDegradation::kFewViews)) return views;
  return std::max(std::min(views, 4), static_cast<int>(std::lround(views * (1.0 - 0.75 * strength))));
}

Eigen::Vector3d Degradation::Variation(const Eigen::Vector3d& clean, const Eigen::Vector3d& point,
                                       double frequency) const {
  if (Active(SynthDegradation::kTextureless)) {
    // Patches where a smooth field is below a threshold that rises with the strength.
    const double field = Smooth(point, 0.8 * frequency, seed);
    const double threshold = 0.25 + 0.6 * strength;  // the field spans about [0.1, 0.9]
    if (field < threshold) return Eigen::Vector3d::Constant(0.6);
  }
  if (Active(SynthDegradation::kRepetitive)) {
    // Stripes across the object, 8 periods per scene unit at frequency 3: a few pixels each.
    const double stripes = 0.5 + 0.5 * std::sin(2.0 * 3.14159265 * frequency * 2.7 * (point.x() + 0.6 * point.y() + 0.3 * point.z()));
    return (1.0 - strength) * clean + strength * Eigen::Vector3d::Constant(stripes);
  }
  return clean;
}

double Degradation::Highlight(const Eigen::Vector3d& normal, const Eigen::Vector3d& light,
                              const Eigen::Vector3d& to_eye) const {
  const double scale = Active(SynthDegradation::kSpecular) ? 1.0 : Active(SynthDegradation::kHandHeld) ? 0.5 : 0.0;
  if (scale == 0.0) return 0.0;
  const Eigen::Vector3d reflected = 2.0 * normal.dot(light) * normal - light;
  return scale * strength * std::pow(std::max(0.0, reflected.dot(to_eye.normalized())), 20.0);
}

double Degradation::Gain(int index) const {
  const double range = Active(SynthDegradation::kExposure) ? 0.5 : Active(SynthDegradation::kHandHeld) ? 0.15 : 0.0;
  if (range == 0.0) return 1.0;
  const double u = static_cast<double>(synth_internal::Mix64(seed ^ (0xE4B05ull + static_cast<uint64_t>(index))) >> 11) * 0x1.0p-53;
  return 1.0 + range * strength * (2.0 * u - 1.0);
}

double Degradation::NoiseSigma() const {
  if (Active(SynthDegradation::kImageNoise)) return 24.0 * strength;
  if (Active(SynthDegradation::kHandHeld)) return 3.0 * strength;
  return 0.0;
}

Eigen::Matrix3d Degradation::AxisTurn(int index) const {
  if (!Active(SynthDegradation::kHandHeld)) return Eigen::Matrix3d::Identity();
  std::mt19937_64 rng(synth_internal::Mix64(seed ^ (0xA715ull + static_cast<uint64_t>(index))));
  std::normal_distribution<double> normal(0.0, 1.0);
  const Eigen::Vector3d axis = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
  const double angle = strength * 3.0 * M_PI / 180.0 * synth_internal::Uniform01(&rng);
  return Eigen::AngleAxisd(angle, axis).toRotationMatrix();
}

void Degradation::PerturbCameras(SparseModel* model) const {
  if (Active(SynthDegradation::kPoseOutliers)) {
    std::mt19937_64 rng(synth_internal::Mix64(seed ^ 0x9051E0u));
    std::normal_distribution<double> normal(0.0, 1.0);
    double scale = 0;  // the ring's radius, as for camera_noise
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto& [id, image] : model->images) centroid += image.Center() / model->images.size();
    for (const auto& [id, image] : model->images) scale += (image.Center() - centroid).norm() / model->images.size();
    const std::vector<int> ids = model->ImageIdsByName();
    for (size_t i = 3; i < ids.size(); i += 12) {
      Image& image = model->images.at(ids[i]);
      const Eigen::Vector3d axis = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
      const Eigen::Vector3d along = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
      const Eigen::Matrix3d turn = Eigen::AngleAxisd(strength * 5.0 * M_PI / 180.0, axis).toRotationMatrix();
      const Eigen::Vector3d center = image.Center() + strength * 0.02 * scale * along;
      const Eigen::Matrix3d rotation = turn * image.cam_from_world.R();
      image.cam_from_world = Rigid3d(rotation, -rotation * center);
    }
    return;
  }
  const bool hand_held = Active(SynthDegradation::kHandHeld);
  if (!Active(SynthDegradation::kCameraNoise) && !hand_held) return;
  // hand_held: a fiftieth of camera_noise's pose error at the same strength, the focal left exact
  // (0.02 degree: about 0.5 px at 1008 wide, near what COLMAP leaves on an LLFF capture).
  const double amount = hand_held ? 0.02 * strength : strength;
  std::mt19937_64 rng(synth_internal::Mix64(seed ^ 0xCA3E7A5ull));
  std::normal_distribution<double> normal(0.0, 1.0);
  double scale = 0;  // the ring's radius: mean camera distance from the cameras' centroid
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& [id, image] : model->images) centroid += image.Center() / model->images.size();
  for (const auto& [id, image] : model->images) scale += (image.Center() - centroid).norm() / model->images.size();
  const double rotation_sigma = amount * 1.0 * M_PI / 180.0, position_sigma = amount * 0.01 * scale;
  for (auto& [id, image] : model->images) {
    const Eigen::Vector3d axis(normal(rng), normal(rng), normal(rng));
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(rotation_sigma * axis.norm(), axis.normalized()).toRotationMatrix();
    const Eigen::Vector3d center = image.Center() + position_sigma * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
    const Eigen::Matrix3d rotation = turn * image.cam_from_world.R();
    image.cam_from_world = Rigid3d(rotation, -rotation * center);
  }
  if (hand_held) return;
  for (auto& [id, camera] : model->cameras) {
    const double gain = 1.0 + strength * 0.02 * normal(rng);
    camera.params.at(0) *= gain;  // PINHOLE fx, fy
    camera.params.at(1) *= gain;
  }
}

std::map<std::string, double> PoseDisplacementsPx(const SparseModel& truth, const SparseModel& written) {
  std::map<std::string, double> displacement;
  for (const auto& [id, image] : written.images) {
    const Image* true_image = truth.FindImage(image.name);
    double sum = 0;
    int count = 0;
    if (true_image != nullptr) {
      const Camera& true_camera = truth.CameraOf(*true_image);
      const Camera& camera = written.CameraOf(image);
      for (const Point2D& observation : true_image->points2D) {
        if (observation.point3D_id < 0) continue;
        const auto point = truth.points.find(observation.point3D_id);
        if (point == truth.points.end()) continue;
        const Eigen::Vector3d in_true = true_image->cam_from_world * point->second.xyz;
        const Eigen::Vector3d in_written = image.cam_from_world * point->second.xyz;
        if (in_true.z() <= 0 || in_written.z() <= 0) continue;
        sum += (true_camera.ImgFromCam(in_true) - camera.ImgFromCam(in_written)).norm();
        ++count;
      }
    }
    displacement[image.name] = count > 0 ? sum / count : 0.0;
  }
  return displacement;
}

}  // namespace ibmr
