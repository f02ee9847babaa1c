// See undistorted_cameras.h.
#include "pipeline/core/undistorted_cameras.h"

#include "pipeline/core/errors.h"

namespace ibmr {

void RequireUndistorted(const Camera& camera, const std::string& image_name, const std::string& cameras_file,
                        const std::string& stage) {
  if (!camera.HasDistortion()) return;
  throw InputError(cameras_file + ": camera " + std::to_string(camera.camera_id) + " of image " + image_name + " (" +
                   CameraModelName(camera.model) + ") has lens distortion; " + stage +
                   " needs undistorted images: add the undistort stage before it (as configs/photos.yaml does), "
                   "or import PINHOLE cameras");
}

}  // namespace ibmr
