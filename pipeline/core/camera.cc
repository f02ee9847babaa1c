// Camera models with COLMAP's names and parameter order: intrinsics access, projection and
// back-projection, and the (k1, k2, p1, p2) lens distortion of OpenCV's projectPoints with its
// Newton inverse. See camera.h for the pixel convention.
#include "pipeline/core/camera.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>
#include <sstream>

namespace ibmr {
namespace {

struct ModelInfo {
  CameraModelId id;
  const char* name;
  int num_params;
  const char* param_names;
};

constexpr std::array<ModelInfo, 6> kModels = {{
    {CameraModelId::kSimplePinhole, "SIMPLE_PINHOLE", 3, "f, cx, cy"},
    {CameraModelId::kPinhole, "PINHOLE", 4, "fx, fy, cx, cy"},
    {CameraModelId::kSimpleRadial, "SIMPLE_RADIAL", 4, "f, cx, cy, k"},
    {CameraModelId::kRadial, "RADIAL", 5, "f, cx, cy, k1, k2"},
    {CameraModelId::kOpenCV, "OPENCV", 8, "fx, fy, cx, cy, k1, k2, p1, p2"},
    {CameraModelId::kFullOpenCV, "FULL_OPENCV", 12, "fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6"},
}};

const ModelInfo* FindModel(CameraModelId model) {
  for (const ModelInfo& info : kModels) {
    if (info.id == model) return &info;
  }
  return nullptr;
}

// Models with one focal length store it once: f, cx, cy, ...
bool HasSingleFocal(CameraModelId model) {
  return model == CameraModelId::kSimplePinhole || model == CameraModelId::kSimpleRadial ||
         model == CameraModelId::kRadial;
}

int PrincipalIndex(CameraModelId model) { return HasSingleFocal(model) ? 1 : 2; }

// Distortion coefficients in OpenCV's (k1, k2, p1, p2, k3, k4, k5, k6) layout; zero for missing
// terms.
struct Coefficients {
  double k1 = 0, k2 = 0, p1 = 0, p2 = 0, k3 = 0, k4 = 0, k5 = 0, k6 = 0;
  bool Any() const { return k1 != 0 || k2 != 0 || p1 != 0 || p2 != 0 || k3 != 0 || k4 != 0 || k5 != 0 || k6 != 0; }
};

// The rational radial factor at r2 = r^2 and its derivative with respect to r2.
double RadialFactor(const Coefficients& c, double r2, double* derivative = nullptr) {
  const double numerator = 1.0 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3));
  const double denominator = 1.0 + r2 * (c.k4 + r2 * (c.k5 + r2 * c.k6));
  if (derivative) {
    const double d_numerator = c.k1 + r2 * (2.0 * c.k2 + 3.0 * c.k3 * r2);
    const double d_denominator = c.k4 + r2 * (2.0 * c.k5 + 3.0 * c.k6 * r2);
    *derivative = (d_numerator * denominator - numerator * d_denominator) / (denominator * denominator);
  }
  return numerator / denominator;
}

Coefficients CoefficientsOf(const Camera& camera) {
  const std::vector<double>& p = camera.params;
  Coefficients c;
  switch (camera.model) {
    case CameraModelId::kSimpleRadial:
      c.k1 = p.at(3);
      break;
    case CameraModelId::kRadial:
      c.k1 = p.at(3);
      c.k2 = p.at(4);
      break;
    case CameraModelId::kOpenCV:
    case CameraModelId::kFullOpenCV:
      c.k1 = p.at(4);
      c.k2 = p.at(5);
      c.p1 = p.at(6);
      c.p2 = p.at(7);
      if (camera.model == CameraModelId::kFullOpenCV) {
        c.k3 = p.at(8);
        c.k4 = p.at(9);
        c.k5 = p.at(10);
        c.k6 = p.at(11);
      }
      break;
    default:
      break;
  }
  return c;
}

// OpenCV's model (cv::projectPoints, rational radial factor, no thin-prism or tilt terms) on
// normalised coordinates.
Eigen::Vector2d ApplyDistortion(const Coefficients& c, const Eigen::Vector2d& u) {
  const double x = u.x(), y = u.y();
  const double r2 = x * x + y * y;
  const double radial = RadialFactor(c, r2);
  return {x * radial + 2.0 * c.p1 * x * y + c.p2 * (r2 + 2.0 * x * x),
          y * radial + c.p1 * (r2 + 2.0 * y * y) + 2.0 * c.p2 * x * y};
}

// Jacobian of ApplyDistortion with respect to the undistorted point.
Eigen::Matrix2d DistortionJacobian(const Coefficients& c, const Eigen::Vector2d& u) {
  const double x = u.x(), y = u.y();
  const double r2 = x * x + y * y;
  double d_radial_d_r2 = 0;  // d(r2)/dx = 2x, d(r2)/dy = 2y
  const double radial = RadialFactor(c, r2, &d_radial_d_r2);
  Eigen::Matrix2d j;
  j(0, 0) = radial + 2.0 * x * x * d_radial_d_r2 + 2.0 * c.p1 * y + 6.0 * c.p2 * x;
  j(0, 1) = 2.0 * x * y * d_radial_d_r2 + 2.0 * c.p1 * x + 2.0 * c.p2 * y;
  j(1, 0) = 2.0 * x * y * d_radial_d_r2 + 2.0 * c.p1 * x + 2.0 * c.p2 * y;
  j(1, 1) = radial + 2.0 * y * y * d_radial_d_r2 + 6.0 * c.p1 * y + 2.0 * c.p2 * x;
  return j;
}

// Fixed-point scheme of cv::undistortPoints: u = (d - tangential(u)) / radial(u). Slower than
// Newton but robust where the Jacobian is near singular.
Eigen::Vector2d UndistortFixedPoint(const Coefficients& c, const Eigen::Vector2d& distorted) {
  Eigen::Vector2d u = distorted;
  for (int i = 0; i < 200; ++i) {
    const double x = u.x(), y = u.y();
    const double r2 = x * x + y * y;
    const double radial = RadialFactor(c, r2);
    if (!(std::abs(radial) > 1e-12) || !std::isfinite(radial)) break;
    const Eigen::Vector2d tangential(2.0 * c.p1 * x * y + c.p2 * (r2 + 2.0 * x * x),
                                     c.p1 * (r2 + 2.0 * y * y) + 2.0 * c.p2 * x * y);
    const Eigen::Vector2d next = (distorted - tangential) / radial;
    if (!next.allFinite()) break;
    const bool converged = (next - u).norm() < 1e-15;
    u = next;
    if (converged) break;
  }
  return u;
}

// Newton iteration with step halving; falls back to the fixed-point scheme when Newton stalls.
Eigen::Vector2d InvertDistortion(const Coefficients& c, const Eigen::Vector2d& distorted) {
  constexpr double kTolerance = 1e-12;
  Eigen::Vector2d u = distorted;
  double residual = (ApplyDistortion(c, u) - distorted).norm();
  for (int i = 0; i < 100 && residual > 1e-15; ++i) {
    const Eigen::Matrix2d j = DistortionJacobian(c, u);
    if (!(std::abs(j.determinant()) > 1e-12)) break;
    const Eigen::Vector2d step = j.inverse() * (ApplyDistortion(c, u) - distorted);
    double scale = 1.0;
    bool improved = false;
    for (int halvings = 0; halvings < 30 && !improved; ++halvings, scale *= 0.5) {
      const Eigen::Vector2d candidate = u - scale * step;
      const double candidate_residual = (ApplyDistortion(c, candidate) - distorted).norm();
      if (candidate.allFinite() && candidate_residual < residual) {
        u = candidate;
        residual = candidate_residual;
        improved = true;
      }
    }
    if (!improved || step.norm() < 1e-16) break;
  }
  if (residual <= kTolerance) return u;
  const Eigen::Vector2d fallback = UndistortFixedPoint(c, distorted);
  const double fallback_residual = (ApplyDistortion(c, fallback) - distorted).norm();
  if (fallback.allFinite() && fallback_residual < residual) return fallback;
  return u.allFinite() ? u : distorted;
}

}  // namespace

bool CameraModelFromName(const std::string& name, CameraModelId* model) {
  for (const ModelInfo& info : kModels) {
    if (name == info.name) {
      *model = info.id;
      return true;
    }
  }
  return false;
}

std::string CameraModelName(CameraModelId model) {
  const ModelInfo* info = FindModel(model);
  return info ? info->name : "UNKNOWN";
}

int CameraModelNumParams(CameraModelId model) {
  const ModelInfo* info = FindModel(model);
  return info ? info->num_params : 0;
}

Camera Camera::Pinhole(int width, int height, double fx, double fy, double cx, double cy) {
  Camera camera;
  camera.model = CameraModelId::kPinhole;
  camera.width = width;
  camera.height = height;
  camera.params = {fx, fy, cx, cy};
  return camera;
}

double Camera::FocalX() const { return params.at(0); }
double Camera::FocalY() const { return HasSingleFocal(model) ? params.at(0) : params.at(1); }
double Camera::PrincipalX() const { return params.at(PrincipalIndex(model)); }
double Camera::PrincipalY() const { return params.at(PrincipalIndex(model) + 1); }

Eigen::Matrix3d Camera::K() const {
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();
  k(0, 0) = FocalX();
  k(1, 1) = FocalY();
  k(0, 2) = PrincipalX();
  k(1, 2) = PrincipalY();
  return k;
}

bool Camera::HasDistortion() const { return CoefficientsOf(*this).Any(); }

Eigen::Vector2d Camera::Distort(const Eigen::Vector2d& normalized) const {
  if (!HasDistortion()) return normalized;
  return ApplyDistortion(CoefficientsOf(*this), normalized);
}

Eigen::Vector2d Camera::Undistort(const Eigen::Vector2d& distorted) const {
  if (!HasDistortion()) return distorted;
  return InvertDistortion(CoefficientsOf(*this), distorted);
}

Eigen::Vector2d Camera::ImgFromCam(const Eigen::Vector3d& point_in_cam) const {
  const Eigen::Vector2d d = Distort(point_in_cam.hnormalized());
  return {FocalX() * d.x() + PrincipalX(), FocalY() * d.y() + PrincipalY()};
}

Eigen::Vector3d Camera::CamFromImg(const Eigen::Vector2d& pixel) const {
  const Eigen::Vector2d d((pixel.x() - PrincipalX()) / FocalX(),
                          (pixel.y() - PrincipalY()) / FocalY());
  return Undistort(d).homogeneous();
}

// Pinhole cameras come back unchanged; distorted ones become SIMPLE_PINHOLE when fx == fy
// (always so for the single-focal models), else PINHOLE. Size and K are kept.
Camera Camera::Undistorted() const {
  if (model == CameraModelId::kSimplePinhole || model == CameraModelId::kPinhole) return *this;
  Camera camera = *this;
  if (FocalX() == FocalY()) {
    camera.model = CameraModelId::kSimplePinhole;
    camera.params = {FocalX(), PrincipalX(), PrincipalY()};
  } else {
    camera.model = CameraModelId::kPinhole;
    camera.params = {FocalX(), FocalY(), PrincipalX(), PrincipalY()};
  }
  return camera;
}

// As COLMAP's Camera::Rescale: the size is rounded, and the intrinsics are scaled by the ratio
// of the rounded sizes so that pixel edges (0 and width) still map onto each other. With the
// (0.5, 0.5) pixel-centre convention this makes cx scale exactly like f. Distortion acts on
// normalised coordinates and is unchanged.
Camera Camera::Scaled(double factor) const {
  Camera camera = *this;
  camera.width = std::max(1, static_cast<int>(std::lround(width * factor)));
  camera.height = std::max(1, static_cast<int>(std::lround(height * factor)));
  const double scale_x = width > 0 ? static_cast<double>(camera.width) / width : factor;
  const double scale_y = height > 0 ? static_cast<double>(camera.height) / height : factor;
  const int principal = PrincipalIndex(model);
  if (HasSingleFocal(model)) {
    camera.params.at(0) *= 0.5 * (scale_x + scale_y);
  } else {
    camera.params.at(0) *= scale_x;
    camera.params.at(1) *= scale_y;
  }
  camera.params.at(principal) *= scale_x;
  camera.params.at(principal + 1) *= scale_y;
  return camera;
}

std::string Camera::Validate() const {
  std::ostringstream error;
  error << "camera " << camera_id << ": ";
  const ModelInfo* info = FindModel(model);
  if (info == nullptr) {
    error << "unknown camera model id " << static_cast<int>(model);
    return error.str();
  }
  if (static_cast<int>(params.size()) != info->num_params) {
    error << "model " << info->name << " needs " << info->num_params << " parameters ("
          << info->param_names << "), got " << params.size();
  } else if (width <= 0 || height <= 0) {
    error << "image size must be positive, got " << width << "x" << height;
  } else if (!std::all_of(params.begin(), params.end(), [](double v) { return std::isfinite(v); })) {
    error << "parameters must be finite numbers";
  } else if (!(FocalX() > 0) || !(FocalY() > 0)) {
    error << "focal length must be positive, got fx=" << FocalX() << " fy=" << FocalY();
  } else {
    return "";
  }
  return error.str();
}

}  // namespace ibmr
