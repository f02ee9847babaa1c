// Tests of the textured model (textured.h): a checkerboard atlas reproduced away from its edges,
// the UV convention (v up: the page's top-left texel lands top-left in the image), coverage, and
// the bilinear sampler's texel convention (centres at +0.5, clamped to the edge).
#include "stages/render/textured.h"

#include <gtest/gtest.h>

#include <cmath>

namespace ibmr {
namespace {

constexpr int kWidth = 120, kHeight = 100;

// The square [-1, 1]^2 at z = 0 as two counter-clockwise triangles, UV (0, 0) at (-1, -1) and
// (1, 1) at (1, 1), on one page.
TexturedMesh Square(const cv::Mat& page) {
  TexturedMesh textured;
  textured.mesh.vertices = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};
  textured.mesh.faces = {{0, 1, 2}, {0, 2, 3}};
  Eigen::Matrix<float, 3, 2> uv0, uv1;
  uv0 << 0, 0, 1, 0, 1, 1;
  uv1 << 0, 0, 1, 1, 0, 1;
  textured.face_uv = {uv0, uv1};
  textured.face_page = {0, 0};
  textured.pages = {page};
  return textured;
}

// Looking down at the square from z = 3, world +x to the image's right and +y up.
Rigid3d TopView() { return LookAt(Eigen::Vector3d(0, 0, 3), Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0)); }
Camera TestCamera() { return Camera::Pinhole(kWidth, kHeight, 90, 90, kWidth / 2.0, kHeight / 2.0); }

// Where the ray through pixel (x, y)'s centre meets z = 0.
Eigen::Vector2d GroundPoint(const Camera& camera, const Rigid3d& cam_from_world, int x, int y) {
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  const Eigen::Vector3d ray = world_from_cam.rotation * camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
  const Eigen::Vector3d eye = world_from_cam.translation;
  const double t = -eye.z() / ray.z();
  return (eye + t * ray).head<2>();
}

TEST(Textured, CheckerboardReproducedAwayFromEdges) {
  constexpr int kPage = 64, kCell = 8;
  cv::Mat page(kPage, kPage, CV_8UC3);
  for (int r = 0; r < kPage; ++r) {
    for (int c = 0; c < kPage; ++c) {
      page.at<cv::Vec3b>(r, c) = ((r / kCell + c / kCell) % 2) ? cv::Vec3b(230, 200, 20) : cv::Vec3b(10, 40, 250);
    }
  }
  const TexturedMesh mesh = Square(page);
  // A slightly oblique camera: perspective-correct interpolation matters.
  const Rigid3d pose = LookAt(Eigen::Vector3d(0.8, -0.6, 2.6), Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
  const RenderResult result = RenderTextured(mesh, TestCamera(), pose);
  size_t checked = 0, inside = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const Eigen::Vector2d g = GroundPoint(TestCamera(), pose, x, y);
      const bool on_square = std::abs(g.x()) < 1 && std::abs(g.y()) < 1;
      const bool well_inside = std::abs(g.x()) < 0.98 && std::abs(g.y()) < 0.98;
      const bool well_outside = std::abs(g.x()) > 1.02 || std::abs(g.y()) > 1.02;
      if (well_inside) EXPECT_EQ(result.coverage.at<uint8_t>(y, x), 255) << x << "," << y;
      if (well_outside) EXPECT_EQ(result.coverage.at<uint8_t>(y, x), 0) << x << "," << y;
      inside += result.coverage.at<uint8_t>(y, x) != 0;
      if (!on_square) continue;
      // Texel coordinates of the point (v up: row 0 at y = 1).
      const double tx = (g.x() + 1) / 2 * kPage, ty = (1 - (g.y() + 1) / 2) * kPage;
      const double edge_x = std::abs(tx / kCell - std::round(tx / kCell)) * kCell;
      const double edge_y = std::abs(ty / kCell - std::round(ty / kCell)) * kCell;
      if (edge_x < 1.5 || edge_y < 1.5) continue;  // bilinear blur across a checker edge
      const int cell = (static_cast<int>(ty) / kCell + static_cast<int>(tx) / kCell) % 2;
      const cv::Vec3b expected = cell ? cv::Vec3b(230, 200, 20) : cv::Vec3b(10, 40, 250);
      const cv::Vec3b got = result.image.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], expected[c], 2) << x << "," << y;
      ++checked;
    }
  }
  EXPECT_GT(checked, 1000u);
  EXPECT_EQ(result.covered_pixels, inside);
}

TEST(Textured, VUpTopLeftTexelLandsTopLeft) {
  // A 4x4 page in 2x2-texel quadrants: top-left red, top-right green, bottom-left blue, bottom-right white.
  cv::Mat page(4, 4, CV_8UC3);
  const cv::Vec3b red(0, 0, 255), green(0, 255, 0), blue(255, 0, 0), white(255, 255, 255);
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) page.at<cv::Vec3b>(r, c) = r < 2 ? (c < 2 ? red : green) : (c < 2 ? blue : white);
  }
  const RenderResult result = RenderTextured(Square(page), TestCamera(), TopView());
  // The quadrants' centres, world (-/+0.5, +/-0.5), are texel centres of same-coloured 2x2 blocks.
  const auto pixel_of = [&](double wx, double wy) {
    const Eigen::Vector2d p = TestCamera().ImgFromCam(TopView() * Eigen::Vector3d(wx, wy, 0));
    return cv::Point(static_cast<int>(p.x()), static_cast<int>(p.y()));
  };
  const cv::Point top_left = pixel_of(-0.5, 0.5), top_right = pixel_of(0.5, 0.5);
  const cv::Point bottom_left = pixel_of(-0.5, -0.5), bottom_right = pixel_of(0.5, -0.5);
  EXPECT_LT(top_left.x, kWidth / 2);
  EXPECT_LT(top_left.y, kHeight / 2);  // the world point with +y is in the image's upper half
  const auto near = [&](const cv::Point& at, const cv::Vec3b& expected) {
    const cv::Vec3b got = result.image.at<cv::Vec3b>(at);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], expected[c], 25) << at;
  };
  near(top_left, red);
  near(top_right, green);
  near(bottom_left, blue);
  near(bottom_right, white);
}

TEST(Textured, BilinearTexelCentresAndClamping) {
  cv::Mat image(2, 2, CV_8UC3);
  image.at<cv::Vec3b>(0, 0) = cv::Vec3b(0, 0, 0);
  image.at<cv::Vec3b>(0, 1) = cv::Vec3b(100, 0, 0);
  image.at<cv::Vec3b>(1, 0) = cv::Vec3b(0, 100, 0);
  image.at<cv::Vec3b>(1, 1) = cv::Vec3b(100, 100, 200);
  EXPECT_NEAR(SampleBilinear(image, 0.5f, 0.5f)[0], 0.f, 1e-4);   // a texel centre
  EXPECT_NEAR(SampleBilinear(image, 1.5f, 0.5f)[0], 100.f, 1e-4);
  EXPECT_NEAR(SampleBilinear(image, 1.0f, 1.0f)[2], 50.f, 1e-4);  // between the four centres
  EXPECT_NEAR(SampleBilinear(image, 1.0f, 0.5f)[0], 50.f, 1e-4);
  EXPECT_NEAR(SampleBilinear(image, 0.1f, 0.1f)[0], 0.f, 1e-4);  // clamped to the edge
  EXPECT_NEAR(SampleBilinear(image, 1.99f, 1.99f)[2], 200.f, 1e-4);
  // TexelFromUv: uv (0, 1) is the page's top-left corner, (1, 0) its bottom-right.
  EXPECT_TRUE(TexelFromUv(Eigen::Vector2f(0, 1), 2, 2).isApprox(Eigen::Vector2f(0, 0)));
  EXPECT_TRUE(TexelFromUv(Eigen::Vector2f(1, 0), 2, 2).isApprox(Eigen::Vector2f(2, 2)));
}

TEST(Textured, SupersampledThenDownsampled) {
  cv::Mat page(4, 4, CV_8UC3, cv::Scalar(30, 60, 90));
  const TexturedMesh mesh = Square(page);
  const int factor = 2;
  const Camera fine_camera = TestCamera().Scaled(factor);
  const RenderResult fine = RenderTextured(mesh, fine_camera, TopView());
  ProxySurface hits;
  hits.width = fine_camera.width;
  hits.height = fine_camera.height;
  hits.hit.resize(static_cast<size_t>(hits.width) * hits.height);
  for (int y = 0; y < hits.height; ++y) {
    for (int x = 0; x < hits.width; ++x) hits.hit[static_cast<size_t>(y) * hits.width + x] = fine.coverage.at<uint8_t>(y, x) != 0;
  }
  const RenderResult result = Downsample(fine, hits, factor);
  ASSERT_EQ(result.image.cols, kWidth);
  ASSERT_EQ(result.image.rows, kHeight);
  const RenderResult direct = RenderTextured(mesh, TestCamera(), TopView());
  EXPECT_EQ(result.image.at<cv::Vec3b>(kHeight / 2, kWidth / 2), cv::Vec3b(30, 60, 90));
  // Coverage agrees with a direct render except along the silhouette.
  EXPECT_NEAR(static_cast<double>(result.covered_pixels), static_cast<double>(direct.covered_pixels),
              0.1 * direct.covered_pixels);
}

}  // namespace
}  // namespace ibmr
