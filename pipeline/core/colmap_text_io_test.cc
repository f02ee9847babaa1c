// Tests for the COLMAP text model: exact round trip, COLMAP headers, hand-written files, and
// error messages that name the file, the line and the field.
#include "pipeline/core/colmap_text_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

// A fresh folder per test under the gtest temp dir.
std::string MakeTestDir() {
  const testing::TestInfo* info = testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::path(testing::TempDir()) / "ibmr_colmap_text_io_test" /
                       (std::string(info->test_suite_name()) + "_" + info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

void WriteText(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

SparseModel MakeModel() {
  SparseModel model;
  Camera opencv;
  opencv.camera_id = 1;
  opencv.model = CameraModelId::kOpenCV;
  opencv.width = 3072;
  opencv.height = 2048;
  opencv.params = {2759.48 + 1.0 / 3, 2764.16, 1520.69, 1006.81, -0.27, 0.24, 0.0018, -0.0003};
  model.cameras[1] = opencv;
  Camera radial;
  radial.camera_id = 7;
  radial.model = CameraModelId::kSimpleRadial;
  radial.width = 640;
  radial.height = 480;
  radial.params = {M_PI * 100, 320.5, 240.5, 1e-17};
  model.cameras[7] = radial;

  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1, 1);
  const char* names[] = {"a/img_0001.png", "img_0000.png", "img_0002.jpg"};
  const int image_ids[] = {2, 5, 9};
  for (int i = 0; i < 3; ++i) {
    Image image;
    image.image_id = image_ids[i];
    image.camera_id = i == 1 ? 7 : 1;
    image.name = names[i];
    image.cam_from_world = Rigid3d(Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng)),
                                   Eigen::Vector3d(u(rng), u(rng), u(rng) * 1e5));
    if (i < 2) {  // the last image has no observations: an empty second line
      for (int k = 0; k < 3; ++k) {
        Point2D p;
        p.xy = Eigen::Vector2d(100 * u(rng) + 300, 100 * u(rng) + 200);
        p.point3D_id = k < 2 ? 100 + k : -1;
        image.points2D.push_back(p);
      }
    }
    model.images[image.image_id] = image;
  }
  for (int k = 0; k < 2; ++k) {
    Point3D point;
    point.xyz = Eigen::Vector3d(u(rng), u(rng) / 3, 1e-3 * u(rng));
    point.color = Eigen::Matrix<uint8_t, 3, 1>(255, static_cast<uint8_t>(10 * k), 0);
    point.error = k == 0 ? 0.123456789012345678 : -1;
    point.track = {{2, k}, {5, k}};
    model.points[100 + k] = point;
  }
  return model;
}

// Every value, rotations included, must survive the text round trip bit for bit.
void ExpectModelsEqual(const SparseModel& a, const SparseModel& b) {
  ASSERT_EQ(a.cameras.size(), b.cameras.size());
  for (const auto& [id, camera] : a.cameras) {
    const Camera& other = b.cameras.at(id);
    EXPECT_EQ(other.camera_id, camera.camera_id);
    EXPECT_EQ(other.model, camera.model);
    EXPECT_EQ(other.width, camera.width);
    EXPECT_EQ(other.height, camera.height);
    EXPECT_EQ(other.params, camera.params);
  }
  ASSERT_EQ(a.images.size(), b.images.size());
  for (const auto& [id, image] : a.images) {
    const Image& other = b.images.at(id);
    EXPECT_EQ(other.image_id, image.image_id);
    EXPECT_EQ(other.camera_id, image.camera_id);
    EXPECT_EQ(other.name, image.name);
    EXPECT_EQ(other.cam_from_world.rotation.coeffs(), image.cam_from_world.rotation.coeffs());
    EXPECT_EQ(other.cam_from_world.translation, image.cam_from_world.translation);
    ASSERT_EQ(other.points2D.size(), image.points2D.size());
    for (size_t i = 0; i < image.points2D.size(); ++i) {
      EXPECT_EQ(other.points2D[i].xy, image.points2D[i].xy);
      EXPECT_EQ(other.points2D[i].point3D_id, image.points2D[i].point3D_id);
    }
  }
  ASSERT_EQ(a.points.size(), b.points.size());
  for (const auto& [id, point] : a.points) {
    const Point3D& other = b.points.at(id);
    EXPECT_EQ(other.xyz, point.xyz);
    EXPECT_EQ(other.color, point.color);
    EXPECT_EQ(other.error, point.error);
    ASSERT_EQ(other.track.size(), point.track.size());
    for (size_t i = 0; i < point.track.size(); ++i) {
      EXPECT_EQ(other.track[i].image_id, point.track[i].image_id);
      EXPECT_EQ(other.track[i].point2D_idx, point.track[i].point2D_idx);
    }
  }
}

// Writes a minimal valid cameras.txt so that tests can focus on images.txt.
void WriteOneCamera(const std::string& dir) {
  WriteText(dir + "/cameras.txt", "# Camera list\n1 PINHOLE 640 480 500 500 320 240\n");
}

// Expects `read` to throw IoError whose message contains every one of `parts`.
void ExpectIoError(const std::string& dir, const std::vector<std::string>& parts) {
  try {
    ReadSparseModelText(dir);
    FAIL() << "expected IoError";
  } catch (const IoError& error) {
    const std::string message = error.what();
    for (const std::string& part : parts) {
      EXPECT_NE(message.find(part), std::string::npos) << "'" << part << "' not in: " << message;
    }
  }
}

TEST(ColmapTextIo, RoundTripIsExact) {
  const std::string dir = MakeTestDir();
  const SparseModel model = MakeModel();
  ASSERT_EQ(model.Validate(), "");
  WriteSparseModelText(dir, model);
  const SparseModel read = ReadSparseModelText(dir);
  ExpectModelsEqual(model, read);
  // Writing what was read gives the same bytes.
  const std::string dir2 = dir + "/again";
  WriteSparseModelText(dir2, read);
  for (const char* file : {"/cameras.txt", "/images.txt", "/points3D.txt"}) {
    EXPECT_EQ(ReadText(dir + file), ReadText(dir2 + file)) << file;
  }
}

TEST(ColmapTextIo, WritesColmapHeaders) {
  const std::string dir = MakeTestDir();
  WriteSparseModelText(dir, MakeModel());
  const std::string cameras = ReadText(dir + "/cameras.txt");
  const std::string images = ReadText(dir + "/images.txt");
  const std::string points = ReadText(dir + "/points3D.txt");
  EXPECT_NE(cameras.find("#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"), std::string::npos);
  EXPECT_NE(cameras.find("# Number of cameras: 2\n"), std::string::npos);
  EXPECT_NE(cameras.find("\n7 SIMPLE_RADIAL 640 480 "), std::string::npos) << cameras;
  EXPECT_NE(images.find("# Number of images: 3, mean observations per image: 2\n"),
            std::string::npos) << images;
  EXPECT_NE(images.find(" 1 img_0002.jpg\n\n"), std::string::npos) << images;  // empty line 2
  EXPECT_NE(points.find("# Number of points: 2, mean track length: 2\n"), std::string::npos)
      << points;
  EXPECT_NE(points.find("\n101 "), std::string::npos);
  EXPECT_EQ(fs::directory_iterator(dir) != fs::directory_iterator(), true);
  for (const auto& entry : fs::directory_iterator(dir)) {  // no temporary files left behind
    EXPECT_EQ(entry.path().string().find(".tmp"), std::string::npos) << entry.path();
  }
}

TEST(ColmapTextIo, ReadsHandWrittenModelWithoutPoints) {
  const std::string dir = MakeTestDir();
  WriteText(dir + "/cameras.txt",
            "# comment\n\n1 SIMPLE_PINHOLE 100 80 90 50 40\r\n2 RADIAL 10 10 5 5 5 0.1 -0.01\n");
  WriteText(dir + "/images.txt",
            "# Image list\n"
            "3 1 0 0 0 0.5 -1 2 1 first image.png\n"
            "\n"
            "4 0 1 0 0 1e-3 +2 -3.5E2 2 second.png\n"
            "10.5 20.25 17 30 40 -1\n");
  const SparseModel model = ReadSparseModelText(dir);
  EXPECT_TRUE(model.points.empty());
  ASSERT_EQ(model.cameras.size(), 2u);
  EXPECT_EQ(model.cameras.at(1).model, CameraModelId::kSimplePinhole);
  EXPECT_EQ(model.cameras.at(2).params.back(), -0.01);
  ASSERT_EQ(model.images.size(), 2u);
  EXPECT_EQ(model.images.at(3).name, "first image.png");
  EXPECT_TRUE(model.images.at(3).points2D.empty());
  EXPECT_EQ(model.images.at(3).cam_from_world.translation, Eigen::Vector3d(0.5, -1, 2));
  const Image& second = model.images.at(4);
  EXPECT_EQ(second.camera_id, 2);
  EXPECT_EQ(second.cam_from_world.translation, Eigen::Vector3d(1e-3, 2, -350));
  EXPECT_NEAR(second.cam_from_world.rotation.angularDistance(
                  Eigen::Quaterniond(0, 1, 0, 0)), 0, 1e-15);
  ASSERT_EQ(second.points2D.size(), 2u);
  EXPECT_EQ(second.points2D[1].xy, Eigen::Vector2d(30, 40));
  EXPECT_EQ(second.points2D[0].point3D_id, -1);  // no points3D.txt: untriangulated
  EXPECT_EQ(second.points2D[1].point3D_id, -1);
  EXPECT_EQ(model.FindImage("second.png"), &second);
  EXPECT_EQ(model.ImageIdsByName(), (std::vector<int>{3, 4}));
}

TEST(ColmapTextIo, MalformedImageLineNamesFileLineAndFields) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  WriteText(dir + "/images.txt",
            "# Image list with two lines of data per image:\n"
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
            "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
            "# Number of images: 2\n"
            "1 1 0 0 0 0 0 0 1 a.png\n"
            "\n"
            "2 1 0 0 0 0 0 0\n"
            "\n");
  ExpectIoError(dir, {"images.txt:7:", "expected 10 fields",
                      "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME", "got 8"});
}

TEST(ColmapTextIo, BadNumberNamesField) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 0.5x 0 1 a.png\n\n");
  ExpectIoError(dir, {"images.txt:1:", "TY", "0.5x"});
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 0 0 1 a.png\n1 2 3 4\n");
  ExpectIoError(dir, {"images.txt:2:", "triples", "got 4"});
}

// "nan" and "inf" parse as numbers but mean nothing in a model: a NaN pose dropped its view with
// only a warning, and a NaN point blanked the scene centre. Refused with file, line and field.
TEST(ColmapTextIo, NonFiniteNumbersNameFileLineAndField) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 nan 0 1 a.png\n\n");
  ExpectIoError(dir, {"images.txt:1:", "TY", "'nan' is not a finite number"});
  WriteText(dir + "/images.txt", "1 1e308 1e308 0 0 0 0 0 1 a.png\n\n");  // a finite quaternion of infinite length
  ExpectIoError(dir, {"images.txt:1:", "quaternion"});
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 0 0 1 a.png\n\n");
  WriteText(dir + "/points3D.txt", "# points\n7 0 inf 0 128 128 128 0\n");
  ExpectIoError(dir, {"points3D.txt:2:", "Y", "'inf' is not a finite number"});
  WriteText(dir + "/cameras.txt", "1 PINHOLE 640 480 500 NaN 320 240\n");
  WriteText(dir + "/points3D.txt", "");
  ExpectIoError(dir, {"cameras.txt:1:", "NaN"});
}

TEST(ColmapTextIo, UnknownModelListsValidOnes) {
  const std::string dir = MakeTestDir();
  WriteText(dir + "/cameras.txt", "# c\n1 PINHOLE 10 10 5 5 5 5\n2 FISHEYE 10 10 5 5 5 0.1\n");
  WriteText(dir + "/images.txt", "");
  ExpectIoError(dir, {"cameras.txt:3:", "FISHEYE", "SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL",
                      "RADIAL", "OPENCV"});
}

TEST(ColmapTextIo, WrongParamCountNamesModel) {
  const std::string dir = MakeTestDir();
  WriteText(dir + "/cameras.txt", "1 OPENCV 10 10 5 5 5 5\n");
  WriteText(dir + "/images.txt", "");
  ExpectIoError(dir, {"cameras.txt:1:", "OPENCV", "8", "got 4"});
}

TEST(ColmapTextIo, MissingFileSaysWhichAndWhatToDo) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  ExpectIoError(dir, {"images.txt", "not found"});
  WriteText(dir + "/images.bin", "binary");
  ExpectIoError(dir, {"images.txt", "model_converter"});
}

TEST(ColmapTextIo, MissingCameraIsInconsistent) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 0 0 4 a.png\n\n");
  ExpectIoError(dir, {"camera 4", "a.png"});
}

TEST(ColmapTextIo, ObservationOfMissingPointIsInconsistent) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 0 0 1 a.png\n1 2 5\n");
  WriteText(dir + "/points3D.txt", "");
  ExpectIoError(dir, {"a.png", "3D point 5"});
}

TEST(ColmapTextIo, BadTrackNamesLine) {
  const std::string dir = MakeTestDir();
  WriteOneCamera(dir);
  WriteText(dir + "/images.txt", "1 1 0 0 0 0 0 0 1 a.png\n\n");
  WriteText(dir + "/points3D.txt", "# p\n1 0 0 0 255 0 0 0.5 1\n");
  ExpectIoError(dir, {"points3D.txt:2:", "TRACK"});
  WriteText(dir + "/points3D.txt", "1 0 0 0 256 0 0 0.5\n");
  ExpectIoError(dir, {"points3D.txt:1:", "R", "256"});
}

}  // namespace
}  // namespace ibmr
