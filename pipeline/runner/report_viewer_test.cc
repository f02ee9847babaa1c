// The viewer's data: each model read from the workspace and made page-sized; an unreadable file
// is an entry with the reason, never an exception; cameras carry their held-out score; a volume
// folder in the documented shape becomes a stack of quads at the right place.
#include "pipeline/runner/report_viewer.h"

#include "pipeline/core/gaussian_splats.h"

#include "pipeline/core/plane_volume.h"

#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>

#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/textured_mesh.h"
#include "pipeline/runner/report_encoding.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

// A tetrahedron with vertex colours.
TriangleMesh Tetrahedron() {
  TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  mesh.colors = {Color3u8(255, 0, 0), Color3u8(0, 255, 0), Color3u8(0, 0, 255), Color3u8(255, 255, 0)};
  mesh.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return mesh;
}

// An n x n grid of squares in z = 0, its faces alternately on two atlas pages.
TexturedMesh TexturedGrid(int n) {
  TexturedMesh textured;
  for (int y = 0; y <= n; ++y) {
    for (int x = 0; x <= n; ++x) textured.mesh.vertices.emplace_back(static_cast<float>(x) / n, static_cast<float>(y) / n, 0.f);
  }
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const int a = y * (n + 1) + x, b = a + 1, c = a + n + 1, d = c + 1;
      for (const Eigen::Vector3i& f : {Eigen::Vector3i(a, b, d), Eigen::Vector3i(a, d, c)}) {
        textured.mesh.faces.push_back(f);
        Eigen::Matrix<float, 3, 2> uv;
        for (int k = 0; k < 3; ++k) uv.row(k) = textured.mesh.vertices[f[k]].head<2>().transpose();
        textured.face_uv.push_back(uv);
        textured.face_page.push_back(static_cast<int>(textured.face_page.size() % 2));
      }
    }
  }
  textured.pages = {cv::Mat(64, 64, CV_8UC3, cv::Scalar(0, 0, 255)), cv::Mat(32, 48, CV_8UC3, cv::Scalar(255, 0, 0))};
  return textured;
}

const nlohmann::json* Model(const ViewerData& data, const std::string& name) {
  for (const auto& m : data.viewer["models"]) {
    if (m["name"] == name) return &m;
  }
  return nullptr;
}

TEST(ReportViewer, DefaultsAreValidAndRangesAreChecked) {
  std::string error;
  EXPECT_TRUE(ViewerOptions().Check(&error)) << error;
  ViewerOptions options;
  options.max_faces = 0;
  EXPECT_FALSE(options.Check(&error));
  EXPECT_NE(error.find("report.max_faces"), std::string::npos) << error;
  options = {};
  options.max_points = -1;
  EXPECT_FALSE(options.Check(&error));
  options = {};
  options.max_texture_size = 8;
  EXPECT_FALSE(options.Check(&error));
  options = {};
  options.max_plane_size = 20000;
  EXPECT_FALSE(options.Check(&error));
}

TEST(ReportViewer, AWorkspaceWithoutModelsHasNone) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_viewer_empty");
  const ViewerData data = GatherViewer(ws.string(), nlohmann::json::object(), "photo_psnr", {});
  EXPECT_TRUE(data.viewer["models"].empty());
  EXPECT_TRUE(data.viewer["cameras"].empty());
  EXPECT_TRUE(data.arrays.empty());
}

TEST(ReportViewer, ModelsInTheirOrderDecimatedToTheBudget) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_viewer_models");
  WriteTexturedGlb(TexturedGrid(40), (ws / "texture/mesh.glb").string());  // 3,200 faces
  WriteMeshPly((ws / "hull/hull.ply").string(), Tetrahedron());
  PointCloud cloud;
  for (int i = 0; i < 1000; ++i) cloud.positions.emplace_back(i * 0.001f, 0.f, 0.f);
  WritePointCloudPly((ws / "dense/fused.ply").string(), cloud);
  ViewerOptions options;
  options.max_faces = 1000;
  options.max_points = 100;
  const ViewerData data = GatherViewer(ws.string(), nlohmann::json::object(), "photo_psnr", options);
  std::vector<std::string> names;
  for (const auto& m : data.viewer["models"]) names.push_back(m["name"]);
  EXPECT_EQ(names, (std::vector<std::string>{"textured mesh", "fused points", "hull"}));

  const nlohmann::json& textured = *Model(data, "textured mesh");
  ASSERT_FALSE(textured.contains("error")) << textured["error"];
  EXPECT_EQ(textured["elements"], 3200);
  EXPECT_LE(textured["shown"].get<int>(), 1000);
  EXPECT_GT(textured["shown"].get<int>(), 200);
  EXPECT_TRUE(textured["decimated"].get<bool>());
  ASSERT_EQ(textured["parts"].size(), 2u);  // one per atlas page
  for (const auto& part : textured["parts"]) {
    EXPECT_EQ(part["texture"].get<std::string>().rfind("data:image/jpeg;base64,", 0), 0u);
    EXPECT_TRUE(part.contains("uv") && part.contains("index") && part.contains("position"));
  }
  const nlohmann::json& points = *Model(data, "fused points");
  EXPECT_EQ(points["elements"], 1000);
  EXPECT_EQ(points["shown"], 100);
  const nlohmann::json& hull = *Model(data, "hull");
  EXPECT_EQ(hull["shown"], 4);
  EXPECT_FALSE(hull["decimated"].get<bool>());
  ASSERT_EQ(hull["parts"].size(), 1u);
  EXPECT_TRUE(hull["parts"][0].contains("color"));
  // The arrays each model names are there, with their lengths (4 vertices x 3 floats = 48 bytes).
  std::map<std::string, std::string> arrays(data.arrays.begin(), data.arrays.end());
  EXPECT_EQ(arrays.at(hull["parts"][0]["position"]).size(), 64u);  // base64 of 48 bytes
  EXPECT_EQ(arrays.at(hull["parts"][0]["index"]).size(), 64u);     // 4 faces x 3 x 4 bytes
  EXPECT_NE(ViewerArraysHtml(data).find("<script type=\"application/octet-stream\" id=\"" + hull["parts"][0]["position"].get<std::string>()),
            std::string::npos);
}

// The fitted splats are points at their centres in their DC colour; nearly transparent ones are
// left out and the rest subsampled to the budget.
TEST(ReportViewer, FittedSplatsArePointsInTheirColour) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_viewer_splats");
  GaussianSplats splats;
  for (int i = 0; i < 300; ++i) {
    splats.Add(Eigen::Vector3f(0.01f * i, 0.f, 1.f), Eigen::Vector4f(1, 0, 0, 0), Eigen::Vector2f(-4, -4),
               i < 100 ? 0.05f : 0.8f, Eigen::Vector3f(1.f, 0.5f, 0.f));
  }
  WriteGaussianSplatsPly((ws / "splat_fit/splats.ply").string(), splats);
  ViewerOptions options;
  options.max_points = 50;
  const ViewerData data = GatherViewer(ws.string(), nlohmann::json::object(), "photo_psnr", options);
  const nlohmann::json* model = Model(data, "fitted splats");
  ASSERT_NE(model, nullptr);
  ASSERT_FALSE(model->contains("error")) << (*model)["error"];
  EXPECT_EQ((*model)["elements"], 200);  // the opaque ones
  EXPECT_NE((*model)["unit"].get<std::string>().find("of 300"), std::string::npos);
  EXPECT_EQ((*model)["shown"], 50);
  std::map<std::string, std::string> arrays(data.arrays.begin(), data.arrays.end());
  // Every shown splat is orange (255, 127.5 rounded either way, 0).
  const std::string colors = arrays.at((*model)["parts"][0]["color"]);
  bool orange = false;
  for (uint8_t green : {127, 128}) {
    std::vector<uint8_t> expected;
    for (int i = 0; i < 50; ++i) expected.insert(expected.end(), {255, green, 0});
    orange |= colors == Base64(expected.data(), expected.size());
  }
  EXPECT_TRUE(orange);
  // The first shown centre is the first opaque splat's (the transparent first hundred are not shown).
  const Eigen::Vector3f first = splats.position[100];
  EXPECT_EQ(arrays.at((*model)["parts"][0]["position"]).substr(0, 16), Base64(first.data(), 12));
}

TEST(ReportViewer, UnreadableModelsCarryTheReason) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_viewer_corrupt");
  WriteFileAtomic((ws / "texture/mesh.glb").string(), "glTF not really");
  WriteFileAtomic((ws / "surfels/mesh.ply").string(), "ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x01");
  WriteMeshPly((ws / "hull/hull.ply").string(), Tetrahedron());
  const ViewerData data = GatherViewer(ws.string(), nlohmann::json::object(), "photo_psnr", {});
  ASSERT_EQ(data.viewer["models"].size(), 3u);
  const std::string glb_error = (*Model(data, "textured mesh")).value("error", "");
  EXPECT_NE(glb_error.find("texture/mesh.glb"), std::string::npos) << glb_error;
  EXPECT_NE(glb_error.find("re-run the texture stage"), std::string::npos) << glb_error;
  const std::string ply_error = (*Model(data, "surfel mesh")).value("error", "");
  EXPECT_NE(ply_error.find("surfels/mesh.ply"), std::string::npos) << ply_error;
  EXPECT_FALSE(Model(data, "hull")->contains("error"));
}

TEST(ReportViewer, CamerasCarryTheirBestHeldOutScore) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_viewer_cameras");
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(100, 80, 100, 100, 50, 40);
  for (int id = 1; id <= 2; ++id) {
    Image image;
    image.image_id = id;
    image.camera_id = 1;
    image.name = "view" + std::to_string(id) + ".png";
    image.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, id));
    model.images[id] = image;
  }
  WriteSparseModelText((ws / "sparse").string(), model);
  const nlohmann::json scores = {{"heldout", {"view2.png"}},
                                 {"proxies", {{"hull", {{"views", {{"view2.png", {{"photo_psnr", 20.5}}}}}}},
                                              {"surfels", {{"views", {{"view2.png", {{"photo_psnr", 24.25}}}}}}},
                                              {"broken", 3}}}};
  const ViewerData data = GatherViewer(ws.string(), scores, "photo_psnr", {});
  const nlohmann::json& cameras = data.viewer["cameras"];
  ASSERT_EQ(cameras.size(), 2u);
  EXPECT_FALSE(cameras[0]["heldout"].get<bool>());
  EXPECT_FALSE(cameras[0].contains("score"));
  EXPECT_TRUE(cameras[1]["heldout"].get<bool>());
  EXPECT_DOUBLE_EQ(cameras[1]["score"].get<double>(), 24.25);
  EXPECT_EQ(cameras[1]["model"], "surfels");
  // Centre -R^T t; the image's top-left corner at unit depth: ((0 - 50) / 100, (0 - 40) / 100, 1).
  EXPECT_DOUBLE_EQ(cameras[1]["center"][2].get<double>(), -2.0);
  EXPECT_DOUBLE_EQ(cameras[1]["corners"][0].get<double>(), -0.5);
  EXPECT_DOUBLE_EQ(cameras[1]["corners"][1].get<double>(), -0.4);
  EXPECT_DOUBLE_EQ(cameras[1]["corners"][2].get<double>(), 1.0);
  // Up: the training camera's -y.
  EXPECT_DOUBLE_EQ(data.viewer["up"][1].get<double>(), -1.0);
  EXPECT_FALSE(cameras[0].contains("flagged"));
  // multi_depth's per-view flag (issue 67): a flagged view is marked for the viewer to colour.
  fs::create_directories(ws / "dense/stereo");
  WriteFileAtomic((ws / "dense/stereo/view_agreement.json").string(), R"({"flagged": ["view1.png"], "views": []})");
  const ViewerData flagged = GatherViewer(ws.string(), scores, "photo_psnr", {});
  EXPECT_TRUE(flagged.viewer["cameras"][0].value("flagged", false));
  EXPECT_FALSE(flagged.viewer["cameras"][1].contains("flagged"));
}

// A volume folder as the volume stage writes it (pipeline/core/plane_volume.h), with `planes` of
// its three plane files left.
void WriteVolume(const fs::path& folder, int planes) {
  PlaneVolume volume;
  volume.camera = Camera::Pinhole(40, 20, 40.0, 40.0, 20.0, 10.0);
  volume.cam_from_world = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 1));
  volume.depths = {2.0, 3.0, 4.0};
  volume.Allocate();
  for (int k = 0; k < 3; ++k) {
    for (size_t i = 0; i < volume.PlaneFloats(); i += 4) {
      const float cell[4] = {40.f * k / 255.f, 100.f / 255.f, 200.f / 255.f, 128.f / 255.f};
      std::copy(cell, cell + 4, volume.Plane(k) + i);
    }
  }
  WritePlaneVolume(folder.string(), volume);
  for (int k = planes; k < 3; ++k) fs::remove(folder / ("plane_00" + std::to_string(k) + ".png"));
}

TEST(ReportViewer, VolumePlanesAreQuadsAtTheirDepth) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_viewer_volume");
  WriteVolume(ws / "volume/view1.png", 3);
  WriteVolume(ws / "volume/view2.png", 2);  // one plane image missing
  WriteFileAtomic((ws / "volume/view3.png/volume.json").string(), R"({"format": "ibmr_plane_volume", "width": 40})");
  const ViewerData data = GatherViewer(ws.string(), nlohmann::json::object(), "photo_psnr", {});
  ASSERT_EQ(data.viewer["models"].size(), 3u);
  const nlohmann::json& volume = *Model(data, "volume view1.png");
  ASSERT_FALSE(volume.contains("error")) << volume["error"];
  EXPECT_EQ(volume["kind"], "planes");
  ASSERT_EQ(volume["planes"].size(), 3u);
  // Plane 1 at depth 3: image corner (0, 0) at camera (-20/40 * 3, -10/40 * 3, 3); the world is
  // the camera frame moved back by t = (0, 0, 1).
  const nlohmann::json& corners = volume["planes"][1]["corners"];
  EXPECT_DOUBLE_EQ(corners[0].get<double>(), -1.5);
  EXPECT_DOUBLE_EQ(corners[1].get<double>(), -0.75);
  EXPECT_DOUBLE_EQ(corners[2].get<double>(), 2.0);
  EXPECT_DOUBLE_EQ(corners[6].get<double>(), 1.5);  // corner (W, H)
  EXPECT_EQ(volume["planes"][1]["texture"].get<std::string>().rfind("data:image/png;base64,", 0), 0u);
  const std::string missing = (*Model(data, "volume view2.png")).value("error", "");
  EXPECT_NE(missing.find("plane_002.png does not exist"), std::string::npos) << missing;
  const std::string incomplete = (*Model(data, "volume view3.png")).value("error", "");
  EXPECT_NE(incomplete.find("height"), std::string::npos) << incomplete;
}

}  // namespace
}  // namespace ibmr
