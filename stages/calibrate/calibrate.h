// Planar-target camera calibration (Zhang's method through OpenCV), after seed 000 lines 3469-3510
// (camera calibration from known 3D points: forward projection equations, internal and external
// parameters) and 4788-4830 (§8: calibrate the intrinsics first with a target, then recover poses).
// Detects a chessboard or a (symmetric / asymmetric) circle grid in each view, refines corners to
// sub-pixel accuracy, runs cv::calibrateCamera with the chosen distortion model, measures each
// view's RMS reprojection error and rejects views whose error is an outlier (then calibrates again),
// keeping the reason for every rejected view.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/progress.h"

namespace ibmr {

enum class CalibrationPattern { kChessboard, kCircles, kAsymmetricCircles };

// Distortion model, named as COLMAP's camera models:
//   PINHOLE      fx, fy, cx, cy, no distortion
//   SIMPLE_RADIAL f, cx, cy, k1 (aspect ratio fixed to 1)
//   RADIAL       f, cx, cy, k1, k2 (aspect ratio fixed to 1)
//   OPENCV       fx, fy, cx, cy, k1, k2, p1, p2
//   FULL_OPENCV  fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6 (k3 fitted, k4..k6 zero: OpenCV's
//                default 5-coefficient model)
enum class DistortionModel { kPinhole, kSimpleRadial, kRadial, kOpenCV, kFullOpenCV };

struct CalibrateOptions {
  CalibrationPattern pattern = CalibrationPattern::kChessboard;
  int pattern_cols = 9;        // inner corners (or circles) per row; >= 2
  int pattern_rows = 6;        // inner corners (or circles) per column; >= 2
  double square_size = 0.025;  // target units (metres) between neighbouring corners / circle centres; > 0
  DistortionModel model = DistortionModel::kFullOpenCV;
  bool fix_aspect_ratio = true;  // fx == fy (CALIB_FIX_ASPECT_RATIO); always on for SIMPLE_RADIAL / RADIAL
  int subpixel_radius = 11;      // cornerSubPix half window in pixels (window 2r+1, OpenCV sample's 11); >= 1
  // A view is an outlier when its RMS error exceeds outlier_factor x the median view error and
  // also outlier_min_error pixels. 0 disables rejection.
  double outlier_factor = 3.0;      // > 1 or 0
  double outlier_min_error = 0.5;   // pixels; >= 0
  int min_views = 3;                // views needed after rejection; >= 1
  bool Check(std::string* error) const;  // error starts with the YAML key
};

struct CalibrationView {
  std::string name;
  cv::Mat image;  // grey or colour, 8-bit
};

struct CalibrationViewResult {
  std::string name;
  bool detected = false;
  bool used = false;          // in the final calibration
  double rms_error = -1;      // pixels, with the final calibration (-1: not detected)
  std::string reason;         // why not used (empty when used)
  std::vector<cv::Point2f> corners;
};

struct CalibrationResult {
  Camera camera;                     // COLMAP model (OPENCV etc.); FULL_OPENCV is written by hand
  cv::Mat camera_matrix;             // 3x3 OpenCV (pixel centre at (0,0) as OpenCV)
  cv::Mat distortion;                // OpenCV order k1 k2 p1 p2 [k3]
  DistortionModel model = DistortionModel::kOpenCV;
  double rms = 0;                    // pixels, over the used views
  int image_width = 0, image_height = 0;
  std::vector<CalibrationViewResult> views;
  // COLMAP cameras.txt line parameters in COLMAP order and pixel convention (centre at 0.5, 0.5).
  std::string colmap_model_name;
  std::vector<double> colmap_params;
};

// Calibrates from the views (all of one size). Throws InputError when fewer than min_views views
// hold the pattern, naming the views.
CalibrationResult CalibratePlanar(const std::vector<CalibrationView>& views, const CalibrateOptions& options,
                                  ProgressReporter* progress = nullptr);

// OpenCV-style YAML (camera_matrix, distortion_coefficients, per-view errors) as text.
std::string CalibrationToOpenCvYaml(const CalibrationResult& result);
// cameras.txt text with one camera (id 1).
std::string CalibrationToColmapCameras(const CalibrationResult& result);
// Removes the lens distortion of `image` (same size and camera matrix).
cv::Mat UndistortWithCalibration(const cv::Mat& image, const CalibrationResult& result);

}  // namespace ibmr
