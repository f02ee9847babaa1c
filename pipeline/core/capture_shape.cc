// Capture shape analysis (see capture_shape.h).
#include "pipeline/core/capture_shape.h"

#include <fmt/format.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <vector>

#include "pipeline/core/errors.h"
#include "pipeline/core/optical_axes.h"

namespace ibmr {
namespace {

constexpr double kPi = 3.14159265358979323846;

double Degrees(double radians) { return radians * 180.0 / kPi; }

// The q-quantile of `values` (sorted here), nearest rank.
double Quantile(std::vector<double> values, double q) {
  std::sort(values.begin(), values.end());
  const size_t index = std::min(values.size() - 1, static_cast<size_t>(std::floor(q * (values.size() - 1) + 0.5)));
  return values[index];
}

// 360 minus the largest gap between the azimuths of `directions` about `axis` (all unit).
double SurroundDegrees(const std::vector<Eigen::Vector3d>& directions, const Eigen::Vector3d& axis) {
  const Eigen::Vector3d u = axis.unitOrthogonal();
  const Eigen::Vector3d w = axis.cross(u);
  std::vector<double> azimuths;
  for (const Eigen::Vector3d& d : directions) {
    const Eigen::Vector3d in_plane = d - d.dot(axis) * axis;
    if (in_plane.norm() < 1e-9) continue;  // on the axis: no azimuth
    azimuths.push_back(std::atan2(in_plane.dot(w), in_plane.dot(u)));
  }
  if (azimuths.size() < 2) return 0;
  std::sort(azimuths.begin(), azimuths.end());
  double largest_gap = azimuths.front() + 2 * kPi - azimuths.back();
  for (size_t i = 1; i < azimuths.size(); ++i) largest_gap = std::max(largest_gap, azimuths[i] - azimuths[i - 1]);
  return Degrees(2 * kPi - largest_gap);
}

}  // namespace

std::string FindModelFolder(const std::string& path) {
  const std::vector<std::string> candidates = {path, path + "/dense/sparse", path + "/sfm/sparse", path + "/sparse"};
  for (const std::string& folder : candidates) {
    if (std::filesystem::exists(folder + "/images.txt")) return folder;
  }
  throw InputError(path + ": no model (images.txt) here nor in dense/sparse, sfm/sparse or sparse; run import or sfm "
                   "first, or give a folder with cameras.txt and images.txt");
}

bool IsCaptureKind(const std::string& kind) {
  for (const char* k : kCaptureKinds) {
    if (kind == k) return true;
  }
  return false;
}

CaptureShape AnalyseCapture(const SparseModel& model, bool has_alpha, const CaptureShapeOptions& options) {
  CaptureShape shape;
  shape.silhouettes = has_alpha;
  std::vector<Eigen::Vector3d> centres, axes;
  for (const auto& [id, image] : model.images) {
    centres.push_back(image.Center());
    axes.push_back(image.ViewingDirection().normalized());
  }
  shape.views = static_cast<int>(centres.size());
  if (centres.size() < 2) {
    shape.reason = "fewer than 2 posed views";
    return shape;
  }

  // Spread of the axes about their mean.
  Eigen::Vector3d mean_axis = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& a : axes) mean_axis += a;
  std::vector<double> angles;
  if (mean_axis.norm() < 1e-9) {
    angles.assign(axes.size(), 180.0);  // axes cancel out: every direction
  } else {
    mean_axis.normalize();
    for (const Eigen::Vector3d& a : axes) angles.push_back(Degrees(std::acos(std::clamp(a.dot(mean_axis), -1.0, 1.0))));
  }
  shape.axis_spread_deg = Quantile(angles, 0.9);
  shape.axis_spread_max_deg = *std::max_element(angles.begin(), angles.end());

  // Diameter of the centres.
  double diameter = 0;
  for (size_t i = 0; i < centres.size(); ++i) {
    for (size_t j = i + 1; j < centres.size(); ++j) diameter = std::max(diameter, (centres[i] - centres[j]).norm());
  }

  // Depths of the sparse points in the views that observe them (every view in front of a point
  // when tracks are empty), at most about 200k samples.
  std::vector<double> depths;
  const size_t stride = std::max<size_t>(1, model.points.size() / 50000);
  size_t index = 0;
  for (const auto& entry : model.points) {  // not a structured binding: a lambda captures `point`
    const Point3D& point = entry.second;
    if (index++ % stride != 0) continue;
    auto add = [&](const Image& image) {
      const double z = (image.cam_from_world * point.xyz).z();
      if (z > 0 && std::isfinite(z)) depths.push_back(z);
    };
    if (!point.track.empty()) {
      for (size_t t = 0; t < point.track.size() && t < 4; ++t) {
        const auto found = model.images.find(point.track[t].image_id);
        if (found != model.images.end()) add(found->second);
      }
    } else {
      int n = 0;
      for (const auto& [image_id, image] : model.images) {
        if (n++ >= 4) break;
        add(image);
      }
    }
  }
  if (depths.size() >= 10) {
    shape.near_depth = Quantile(depths, 0.05);
    shape.far_depth = Quantile(depths, 0.95);
    if (*shape.near_depth > 0) shape.baseline_over_near = diameter / *shape.near_depth;
  }

  // Convergence of the axes.
  Eigen::Vector3d point;
  if (PointNearestToAxes(centres, axes, &point)) {
    shape.converges = true;
    std::vector<double> axis_distances, camera_distances;
    std::vector<Eigen::Vector3d> outward;  // from the point to each camera
    int in_front = 0;
    for (size_t i = 0; i < centres.size(); ++i) {
      const Eigen::Vector3d to_point = point - centres[i];
      const double along = to_point.dot(axes[i]);
      if (along > 0) ++in_front;
      axis_distances.push_back((to_point - along * axes[i]).norm());
      camera_distances.push_back(to_point.norm());
      if (to_point.norm() > 1e-12) outward.push_back(-to_point.normalized());
    }
    const double median_camera = Quantile(camera_distances, 0.5);
    shape.convergence_residual = median_camera > 0 ? Quantile(axis_distances, 0.5) / median_camera : 1.0;
    shape.in_front = static_cast<double>(in_front) / centres.size();
    if (outward.size() >= 2) {
      // The ring's axis: the direction the outward vectors vary least along.
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (const Eigen::Vector3d& d : outward) mean += d;
      mean /= static_cast<double>(outward.size());
      Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
      for (const Eigen::Vector3d& d : outward) covariance += (d - mean) * (d - mean).transpose();
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
      shape.surround_deg = SurroundDegrees(outward, solver.eigenvectors().col(0).normalized());
    }
  }

  const bool narrow = shape.axis_spread_deg <= options.forward_max_spread_deg;
  const bool small_baseline =
      !shape.baseline_over_near || *shape.baseline_over_near <= options.forward_max_baseline_over_near;
  const bool surrounds = shape.converges && shape.in_front >= options.object_min_in_front &&
                         shape.convergence_residual <= options.object_max_residual &&
                         shape.surround_deg >= options.object_min_surround_deg;
  if (narrow && small_baseline) {
    shape.kind = "forward_facing";
  } else if (surrounds) {
    shape.kind = "object";
  } else {
    shape.kind = "general";
  }
  shape.reason = shape.Describe();
  return shape;
}

std::string CaptureShape::Describe() const {
  if (kind.empty()) return "unknown (" + (reason.empty() ? std::string("no posed views") : reason) + ")";
  std::string text = fmt::format("{} ({}{} views; axis spread {:.0f} deg", kind,
                                 set_by.empty() ? std::string() : "set by " + set_by + "; ", views, axis_spread_deg);
  text += baseline_over_near ? fmt::format(", baseline over near depth {:.2f}", *baseline_over_near)
                             : std::string(", no points for the depth range");
  if (converges) {
    text += fmt::format(", axes converge with residual {:.2f}, {:.0f}% looking at the point, cameras {:.0f} deg round it",
                        convergence_residual, 100 * in_front, surround_deg);
  } else {
    text += ", axes do not converge";
  }
  return text + ")";
}

nlohmann::json CaptureShape::ToJson() const {
  nlohmann::json json = {{"kind", kind},
                         {"reason", reason},
                         {"views", views},
                         {"axis_spread_deg", axis_spread_deg},
                         {"axis_spread_max_deg", axis_spread_max_deg},
                         {"baseline_over_near", baseline_over_near ? nlohmann::json(*baseline_over_near) : nlohmann::json()},
                         {"depth_range", near_depth ? nlohmann::json::array({*near_depth, *far_depth}) : nlohmann::json()},
                         {"convergence",
                          {{"converges", converges},
                           {"residual", convergence_residual},
                           {"in_front", in_front},
                           {"surround_deg", surround_deg}}},
                         {"silhouettes", silhouettes}};
  if (!set_by.empty()) json["set_by"] = set_by;
  return json;
}

CaptureShape CaptureShape::FromJson(const nlohmann::json& json) {
  CaptureShape shape;
  shape.kind = json.value("kind", std::string());
  shape.reason = json.value("reason", std::string());
  shape.views = json.value("views", 0);
  shape.axis_spread_deg = json.value("axis_spread_deg", 0.0);
  shape.axis_spread_max_deg = json.value("axis_spread_max_deg", 0.0);
  if (json.contains("baseline_over_near") && json["baseline_over_near"].is_number()) {
    shape.baseline_over_near = json["baseline_over_near"].get<double>();
  }
  if (json.contains("depth_range") && json["depth_range"].is_array() && json["depth_range"].size() == 2) {
    shape.near_depth = json["depth_range"][0].get<double>();
    shape.far_depth = json["depth_range"][1].get<double>();
  }
  if (json.contains("convergence") && json["convergence"].is_object()) {
    const nlohmann::json& c = json["convergence"];
    shape.converges = c.value("converges", false);
    shape.convergence_residual = c.value("residual", 0.0);
    shape.in_front = c.value("in_front", 0.0);
    shape.surround_deg = c.value("surround_deg", 0.0);
  }
  shape.silhouettes = json.value("silhouettes", false);
  shape.set_by = json.value("set_by", std::string());
  return shape;
}

}  // namespace ibmr
