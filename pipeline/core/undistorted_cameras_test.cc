// RequireUndistorted: pinhole cameras and distortion models whose coefficients are all zero pass;
// any non-zero coefficient is refused with a message naming the file, camera, image, model, stage
// and the fix.
#include "pipeline/core/undistorted_cameras.h"

#include <gtest/gtest.h>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

Camera OpenCv(double k1, double p2) {
  Camera camera;
  camera.camera_id = 7;
  camera.model = CameraModelId::kOpenCV;
  camera.width = 640;
  camera.height = 480;
  camera.params = {500, 500, 320, 240, k1, 0, 0, p2};
  return camera;
}

TEST(RequireUndistorted, PinholeAndZeroCoefficientsPass) {
  EXPECT_NO_THROW(RequireUndistorted(Camera::Pinhole(640, 480, 500, 500, 320, 240), "a.png", "cameras.txt", "render"));
  EXPECT_NO_THROW(RequireUndistorted(OpenCv(0, 0), "a.png", "cameras.txt", "render"));
}

TEST(RequireUndistorted, AnyCoefficientIsRefusedWithFileCameraImageStageAndFix) {
  for (const Camera& camera : {OpenCv(0.05, 0), OpenCv(0, 1e-4)}) {
    try {
      RequireUndistorted(camera, "view_003.png", "ws/sparse/cameras.txt", "texture");
      FAIL() << "a distorted camera passed";
    } catch (const InputError& e) {
      const std::string message = e.what();
      for (const char* part : {"ws/sparse/cameras.txt", "camera 7", "view_003.png", "OPENCV", "lens distortion",
                               "texture needs", "add the undistort stage", "PINHOLE"}) {
        EXPECT_NE(message.find(part), std::string::npos) << "no \"" << part << "\" in: " << message;
      }
    }
  }
}

}  // namespace
}  // namespace ibmr
