// Undistortion for dense stages (seed 000 lines 3469-3510: the forward projection model of a
// calibrated camera; 4788-4830: calibrate once, then work with ideal pinhole cameras). Each image
// is resampled into a PINHOLE camera with the same size, focal lengths and principal point: an
// output pixel's ray x = K^-1 p is distorted with the source model and looked up (bilinear).
// COLMAP pixel convention (centre of the top-left pixel at (0.5, 0.5)) on both sides.
#pragma once

#include <opencv2/core.hpp>
#include <string>

#include "pipeline/core/camera.h"
#include "pipeline/core/sparse_model.h"

namespace ibmr {

struct UndistortOptions {
  // Longest side of the undistorted images, pixels (COLMAP's image_undistorter max_image_size):
  // larger ones are downscaled (area averaging) with their cameras; 0: as they are.
  int max_image_size = 1600;
  bool Check(std::string* error) const;
};

// Lookup maps (OpenCV remap, pixel centres at integer coordinates) from the pinhole camera
// `camera.Undistorted()` into the distorted source image.
void UndistortMaps(const Camera& camera, cv::Mat* map_x, cv::Mat* map_y);

// Resamples one image; the output camera is camera.Undistorted().
cv::Mat UndistortImage(const cv::Mat& image, const cv::Mat& map_x, const cv::Mat& map_y);

// The model with every camera replaced by its undistorted pinhole, scaled so that its longest side
// is at most options.max_image_size, and 2D points moved accordingly.
SparseModel UndistortModel(const SparseModel& model, const UndistortOptions& options = UndistortOptions());

}  // namespace ibmr
