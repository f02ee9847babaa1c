// Camera models with COLMAP's names, parameter order and pixel convention.
//
// Parameter order follows COLMAP (src/colmap/sensor/models.h):
//   SIMPLE_PINHOLE  f, cx, cy
//   PINHOLE         fx, fy, cx, cy
//   SIMPLE_RADIAL   f, cx, cy, k
//   RADIAL          f, cx, cy, k1, k2
//   OPENCV          fx, fy, cx, cy, k1, k2, p1, p2
//   FULL_OPENCV     fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6
// Pixel convention (COLMAP): the centre of the top-left pixel is at (0.5, 0.5), so a pixel
// (col, row) of an image covers [col, col+1) x [row, row+1). Middlebury and Strecha files put the
// centre at (0, 0): their importers add 0.5 to the principal point (see import stage).
// Distortion acts on normalised coordinates (x/z, y/z) exactly as OpenCV's projectPoints with
// the distortion vector (k1, k2, p1, p2[, k3, k4, k5, k6]): the rational radial factor
// (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6) and the tangential terms, which
// the tests check.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace ibmr {

enum class CameraModelId { kSimplePinhole, kPinhole, kSimpleRadial, kRadial, kOpenCV, kFullOpenCV };

// "PINHOLE" -> kPinhole. Returns false for an unknown name.
bool CameraModelFromName(const std::string& name, CameraModelId* model);
std::string CameraModelName(CameraModelId model);
// Number of parameters of a model (3, 4, 4, 5, 8, 12).
int CameraModelNumParams(CameraModelId model);

struct Camera {
  int camera_id = 1;
  CameraModelId model = CameraModelId::kPinhole;
  int width = 0;   // pixels
  int height = 0;  // pixels
  std::vector<double> params;  // COLMAP order, see above

  // Builders for the common cases.
  static Camera Pinhole(int width, int height, double fx, double fy, double cx, double cy);

  double FocalX() const;
  double FocalY() const;
  double PrincipalX() const;
  double PrincipalY() const;
  // Calibration matrix (no distortion), COLMAP pixel convention.
  Eigen::Matrix3d K() const;
  bool HasDistortion() const;

  // Applies the lens distortion to normalised coordinates (x/z, y/z).
  Eigen::Vector2d Distort(const Eigen::Vector2d& normalized) const;
  // Inverse of Distort by Newton iteration (exact for pinhole models).
  Eigen::Vector2d Undistort(const Eigen::Vector2d& distorted) const;

  // Camera-frame point (z > 0 in front) to pixel coordinates, with distortion.
  Eigen::Vector2d ImgFromCam(const Eigen::Vector3d& point_in_cam) const;
  // Pixel coordinates to the normalised undistorted ray direction (x, y, 1).
  Eigen::Vector3d CamFromImg(const Eigen::Vector2d& pixel) const;

  // The same camera with distortion removed (PINHOLE, or SIMPLE_PINHOLE when fx == fy).
  Camera Undistorted() const;
  // Scales the image size and intrinsics by `factor` (e.g. 0.5 for half resolution).
  Camera Scaled(double factor) const;

  // Empty when valid; otherwise says what is wrong (parameter count, size, focal length).
  std::string Validate() const;
};

}  // namespace ibmr
