// Normals from depth: a tilted plane gives its normal everywhere inside, facing the camera;
// depth jumps and missing neighbours give no normal; rays follow the pixel-centre convention.
#include "pipeline/core/depth_normals.h"

#include <gtest/gtest.h>

namespace ibmr {
namespace {

TEST(DepthNormals, TiltedPlaneGivesItsNormal) {
  const Camera camera = Camera::Pinhole(40, 30, 50, 50, 20, 15);
  const Eigen::Vector3d normal = Eigen::Vector3d(0.3, -0.2, -1).normalized();  // faces the camera
  const double offset = -normal.dot(Eigen::Vector3d(0, 0, 4));                // plane through (0,0,4)
  DepthMap depth(40, 30);
  for (int y = 0; y < 30; ++y) {
    for (int x = 0; x < 40; ++x) {
      const Eigen::Vector3d ray = camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
      depth.At(x, y) = static_cast<float>(-offset / normal.dot(ray));  // z of the ray-plane hit
    }
  }
  const FloatMap normals = NormalsFromDepth(camera, depth);
  for (int y = 1; y < 29; ++y) {
    for (int x = 1; x < 39; ++x) {
      const Eigen::Vector3d n(normals.At(x, y, 0), normals.At(x, y, 1), normals.At(x, y, 2));
      ASSERT_NEAR(n.dot(normal), 1.0, 1e-4) << x << "," << y;
    }
  }
  EXPECT_EQ(normals.At(0, 5, 0), 0.f);  // border
}

TEST(DepthNormals, JumpsAndHolesGiveNoNormal) {
  const Camera camera = Camera::Pinhole(20, 20, 30, 30, 10, 10);
  DepthMap depth(20, 20, 1, 2.f);
  for (int y = 0; y < 20; ++y) {
    for (int x = 10; x < 20; ++x) depth.At(x, y) = 3.f;  // a step of 50%
  }
  depth.At(5, 5) = 0.f;
  const FloatMap normals = NormalsFromDepth(camera, depth);
  EXPECT_EQ(normals.At(9, 8, 2), 0.f);
  EXPECT_EQ(normals.At(10, 8, 2), 0.f);
  EXPECT_EQ(normals.At(5, 4, 2), 0.f);
  EXPECT_NEAR(normals.At(3, 3, 2), -1.f, 1e-6);  // fronto-parallel, facing the camera
}

TEST(DepthNormals, RaysScaleToTheMapResolution) {
  const Camera camera = Camera::Pinhole(40, 20, 50, 50, 20, 10);
  const std::vector<Eigen::Vector3f> rays = PixelRays(camera, 20, 10);  // half resolution
  // Pixel (10, 5) of the half map covers full-resolution pixels 20-21: its centre is at x = 21.
  EXPECT_NEAR(rays[5 * 20 + 10].x(), (21.0 - 20) / 50, 1e-6);
  EXPECT_NEAR(rays[5 * 20 + 10].y(), (11.0 - 10) / 50, 1e-6);
}

}  // namespace
}  // namespace ibmr
