// The volume stage's driver (volume.h): options, the virtual camera and its planes, the pyramid,
// phase 1 at the coarsest level and phase 2 from coarse to fine.
#include "stages/volume/volume.h"

#include <Eigen/SVD>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "pipeline/core/plane_homography.h"

namespace ibmr {

bool VolumeOptions::Check(std::string* error) const {
  auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (num_planes < 2 || num_planes > 256) return fail("num_planes: must be in [2, 256], got " + std::to_string(num_planes));
  if (!(resolution > 0 && resolution <= 4)) return fail("resolution: must be in (0, 4], got " + std::to_string(resolution));
  if (!(max_widen >= 1 && max_widen <= 4)) return fail("max_widen: must be in [1, 4], got " + std::to_string(max_widen));
  if (window_radius < 0 || window_radius > 16) return fail("window_radius: must be in [0, 16], got " + std::to_string(window_radius));
  if (!(vote_temperature >= 0)) return fail("vote_temperature: must be >= 0, got " + std::to_string(vote_temperature));
  if (visibility_rounds < 0 || visibility_rounds > 5) return fail("visibility_rounds: must be in [0, 5], got " + std::to_string(visibility_rounds));
  if (levels < 1 || levels > 6) return fail("levels: must be in [1, 6], got " + std::to_string(levels));
  if (iterations < 0 || iterations > 100000) return fail("iterations: must be in [0, 100000], got " + std::to_string(iterations));
  if (min_iterations < 0 || min_iterations > 100000) return fail("min_iterations: must be in [0, 100000], got " + std::to_string(min_iterations));
  if (views_per_step < 0 || views_per_step > 10000) return fail("views_per_step: must be in [0, 10000], got " + std::to_string(views_per_step));
  if (!(learning_rate > 0)) return fail("learning_rate: must be > 0, got " + std::to_string(learning_rate));
  if (!(robust_epsilon > 0)) return fail("robust_epsilon: must be > 0, got " + std::to_string(robust_epsilon));
  if (!(smoothness >= 0)) return fail("smoothness: must be >= 0, got " + std::to_string(smoothness));
  if (!(opacity_prior >= 0)) return fail("opacity_prior: must be >= 0, got " + std::to_string(opacity_prior));
  if (!(max_memory_mb > 0)) return fail("max_memory_mb: must be > 0, got " + std::to_string(max_memory_mb));
  return true;
}

std::vector<double> PlaneDepths(double near, double far, int planes) {
  // InverseDepthPlanes counts from the far plane; the volume lists its planes nearest first.
  const InverseDepthPlanes sweep{near, far, planes};
  std::vector<double> depths(planes);
  for (int k = 0; k < planes; ++k) depths[k] = sweep.Depth(planes - 1 - k);
  depths.front() = near;
  depths.back() = far;
  return depths;
}

VirtualCamera ChooseVirtualCamera(const std::vector<VolumeView>& views, int reference, double near, double far,
                                  const VolumeOptions& options) {
  if (views.empty()) throw std::invalid_argument("ChooseVirtualCamera: no views");
  if (!(near > 0 && far > near)) throw std::invalid_argument("ChooseVirtualCamera: needs 0 < near < far");
  if (reference >= static_cast<int>(views.size())) throw std::invalid_argument("ChooseVirtualCamera: no such reference view");
  VirtualCamera virtual_camera;
  virtual_camera.near = near;
  virtual_camera.far = far;
  double fx = 0, fy = 0, width = 0, height = 0;
  for (const VolumeView& view : views) {
    fx += view.camera.FocalX() / views.size();
    fy += view.camera.FocalY() / views.size();
    width += static_cast<double>(view.camera.width) / views.size();
    height += static_cast<double>(view.camera.height) / views.size();
  }
  if (reference >= 0) {
    virtual_camera.cam_from_world = views[reference].cam_from_world;
  } else {
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    Eigen::Matrix3d rotation_sum = Eigen::Matrix3d::Zero();
    for (const VolumeView& view : views) {
      centre += view.cam_from_world.Inverse().translation / static_cast<double>(views.size());
      rotation_sum += view.cam_from_world.R();
    }
    // The rotation nearest (Frobenius) to the mean matrix: U V^T of its SVD, with det +1.
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(rotation_sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
    d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
    const Eigen::Matrix3d rotation = svd.matrixU() * d * svd.matrixV().transpose();
    virtual_camera.cam_from_world = Rigid3d(rotation, -(rotation * centre));
  }
  fx *= options.resolution;
  fy *= options.resolution;
  // The training views' image corners at the near and far depth, seen by the virtual camera.
  double u_min = 0, u_max = width * options.resolution, v_min = 0, v_max = height * options.resolution;
  const double cx = 0.5 * width * options.resolution, cy = 0.5 * height * options.resolution;
  for (const VolumeView& view : views) {
    const Rigid3d world_from_view = view.cam_from_world.Inverse();
    const Eigen::Matrix3d k_inv = view.camera.K().inverse();
    for (const double z : {near, far}) {
      for (const auto& corner : {Eigen::Vector2d(0, 0), Eigen::Vector2d(view.camera.width, 0),
                                 Eigen::Vector2d(0, view.camera.height),
                                 Eigen::Vector2d(view.camera.width, view.camera.height)}) {
        const Eigen::Vector3d point = virtual_camera.cam_from_world * (world_from_view * (z * (k_inv * corner.homogeneous())));
        if (!(point.z() > 1e-9)) continue;
        u_min = std::min(u_min, fx * point.x() / point.z() + cx);
        u_max = std::max(u_max, fx * point.x() / point.z() + cx);
        v_min = std::min(v_min, fy * point.y() / point.z() + cy);
        v_max = std::max(v_max, fy * point.y() / point.z() + cy);
      }
    }
  }
  // Widen at most max_widen times, symmetrically limited on each side.
  const double extra_u = (options.max_widen - 1) * width * options.resolution / 2;
  const double extra_v = (options.max_widen - 1) * height * options.resolution / 2;
  u_min = std::max(u_min, -extra_u);
  v_min = std::max(v_min, -extra_v);
  u_max = std::min(u_max, width * options.resolution + extra_u);
  v_max = std::min(v_max, height * options.resolution + extra_v);
  const int out_width = std::max(2, static_cast<int>(std::ceil(u_max - std::floor(u_min))));
  const int out_height = std::max(2, static_cast<int>(std::ceil(v_max - std::floor(v_min))));
  virtual_camera.camera =
      Camera::Pinhole(out_width, out_height, fx, fy, cx - std::floor(u_min), cy - std::floor(v_min));
  return virtual_camera;
}

double VolumeFitBytes(const VirtualCamera& virtual_camera, const std::vector<VolumeView>& views,
                      const VolumeOptions& options) {
  const double cells = static_cast<double>(virtual_camera.camera.width) * virtual_camera.camera.height *
                       options.num_planes * 4;
  const double buffers = options.optimizer == VolumeOptimizer::kAdam ? 4 : 2;  // cells, gradient (, two moments)
  double photos = 0;
  for (const VolumeView& view : views) photos += static_cast<double>(view.camera.width) * view.camera.height * 3 * 4;
  const double bands = static_cast<double>(kVolumeBandFloats) * sizeof(float);
  return cells * 4 * buffers + photos + bands;
}

std::vector<LevelView> LevelViews(const std::vector<VolumeView>& views, double scale) {
  std::vector<LevelView> level(views.size());
  for (size_t i = 0; i < views.size(); ++i) {
    level[i].camera = views[i].camera.Scaled(scale);
    level[i].cam_from_world = views[i].cam_from_world;
    cv::Mat resized;
    if (level[i].camera.width == views[i].image.cols && level[i].camera.height == views[i].image.rows) {
      resized = views[i].image;
    } else {
      cv::resize(views[i].image, resized, cv::Size(level[i].camera.width, level[i].camera.height), 0, 0, cv::INTER_AREA);
    }
    resized.convertTo(level[i].image, CV_32FC3, 1.0 / 255.0);
  }
  return level;
}

namespace {

// The volume's empty shell at pyramid scale `scale` of the virtual camera.
PlaneVolume ShellAt(const VirtualCamera& virtual_camera, const std::vector<double>& depths, double scale) {
  PlaneVolume volume;
  volume.camera = virtual_camera.camera.Scaled(scale);
  volume.cam_from_world = virtual_camera.cam_from_world;
  volume.depths = depths;
  volume.Allocate();
  return volume;
}

// `coarse`'s planes resized bilinearly into `fine`'s size.
void Upsample(const PlaneVolume& coarse, PlaneVolume* fine) {
  for (int k = 0; k < coarse.Planes(); ++k) {
    const cv::Mat from(coarse.Height(), coarse.Width(), CV_32FC4, const_cast<float*>(coarse.Plane(k)));
    cv::Mat to(fine->Height(), fine->Width(), CV_32FC4, fine->Plane(k));
    cv::resize(from, to, to.size(), 0, 0, cv::INTER_LINEAR);
  }
}

}  // namespace

VolumeResult FitPlaneVolume(const std::vector<VolumeView>& views, const VirtualCamera& virtual_camera,
                            const VolumeOptions& options, ProgressReporter* progress) {
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument("volume: " + error);
  if (views.size() < 2) throw std::invalid_argument("volume: needs at least 2 training views");
  for (const VolumeView& view : views) {
    if (view.camera.HasDistortion()) throw std::invalid_argument("volume: view " + view.name + " is not undistorted");
    if (view.image.cols != view.camera.width || view.image.rows != view.camera.height || view.image.type() != CV_8UC3) {
      throw std::invalid_argument("volume: view " + view.name + "'s photo is not an 8-bit colour image of its camera's size");
    }
  }
  NullProgress null_progress;
  if (progress == nullptr) progress = &null_progress;
  VolumeResult result;
  const std::vector<double> depths = PlaneDepths(virtual_camera.near, virtual_camera.far, options.num_planes);
  std::vector<int> iterations(options.levels);
  for (int level = 0; level < options.levels; ++level) {
    iterations[level] = std::max(options.min_iterations, options.iterations >> level);
  }
  const auto start = std::chrono::steady_clock::now();
  auto seconds_since = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  PlaneVolume volume;
  for (int level = 0; level < options.levels; ++level) {
    const double scale = std::ldexp(1.0, -(options.levels - 1 - level));
    const std::vector<LevelView> level_views = LevelViews(views, scale);
    PlaneVolume shell = ShellAt(virtual_camera, depths, scale);
    if (level == 0) {
      progress->Begin("volume: initial sweep", 1);
      InitializeVolume(level_views, options, &shell);
      progress->Advance(1);
      progress->End();
      result.init_seconds = seconds_since(start);
    } else {
      Upsample(volume, &shell);
    }
    volume = std::move(shell);
    if (level == options.levels - 1) {
      double data = 0;
      VolumeObjective(volume, level_views, options, nullptr, &data);
      result.initial_data = data;
    }
    progress->Begin("volume: fitting level " + std::to_string(level + 1) + "/" + std::to_string(options.levels),
                    iterations[level]);
    RefineVolume(level_views, options, level, iterations[level], &volume, &result.curve, progress);
    progress->End();
  }
  result.final_data = result.curve.empty() ? 0 : result.curve.back().data;
  result.fit_seconds = seconds_since(start) - result.init_seconds;
  result.volume = std::move(volume);
  return result;
}

}  // namespace ibmr
