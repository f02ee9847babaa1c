// Undistortion maps and model conversion (see undistort.h).
#include "stages/undistort/undistort.h"

#include <opencv2/imgproc.hpp>

namespace ibmr {

void UndistortMaps(const Camera& camera, cv::Mat* map_x, cv::Mat* map_y) {
  const Camera pinhole = camera.Undistorted();
  map_x->create(camera.height, camera.width, CV_32F);
  map_y->create(camera.height, camera.width, CV_32F);
  for (int row = 0; row < camera.height; ++row) {
    float* mx = map_x->ptr<float>(row);
    float* my = map_y->ptr<float>(row);
    for (int col = 0; col < camera.width; ++col) {
      const Eigen::Vector3d ray = pinhole.CamFromImg(Eigen::Vector2d(col + 0.5, row + 0.5));
      const Eigen::Vector2d source = camera.ImgFromCam(ray);
      mx[col] = static_cast<float>(source.x() - 0.5);
      my[col] = static_cast<float>(source.y() - 0.5);
    }
  }
}

cv::Mat UndistortImage(const cv::Mat& image, const cv::Mat& map_x, const cv::Mat& map_y) {
  cv::Mat output;
  cv::remap(image, output, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return output;
}

bool UndistortOptions::Check(std::string* error) const {
  if (max_image_size != 0 && (max_image_size < 16 || max_image_size > 100000)) {
    *error = "max_image_size: must be 0 (keep) or in [16, 100000], got " + std::to_string(max_image_size);
    return false;
  }
  return true;
}

SparseModel UndistortModel(const SparseModel& model, const UndistortOptions& options) {
  SparseModel result = model;
  for (auto& [id, camera] : result.cameras) {
    camera = model.cameras.at(id).Undistorted();
    const int longest = std::max(camera.width, camera.height);
    if (options.max_image_size > 0 && longest > options.max_image_size) {
      camera = camera.Scaled(static_cast<double>(options.max_image_size) / longest);
    }
    camera.camera_id = id;
  }
  for (auto& [id, image] : result.images) {
    const Camera& source = model.cameras.at(image.camera_id);
    const Camera& target = result.cameras.at(image.camera_id);
    for (Point2D& point : image.points2D) point.xy = target.ImgFromCam(source.CamFromImg(point.xy));
  }
  return result;
}

}  // namespace ibmr
