// Planar-target calibration: detection, sub-pixel refinement, cv::calibrateCamera, per-view
// errors and outlier rejection (seed 000 lines 3469-3510 and 4788-4830; see calibrate.h).
#include "stages/calibrate/calibrate.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "pipeline/core/median.h"
#include "pipeline/core/errors.h"

namespace ibmr {

namespace {

bool Fail(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

std::vector<cv::Point3f> TargetPoints(const CalibrateOptions& options) {
  std::vector<cv::Point3f> points;
  for (int r = 0; r < options.pattern_rows; ++r) {
    for (int c = 0; c < options.pattern_cols; ++c) {
      const double x = options.pattern == CalibrationPattern::kAsymmetricCircles ? (2 * c + r % 2) : c;
      points.emplace_back(static_cast<float>(x * options.square_size), static_cast<float>(r * options.square_size), 0.f);
    }
  }
  return points;
}

bool Detect(const cv::Mat& image, const CalibrateOptions& options, std::vector<cv::Point2f>* corners) {
  cv::Mat grey;
  if (image.channels() == 1) grey = image;
  else cv::cvtColor(image, grey, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  const cv::Size size(options.pattern_cols, options.pattern_rows);
  switch (options.pattern) {
    case CalibrationPattern::kChessboard: {
      if (!cv::findChessboardCorners(grey, size, *corners,
                                     cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE)) {
        return false;
      }
      cv::cornerSubPix(grey, *corners, cv::Size(options.subpixel_radius, options.subpixel_radius), cv::Size(-1, -1),
                       cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 1e-3));
      return true;
    }
    case CalibrationPattern::kCircles:
      return cv::findCirclesGrid(grey, size, *corners, cv::CALIB_CB_SYMMETRIC_GRID);
    case CalibrationPattern::kAsymmetricCircles:
      return cv::findCirclesGrid(grey, size, *corners, cv::CALIB_CB_ASYMMETRIC_GRID);
  }
  return false;
}

int CalibrationFlags(const CalibrateOptions& options) {
  int flags = 0;
  if (options.fix_aspect_ratio) flags |= cv::CALIB_FIX_ASPECT_RATIO;
  switch (options.model) {
    case DistortionModel::kPinhole:
      flags |= cv::CALIB_FIX_K1 | cv::CALIB_FIX_K2 | cv::CALIB_FIX_K3 | cv::CALIB_ZERO_TANGENT_DIST;
      break;
    case DistortionModel::kSimpleRadial:
      flags |= cv::CALIB_FIX_ASPECT_RATIO | cv::CALIB_FIX_K2 | cv::CALIB_FIX_K3 | cv::CALIB_ZERO_TANGENT_DIST;
      break;
    case DistortionModel::kRadial:
      flags |= cv::CALIB_FIX_ASPECT_RATIO | cv::CALIB_FIX_K3 | cv::CALIB_ZERO_TANGENT_DIST;
      break;
    case DistortionModel::kOpenCV: flags |= cv::CALIB_FIX_K3; break;
    case DistortionModel::kFullOpenCV: break;
  }
  return flags;
}

double ViewRms(const std::vector<cv::Point3f>& object, const std::vector<cv::Point2f>& corners, const cv::Mat& rvec,
               const cv::Mat& tvec, const cv::Mat& k, const cv::Mat& dist) {
  std::vector<cv::Point2f> projected;
  cv::projectPoints(object, rvec, tvec, k, dist, projected);
  double sum = 0;
  for (size_t i = 0; i < corners.size(); ++i) {
    const cv::Point2f d = projected[i] - corners[i];
    sum += d.x * d.x + d.y * d.y;
  }
  return std::sqrt(sum / corners.size());
}

// One calibrateCamera over the views flagged `used`; fills rms and per-view errors of used views.
void Calibrate(const CalibrateOptions& options, const cv::Size& size, CalibrationResult* result) {
  const std::vector<cv::Point3f> object = TargetPoints(options);
  std::vector<std::vector<cv::Point3f>> objects;
  std::vector<std::vector<cv::Point2f>> images;
  std::vector<CalibrationViewResult*> used;
  for (CalibrationViewResult& view : result->views) {
    if (!view.used) continue;
    objects.push_back(object);
    images.push_back(view.corners);
    used.push_back(&view);
  }
  cv::Mat k = cv::Mat::eye(3, 3, CV_64F), dist = cv::Mat::zeros(5, 1, CV_64F);
  std::vector<cv::Mat> rvecs, tvecs;
  result->rms = cv::calibrateCamera(objects, images, size, k, dist, rvecs, tvecs, CalibrationFlags(options));
  result->camera_matrix = k;
  result->distortion = dist;
  for (size_t i = 0; i < used.size(); ++i) used[i]->rms_error = ViewRms(object, images[i], rvecs[i], tvecs[i], k, dist);
}

// Flags the worst outlier view (if any) as unused with the reason; true when one was flagged.
bool RejectWorstOutlier(const CalibrateOptions& options, CalibrationResult* result) {
  if (options.outlier_factor <= 0) return false;
  std::vector<double> errors;
  CalibrationViewResult* worst = nullptr;
  for (CalibrationViewResult& view : result->views) {
    if (!view.used) continue;
    errors.push_back(view.rms_error);
    if (!worst || view.rms_error > worst->rms_error) worst = &view;
  }
  if (!worst || static_cast<int>(errors.size()) <= options.min_views) return false;
  const double median = Median(errors);
  const double limit = std::max(options.outlier_factor * median, options.outlier_min_error);
  if (worst->rms_error <= limit) return false;
  std::ostringstream reason;
  reason.precision(3);
  reason << "outlier: RMS reprojection error " << worst->rms_error << " px > max(" << options.outlier_factor
         << " x median " << median << " px, " << options.outlier_min_error << " px)";
  worst->used = false;
  worst->reason = reason.str();
  return true;
}

void FillColmapCamera(const CalibrateOptions& options, CalibrationResult* result) {
  const cv::Mat& k = result->camera_matrix;
  const cv::Mat& d = result->distortion;
  const double fx = k.at<double>(0, 0), fy = k.at<double>(1, 1);
  const double cx = k.at<double>(0, 2) + 0.5, cy = k.at<double>(1, 2) + 0.5;  // OpenCV (0,0) -> COLMAP (0.5,0.5)
  const double k1 = d.at<double>(0), k2 = d.at<double>(1), p1 = d.at<double>(2), p2 = d.at<double>(3);
  const double k3 = d.total() > 4 ? d.at<double>(4) : 0.0;
  Camera& camera = result->camera;
  camera.camera_id = 1;
  camera.width = result->image_width;
  camera.height = result->image_height;
  switch (options.model) {
    case DistortionModel::kPinhole:
      result->colmap_model_name = "PINHOLE";
      result->colmap_params = {fx, fy, cx, cy};
      camera.model = CameraModelId::kPinhole;
      break;
    case DistortionModel::kSimpleRadial:
      result->colmap_model_name = "SIMPLE_RADIAL";
      result->colmap_params = {fx, cx, cy, k1};
      camera.model = CameraModelId::kSimpleRadial;
      break;
    case DistortionModel::kRadial:
      result->colmap_model_name = "RADIAL";
      result->colmap_params = {fx, cx, cy, k1, k2};
      camera.model = CameraModelId::kRadial;
      break;
    case DistortionModel::kOpenCV:
      result->colmap_model_name = "OPENCV";
      result->colmap_params = {fx, fy, cx, cy, k1, k2, p1, p2};
      camera.model = CameraModelId::kOpenCV;
      break;
    case DistortionModel::kFullOpenCV:
      result->colmap_model_name = "FULL_OPENCV";
      result->colmap_params = {fx, fy, cx, cy, k1, k2, p1, p2, k3, 0, 0, 0};
      camera.model = CameraModelId::kFullOpenCV;
      break;
  }
  camera.params = result->colmap_params;
}

}  // namespace

bool CalibrateOptions::Check(std::string* error) const {
  if (pattern_cols < 2) return Fail(error, "pattern_cols: must be >= 2, got " + std::to_string(pattern_cols));
  if (pattern_rows < 2) return Fail(error, "pattern_rows: must be >= 2, got " + std::to_string(pattern_rows));
  if (!(square_size > 0)) return Fail(error, "square_size: must be > 0, got " + std::to_string(square_size));
  if (subpixel_radius < 1) return Fail(error, "subpixel_radius: must be >= 1, got " + std::to_string(subpixel_radius));
  if (outlier_factor != 0 && !(outlier_factor > 1)) {
    return Fail(error, "outlier_factor: must be > 1 (or 0 to disable), got " + std::to_string(outlier_factor));
  }
  if (!(outlier_min_error >= 0)) return Fail(error, "outlier_min_error: must be >= 0, got " + std::to_string(outlier_min_error));
  if (min_views < 1) return Fail(error, "min_views: must be >= 1, got " + std::to_string(min_views));
  return true;
}

CalibrationResult CalibratePlanar(const std::vector<CalibrationView>& views, const CalibrateOptions& options,
                                  ProgressReporter* progress) {
  NullProgress null_progress;
  if (!progress) progress = &null_progress;
  CalibrationResult result;
  result.model = options.model;
  cv::Size size;
  std::string missing;
  progress->Begin("pattern detection", views.size());
  for (const CalibrationView& view : views) {
    CalibrationViewResult entry;
    entry.name = view.name;
    if (size.area() == 0) size = view.image.size();
    if (view.image.size() != size) {
      entry.reason = "image size differs from the first view's";
    } else if (Detect(view.image, options, &entry.corners)) {
      entry.detected = entry.used = true;
    } else {
      entry.reason = "pattern not found";
      missing += " " + view.name;
    }
    result.views.push_back(entry);
    progress->Advance(1, view.name);
  }
  progress->End();
  const int detected = std::count_if(result.views.begin(), result.views.end(), [](const auto& v) { return v.used; });
  if (detected < options.min_views) {
    throw InputError("calibrate: the " + std::to_string(options.pattern_cols) + "x" + std::to_string(options.pattern_rows) +
                     " pattern was found in " + std::to_string(detected) + " views, " + std::to_string(options.min_views) +
                     " needed (not found in:" + missing + "); check pattern, pattern_cols and pattern_rows");
  }
  result.image_width = size.width;
  result.image_height = size.height;
  Calibrate(options, size, &result);
  while (RejectWorstOutlier(options, &result)) Calibrate(options, size, &result);
  // Rejected views: their error under the final calibration, for the record.
  const std::vector<cv::Point3f> object = TargetPoints(options);
  for (CalibrationViewResult& view : result.views) {
    if (view.used || !view.detected) continue;
    cv::Mat rvec, tvec;
    cv::solvePnP(object, view.corners, result.camera_matrix, result.distortion, rvec, tvec);
    view.rms_error = ViewRms(object, view.corners, rvec, tvec, result.camera_matrix, result.distortion);
  }
  FillColmapCamera(options, &result);
  return result;
}

std::string CalibrationToOpenCvYaml(const CalibrationResult& result) {
  cv::FileStorage fs(".yml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY);
  fs << "image_width" << result.image_width << "image_height" << result.image_height;
  fs << "camera_matrix" << result.camera_matrix << "distortion_coefficients" << result.distortion;
  fs << "avg_reprojection_error" << result.rms;
  fs << "views" << "[";
  for (const CalibrationViewResult& view : result.views) {
    fs << "{" << "name" << view.name << "used" << view.used << "rms_error" << view.rms_error << "reason" << view.reason << "}";
  }
  fs << "]";
  return fs.releaseAndGetString();
}

std::string CalibrationToColmapCameras(const CalibrationResult& result) {
  std::ostringstream out;
  out.precision(17);
  out << "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
      << "# Number of cameras: 1\n1 " << result.colmap_model_name << " " << result.image_width << " " << result.image_height;
  for (double p : result.colmap_params) out << " " << p;
  out << "\n";
  return out.str();
}

cv::Mat UndistortWithCalibration(const cv::Mat& image, const CalibrationResult& result) {
  cv::Mat undistorted;
  cv::undistort(image, undistorted, result.camera_matrix, result.distortion, result.camera_matrix);
  return undistorted;
}

}  // namespace ibmr
