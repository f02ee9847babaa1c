// Tests for camera models: names, projection round trips per model, distortion checked against
// OpenCV's projectPoints, Newton undistortion, Validate messages, Undistorted and Scaled.
#include "pipeline/core/camera.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>
#include <opencv2/calib3d.hpp>
#include <random>

namespace ibmr {
namespace {

constexpr double kK1 = -0.27, kK2 = 0.24, kP1 = 0.0018, kP2 = -0.0003;
constexpr double kK3 = -0.05, kK4 = 0.02, kK5 = 0.01, kK6 = -0.004;  // FULL_OPENCV's rational terms

Camera MakeCamera(CameraModelId model) {
  Camera camera;
  camera.model = model;
  camera.width = 640;
  camera.height = 480;
  switch (model) {
    case CameraModelId::kSimplePinhole: camera.params = {520, 321.5, 238.25}; break;
    case CameraModelId::kPinhole: camera.params = {520, 515, 321.5, 238.25}; break;
    case CameraModelId::kSimpleRadial: camera.params = {520, 321.5, 238.25, kK1}; break;
    case CameraModelId::kRadial: camera.params = {520, 321.5, 238.25, kK1, kK2}; break;
    case CameraModelId::kOpenCV:
      camera.params = {520, 515, 321.5, 238.25, kK1, kK2, kP1, kP2};
      break;
    case CameraModelId::kFullOpenCV:
      camera.params = {520, 515, 321.5, 238.25, kK1, kK2, kP1, kP2, kK3, kK4, kK5, kK6};
      break;
  }
  return camera;
}

const CameraModelId kAllModels[] = {CameraModelId::kSimplePinhole, CameraModelId::kPinhole,
                                    CameraModelId::kSimpleRadial, CameraModelId::kRadial,
                                    CameraModelId::kOpenCV, CameraModelId::kFullOpenCV};

TEST(CameraModel, NamesRoundTripAndCounts) {
  const int expected_counts[] = {3, 4, 4, 5, 8, 12};
  int i = 0;
  for (CameraModelId model : kAllModels) {
    CameraModelId parsed;
    ASSERT_TRUE(CameraModelFromName(CameraModelName(model), &parsed));
    EXPECT_EQ(parsed, model);
    EXPECT_EQ(CameraModelNumParams(model), expected_counts[i++]);
  }
  CameraModelId parsed;
  EXPECT_FALSE(CameraModelFromName("OPENCV_FISHEYE", &parsed));
  EXPECT_FALSE(CameraModelFromName("pinhole", &parsed));
  EXPECT_EQ(CameraModelName(CameraModelId::kSimpleRadial), "SIMPLE_RADIAL");
}

TEST(Camera, Accessors) {
  const Camera radial = MakeCamera(CameraModelId::kRadial);
  EXPECT_EQ(radial.FocalX(), 520);
  EXPECT_EQ(radial.FocalY(), 520);
  EXPECT_EQ(radial.PrincipalX(), 321.5);
  EXPECT_EQ(radial.PrincipalY(), 238.25);
  const Camera opencv = MakeCamera(CameraModelId::kOpenCV);
  EXPECT_EQ(opencv.FocalY(), 515);
  EXPECT_EQ(opencv.PrincipalX(), 321.5);
  const Eigen::Matrix3d k = opencv.K();
  EXPECT_EQ(k(0, 0), 520);
  EXPECT_EQ(k(1, 1), 515);
  EXPECT_EQ(k(0, 2), 321.5);
  EXPECT_EQ(k(1, 2), 238.25);
  EXPECT_EQ(k(2, 2), 1);
  EXPECT_EQ(k(0, 1), 0);
  EXPECT_TRUE(opencv.HasDistortion());
  EXPECT_FALSE(MakeCamera(CameraModelId::kPinhole).HasDistortion());
}

TEST(Camera, PinholeProjectsWithK) {
  const Camera camera = Camera::Pinhole(640, 480, 500, 400, 320, 240);
  const Eigen::Vector2d pixel = camera.ImgFromCam(Eigen::Vector3d(1, -2, 4));
  EXPECT_DOUBLE_EQ(pixel.x(), 500 * 0.25 + 320);
  EXPECT_DOUBLE_EQ(pixel.y(), 400 * -0.5 + 240);
}

TEST(Camera, ProjectUnprojectRoundTripPerModel) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> xy(-0.6, 0.6), depth(0.5, 20);
  for (CameraModelId model : kAllModels) {
    const Camera camera = MakeCamera(model);
    for (int i = 0; i < 200; ++i) {
      const double z = depth(rng);
      const Eigen::Vector3d point(xy(rng) * z, xy(rng) * z, z);
      const Eigen::Vector2d pixel = camera.ImgFromCam(point);
      const Eigen::Vector3d ray = camera.CamFromImg(pixel);
      EXPECT_EQ(ray.z(), 1);
      EXPECT_NEAR((ray * z - point).norm(), 0, 1e-9 * z) << CameraModelName(model);
      EXPECT_NEAR((camera.ImgFromCam(ray) - pixel).norm(), 0, 1e-9) << CameraModelName(model);
    }
  }
}

// OpenCV's projectPoints with the same K and (k1, k2, p1, p2) is the reference.
TEST(Camera, MatchesOpenCvProjectPoints) {
  const Camera camera = MakeCamera(CameraModelId::kOpenCV);
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> xy(-0.7, 0.7), depth(0.5, 50);
  std::vector<cv::Point3d> points;
  for (int i = 0; i < 500; ++i) {
    const double z = depth(rng);
    points.emplace_back(xy(rng) * z, xy(rng) * z, z);
  }
  const cv::Matx33d k(520, 0, 321.5, 0, 515, 238.25, 0, 0, 1);
  const std::vector<double> dist = {kK1, kK2, kP1, kP2};
  std::vector<cv::Point2d> expected;
  cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), k, dist, expected);
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p(points[i].x, points[i].y, points[i].z);
    const Eigen::Vector2d pixel = camera.ImgFromCam(p);
    EXPECT_NEAR(pixel.x(), expected[i].x, 1e-9 * std::abs(expected[i].x) + 1e-12);
    EXPECT_NEAR(pixel.y(), expected[i].y, 1e-9 * std::abs(expected[i].y) + 1e-12);
    // Distort on normalised coordinates: compare against the reference divided back by K.
    const Eigen::Vector2d normalized = camera.Distort(p.hnormalized());
    EXPECT_NEAR(normalized.x(), (expected[i].x - 321.5) / 520, 1e-9 * std::abs(normalized.x()) + 1e-12);
    EXPECT_NEAR(normalized.y(), (expected[i].y - 238.25) / 515, 1e-9 * std::abs(normalized.y()) + 1e-12);
  }
}

// FULL_OPENCV: the rational radial factor, as projectPoints with the 8-term distortion vector.
TEST(Camera, FullOpenCvMatchesOpenCvProjectPoints) {
  const Camera camera = MakeCamera(CameraModelId::kFullOpenCV);
  std::mt19937 rng(43);
  std::uniform_real_distribution<double> xy(-0.7, 0.7), depth(0.5, 50);
  std::vector<cv::Point3d> points;
  for (int i = 0; i < 500; ++i) {
    const double z = depth(rng);
    points.emplace_back(xy(rng) * z, xy(rng) * z, z);
  }
  const cv::Matx33d k(520, 0, 321.5, 0, 515, 238.25, 0, 0, 1);
  const std::vector<double> dist = {kK1, kK2, kP1, kP2, kK3, kK4, kK5, kK6};
  std::vector<cv::Point2d> expected;
  cv::projectPoints(points, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), k, dist, expected);
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p(points[i].x, points[i].y, points[i].z);
    const Eigen::Vector2d pixel = camera.ImgFromCam(p);
    EXPECT_NEAR(pixel.x(), expected[i].x, 1e-9 * std::abs(expected[i].x) + 1e-12);
    EXPECT_NEAR(pixel.y(), expected[i].y, 1e-9 * std::abs(expected[i].y) + 1e-12);
    const Eigen::Vector2d back = camera.Undistort(camera.Distort(p.hnormalized()));
    EXPECT_NEAR(back.x(), p.hnormalized().x(), 1e-8);
    EXPECT_NEAR(back.y(), p.hnormalized().y(), 1e-8);
  }
}

TEST(Camera, RadialModelsMatchOpenCvWithZeroTerms) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> xy(-0.7, 0.7);
  const Camera simple_radial = MakeCamera(CameraModelId::kSimpleRadial);
  const Camera radial = MakeCamera(CameraModelId::kRadial);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector2d u(xy(rng), xy(rng));
    const double r2 = u.squaredNorm();
    EXPECT_NEAR((simple_radial.Distort(u) - u * (1 + kK1 * r2)).norm(), 0, 1e-15);
    EXPECT_NEAR((radial.Distort(u) - u * (1 + kK1 * r2 + kK2 * r2 * r2)).norm(), 0, 1e-15);
  }
}

TEST(Camera, UndistortInvertsDistort) {
  const Camera camera = MakeCamera(CameraModelId::kOpenCV);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> xy(-0.8, 0.8);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector2d u(xy(rng), xy(rng));
    const Eigen::Vector2d back = camera.Undistort(camera.Distort(u));
    ASSERT_TRUE(back.allFinite());
    EXPECT_NEAR((back - u).norm(), 0, 1e-12) << u.transpose();
  }
  // The centre and points far outside the image stay finite.
  EXPECT_EQ(camera.Undistort(Eigen::Vector2d::Zero()), Eigen::Vector2d::Zero());
  EXPECT_TRUE(camera.Undistort(Eigen::Vector2d(5, -7)).allFinite());
}

TEST(Camera, UndistortStrongBarrelStaysFinite) {
  Camera camera = MakeCamera(CameraModelId::kRadial);
  camera.params[3] = -0.6;  // folds over beyond r ~ 0.75: no exact inverse there
  camera.params[4] = 0.0;
  for (double x = -2; x <= 2; x += 0.125) {
    const Eigen::Vector2d u = camera.Undistort(Eigen::Vector2d(x, 0.5 * x));
    EXPECT_TRUE(u.allFinite()) << x;
  }
  const Eigen::Vector2d inside(0.3, -0.2);
  EXPECT_NEAR((camera.Undistort(camera.Distort(inside)) - inside).norm(), 0, 1e-12);
}

TEST(Camera, ValidateAcceptsGoodCameras) {
  for (CameraModelId model : kAllModels) {
    EXPECT_EQ(MakeCamera(model).Validate(), "") << CameraModelName(model);
  }
}

TEST(Camera, ValidateNamesTheProblem) {
  Camera camera = MakeCamera(CameraModelId::kOpenCV);
  camera.camera_id = 3;
  camera.params.resize(4);
  const std::string count_error = camera.Validate();
  EXPECT_NE(count_error.find("OPENCV"), std::string::npos) << count_error;
  EXPECT_NE(count_error.find("8"), std::string::npos) << count_error;
  EXPECT_NE(count_error.find("got 4"), std::string::npos) << count_error;
  EXPECT_NE(count_error.find("camera 3"), std::string::npos) << count_error;

  camera = MakeCamera(CameraModelId::kPinhole);
  camera.width = 0;
  EXPECT_NE(camera.Validate().find("size"), std::string::npos) << camera.Validate();

  camera = MakeCamera(CameraModelId::kPinhole);
  camera.params[1] = -5;
  EXPECT_NE(camera.Validate().find("focal"), std::string::npos) << camera.Validate();

  camera = MakeCamera(CameraModelId::kSimplePinhole);
  camera.params[0] = 0;
  EXPECT_NE(camera.Validate().find("focal"), std::string::npos) << camera.Validate();

  camera = MakeCamera(CameraModelId::kRadial);
  camera.params[3] = std::nan("");
  EXPECT_NE(camera.Validate().find("finite"), std::string::npos) << camera.Validate();
}

TEST(Camera, UndistortedDropsDistortionKeepsK) {
  const Camera opencv = MakeCamera(CameraModelId::kOpenCV);
  const Camera pinhole = opencv.Undistorted();
  EXPECT_EQ(pinhole.model, CameraModelId::kPinhole);
  EXPECT_EQ(pinhole.K(), opencv.K());
  EXPECT_EQ(pinhole.width, 640);
  EXPECT_FALSE(pinhole.HasDistortion());
  EXPECT_EQ(pinhole.Validate(), "");

  const Camera radial = MakeCamera(CameraModelId::kRadial);
  const Camera simple = radial.Undistorted();
  EXPECT_EQ(simple.model, CameraModelId::kSimplePinhole);
  EXPECT_EQ(simple.K(), radial.K());
  EXPECT_EQ(simple.Validate(), "");

  const Camera already = MakeCamera(CameraModelId::kPinhole);
  EXPECT_EQ(already.Undistorted().params, already.params);
}

TEST(Camera, ScaledHalvesSizeAndIntrinsics) {
  const Camera camera = MakeCamera(CameraModelId::kOpenCV);
  const Camera half = camera.Scaled(0.5);
  EXPECT_EQ(half.width, 320);
  EXPECT_EQ(half.height, 240);
  EXPECT_DOUBLE_EQ(half.FocalX(), 260);
  EXPECT_DOUBLE_EQ(half.FocalY(), 257.5);
  EXPECT_DOUBLE_EQ(half.PrincipalX(), 160.75);
  EXPECT_DOUBLE_EQ(half.PrincipalY(), 119.125);
  EXPECT_EQ(half.params[4], kK1);  // distortion is in normalised coordinates
  EXPECT_EQ(half.params[7], kP2);
  // With the (0.5, 0.5) pixel-centre convention a point lands at exactly half its pixel position.
  const Eigen::Vector3d point(0.3, -0.1, 2);
  EXPECT_NEAR((half.ImgFromCam(point) - 0.5 * camera.ImgFromCam(point)).norm(), 0, 1e-9);

  const Camera simple = MakeCamera(CameraModelId::kSimpleRadial).Scaled(2);
  EXPECT_EQ(simple.width, 1280);
  EXPECT_DOUBLE_EQ(simple.FocalX(), 1040);
  EXPECT_DOUBLE_EQ(simple.PrincipalY(), 476.5);
}

}  // namespace
}  // namespace ibmr
