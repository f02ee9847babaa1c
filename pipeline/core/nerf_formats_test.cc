// Conventions of transforms.json and poses_bounds.npy (nerf_formats.h): round trips through the
// writers within 1e-9, OpenGL versus OpenCV camera axes, LLFF's [down, right, back] columns, the
// Blender layout (camera_angle_x, paths without extension), per-frame intrinsics, and errors.
#include "pipeline/core/nerf_formats.h"

#include <gtest/gtest.h>

#include <random>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

// Cameras on a ring looking at the origin, random tilts; `shared` one camera for all.
SparseModel Ring(int count, bool shared, bool centred) {
  SparseModel model;
  std::mt19937 random(7);
  std::uniform_real_distribution<double> jitter(-0.3, 0.3);
  for (int i = 0; i < count; ++i) {
    const int id = i + 1;
    if (!shared || i == 0) {
      const double f = shared ? 500 : 400 + 10 * i;
      Camera camera = centred ? Camera::Pinhole(640, 480, f, f, 320, 240) : Camera::Pinhole(640, 480, f, f * 1.01, 321.3, 238.9);
      camera.camera_id = id;
      model.cameras[id] = camera;
    }
    const double a = 2 * M_PI * i / count;
    const Eigen::Vector3d eye(3 * std::cos(a), 3 * std::sin(a), 1 + jitter(random));
    Image image;
    image.image_id = id;
    image.camera_id = shared ? 1 : id;
    image.name = "view_" + std::to_string(100 + i) + ".png";
    image.cam_from_world = LookAt(eye, Eigen::Vector3d(jitter(random), jitter(random), 0), Eigen::Vector3d(0, 0, 1));
    model.images[id] = image;
  }
  return model;
}

void ExpectSameCameras(const SparseModel& a, const SparseModel& b) {
  ASSERT_EQ(a.images.size(), b.images.size());
  for (const auto& [id, image] : a.images) {
    const Image* other = b.FindImage(image.name);
    ASSERT_NE(other, nullptr) << image.name;
    EXPECT_LT((image.cam_from_world.R() - other->cam_from_world.R()).norm(), 1e-9) << image.name;
    EXPECT_LT((image.Center() - other->Center()).norm(), 1e-9) << image.name;
    const Camera& ca = a.CameraOf(image);
    const Camera& cb = b.CameraOf(*other);
    EXPECT_EQ(ca.width, cb.width);
    EXPECT_EQ(ca.height, cb.height);
    EXPECT_NEAR(ca.FocalX(), cb.FocalX(), 1e-9);
    EXPECT_NEAR(ca.FocalY(), cb.FocalY(), 1e-9);
    EXPECT_NEAR(ca.PrincipalX(), cb.PrincipalX(), 1e-9);
    EXPECT_NEAR(ca.PrincipalY(), cb.PrincipalY(), 1e-9);
  }
}

const auto kNoImages = [](const std::string& name) -> std::pair<int, int> {
  throw IoError("no image " + name);
};

TEST(TransformsJson, RoundTripSharedAndPerFrameCameras) {
  for (const bool shared : {true, false}) {
    const SparseModel model = Ring(9, shared, false);
    const std::string text = WriteTransformsJson(model, "images/");
    std::vector<std::string> names;
    const SparseModel back = ParseTransformsJson(text, "t.json", kNoImages, &names);
    ASSERT_EQ(names.size(), 9u);
    EXPECT_EQ(names[0], "images/view_100.png");
    SparseModel renamed = back;  // the json's paths carry the folder
    for (auto& [id, image] : renamed.images) image.name = image.name.substr(7);
    ExpectSameCameras(model, renamed);
    EXPECT_EQ(back.cameras.size(), shared ? 1u : 9u);
  }
}

// OpenGL axes: a transform_matrix equal to the identity is a camera at the origin looking down
// world -z with world +y up in the image; in OpenCV terms its z axis is world -z and its y axis
// (image down) is world -y.
TEST(TransformsJson, OpenGlAxes) {
  const std::string text = R"({"fl_x": 100, "fl_y": 100, "cx": 50, "cy": 40, "w": 100, "h": 80,
    "frames": [{"file_path": "a.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})";
  std::vector<std::string> names;
  const SparseModel model = ParseTransformsJson(text, "t.json", kNoImages, &names);
  const Image& image = model.images.begin()->second;
  EXPECT_LT((image.ViewingDirection() - Eigen::Vector3d(0, 0, -1)).norm(), 1e-12);
  // A point up in the world (+y) in front of the camera projects above the principal point.
  const Eigen::Vector2d pixel = model.CameraOf(image).ImgFromCam(image.cam_from_world * Eigen::Vector3d(0, 1, -5));
  EXPECT_LT(pixel.y(), 40);
  EXPECT_NEAR(pixel.x(), 50, 1e-9);
}

// The Blender synthetic layout: camera_angle_x, sizes from the images, paths without extension.
TEST(TransformsJson, BlenderLayout) {
  const std::string text = R"({"camera_angle_x": 0.6911112070083618,
    "frames": [{"file_path": "./train/r_0", "rotation": 0.0,
                "transform_matrix": [[-1,0,0,0],[0,-0.7341,0.6790,2.7373],[0,0.6790,0.7341,2.9593],[0,0,0,1]]}]})";
  std::vector<std::string> names;
  const SparseModel model =
      ParseTransformsJson(text, "t.json", [](const std::string&) { return std::pair<int, int>(800, 800); }, &names);
  EXPECT_EQ(names[0], "train/r_0.png");
  const Camera& camera = model.cameras.at(1);
  EXPECT_EQ(camera.width, 800);
  EXPECT_NEAR(camera.FocalX(), 400 / std::tan(0.6911112070083618 / 2), 1e-9);  // 1111.11 px
  EXPECT_NEAR(camera.PrincipalX(), 400, 1e-12);
  // The camera looks back at the origin from (0, 2.74, 2.96).
  const Image& image = model.images.at(1);
  EXPECT_GT(image.ViewingDirection().dot(-image.Center().normalized()), 0.999);
}

TEST(TransformsJson, ErrorsNameTheFrame) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"[]", "frames"},
      {R"({"frames": [{"transform_matrix": []}]})", "frame 0"},
      {R"({"fl_x": 100, "w": 10, "h": 10, "frames": [{"file_path": "a.png", "transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})",
       "not a rigid"},
      {R"({"w": 10, "h": 10, "frames": [{"file_path": "a.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})",
       "camera_angle_x"},
      {R"({"fl_x": 10, "w": 10, "h": 10, "frames": [{"file_path": "../a.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]})",
       "relative"},
  };
  for (const auto& [text, what] : bad) {
    std::vector<std::string> names;
    try {
      ParseTransformsJson(text, "bad.json", kNoImages, &names);
      ADD_FAILURE() << "accepted " << text;
    } catch (const IoError& e) {
      EXPECT_NE(std::string(e.what()).find("bad.json"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
    }
  }
}

TEST(PosesBounds, RoundTripAndLlffColumns) {
  const SparseModel model = Ring(7, false, true);
  std::vector<std::string> names;
  std::vector<std::pair<double, double>> bounds;
  for (const int id : model.ImageIdsByName()) {
    names.push_back(model.images.at(id).name);
    bounds.emplace_back(1.5, 4.5 + id);
  }
  const std::string bytes = WritePosesBounds(model, names, bounds);
  EXPECT_EQ(bytes.compare(0, 6, "\x93NUMPY"), 0);
  std::vector<std::pair<double, double>> read_bounds;
  const SparseModel back = ParsePosesBounds(bytes, "poses_bounds.npy", names, 1, &read_bounds);
  ExpectSameCameras(model, back);
  EXPECT_EQ(read_bounds, bounds);
  // images_4: a quarter of the size and focal, same poses.
  const SparseModel quarter = ParsePosesBounds(bytes, "poses_bounds.npy", names, 4, nullptr);
  EXPECT_EQ(quarter.cameras.at(1).width, 160);
  EXPECT_NEAR(quarter.cameras.at(1).FocalX(), model.cameras.at(1).FocalX() / 4, 1e-9);
  // LLFF's first column is the camera's down axis: the world direction image rows grow along.
  double v[17];
  std::memcpy(v, bytes.data() + bytes.size() - 7 * sizeof(v), sizeof(v));
  const Image& first = model.images.at(model.ImageIdsByName()[0]);
  const Eigen::Vector3d down = first.cam_from_world.Inverse().rotation * Eigen::Vector3d(0, 1, 0);
  EXPECT_LT((Eigen::Vector3d(v[0], v[5], v[10]) - down).norm(), 1e-12);
  // Errors: wrong row count, not .npy.
  EXPECT_THROW(ParsePosesBounds(bytes, "p.npy", {"a.png"}, 1, nullptr), IoError);
  EXPECT_THROW(ParsePosesBounds("not numpy", "p.npy", names, 1, nullptr), IoError);
  EXPECT_THROW(ParsePosesBounds(bytes.substr(0, bytes.size() - 8), "p.npy", names, 1, nullptr), IoError);
}

}  // namespace
}  // namespace ibmr
