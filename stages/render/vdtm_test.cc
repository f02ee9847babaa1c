// Tests of view-dependent texture mapping (vdtm.h; seed 003 §7-8) on a plane seen by three
// source views, each photo one constant colour, so that a pixel's colour spells its weights:
// a desired camera at a source reproduces it (weight 1), between sources the weights sum to 1
// and the colour is their blend, faces no view sees take the atlas (hole filling, §6), a
// projection outside its photo drops that view, leave-one-out never samples the own photo.
#include "stages/render/vdtm.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/rasterizer.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_render(StageRegistry* registry);

namespace {

constexpr int kSize = 160;
constexpr int kCells = 8;  // the plane is kCells x kCells squares of two triangles
const cv::Vec3b kAtlas(77, 77, 77);
const cv::Vec3b kColors[3] = {cv::Vec3b(255, 0, 0), cv::Vec3b(0, 255, 0), cv::Vec3b(0, 0, 255)};  // BGR
const Eigen::Vector3d kCenters[3] = {{0, 0, 4}, {2.5, 0, 3}, {-1.5, 2.2, 3}};

Camera TestCamera() { return Camera::Pinhole(kSize, kSize, 100, 100, kSize / 2.0, kSize / 2.0); }
Rigid3d PoseAt(const Eigen::Vector3d& eye) { return LookAt(eye, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0)); }

// The square [-1, 1]^2 at z = 0, counter-clockwise seen from +z, its atlas one grey page.
TexturedMesh Plane() {
  TexturedMesh textured;
  for (int j = 0; j <= kCells; ++j) {
    for (int i = 0; i <= kCells; ++i) {
      textured.mesh.vertices.emplace_back(-1.f + 2.f * i / kCells, -1.f + 2.f * j / kCells, 0.f);
    }
  }
  const auto uv_of = [&](int v) {
    const Eigen::Vector3f& p = textured.mesh.vertices[v];
    return Eigen::RowVector2f((p.x() + 1) / 2, (p.y() + 1) / 2);
  };
  for (int j = 0; j < kCells; ++j) {
    for (int i = 0; i < kCells; ++i) {
      const int a = j * (kCells + 1) + i, b = a + 1, c = a + kCells + 2, d = a + kCells + 1;
      for (const Eigen::Vector3i& face : {Eigen::Vector3i(a, b, c), Eigen::Vector3i(a, c, d)}) {
        textured.mesh.faces.push_back(face);
        Eigen::Matrix<float, 3, 2> uv;
        for (int k = 0; k < 3; ++k) uv.row(k) = uv_of(face[k]);
        textured.face_uv.push_back(uv);
        textured.face_page.push_back(0);
      }
    }
  }
  textured.pages = {cv::Mat(16, 16, CV_8UC3, cv::Scalar(kAtlas[0], kAtlas[1], kAtlas[2]))};
  return textured;
}

// Faces in the corner x, y < -0.5 are seen by no view.
bool Hidden(const TexturedMesh& mesh, int face) {
  Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
  for (int k = 0; k < 3; ++k) centroid += mesh.mesh.vertices[mesh.mesh.faces[face][k]] / 3.f;
  return centroid.x() < -0.5f && centroid.y() < -0.5f;
}

// View maps of the plane for the three views (every view sees every face but the hidden ones).
ViewMaps Maps(const TexturedMesh& mesh, int grid = 32) {
  ViewMaps maps;
  maps.grid = grid;
  maps.view_names = {"a", "b", "c"};
  for (size_t f = 0; f < mesh.mesh.faces.size(); ++f) {
    FaceViewMap face;
    if (!Hidden(mesh, static_cast<int>(f))) {
      const Eigen::Vector3i& v = mesh.mesh.faces[f];
      const Eigen::Vector3d a = mesh.mesh.vertices[v[0]].cast<double>(), b = mesh.mesh.vertices[v[1]].cast<double>(),
                            c = mesh.mesh.vertices[v[2]].cast<double>();
      const Eigen::Matrix3d frame = FaceFrame((b - a).cross(c - a).normalized());
      const Eigen::Vector3d centroid = (a + b + c) / 3;
      for (uint16_t k = 0; k < 3; ++k) {
        face.views.push_back(k);
        face.directions.push_back(MapDirection(frame, (kCenters[k] - centroid).normalized()).cast<float>());
      }
      BuildGrid(grid, &face);
    }
    maps.faces.push_back(face);
  }
  return maps;
}

SourceView Source(int k, const Camera& camera = TestCamera()) {
  SourceView view;
  view.name = std::string(1, static_cast<char>('a' + k));
  view.camera = camera;
  view.cam_from_world = PoseAt(kCenters[k]);
  view.image = cv::Mat(camera.height, camera.width, CV_8UC3, cv::Scalar(kColors[k][0], kColors[k][1], kColors[k][2]));
  return view;
}

std::vector<SourceView> Sources() { return {Source(0), Source(1), Source(2)}; }

struct Fixture {
  TexturedMesh mesh = Plane();
  ViewMaps maps = Maps(mesh);
};

TEST(Vdtm, DesiredAtASourceReproducesIt) {
  const Fixture fx;
  const std::vector<SourceView> sources = Sources();
  const VdtmRenderer renderer(&fx.mesh, &fx.maps, &sources);
  EXPECT_EQ(renderer.MatchedViews(), 3);
  for (int k = 0; k < 3; ++k) {
    for (size_t f = 0; f < fx.mesh.mesh.faces.size(); ++f) {
      if (Hidden(fx.mesh, static_cast<int>(f))) continue;
      const FaceBlend blend = renderer.Blend(static_cast<int>(f), kCenters[k]);
      ASSERT_EQ(blend.count, 1) << "view " << k << " face " << f;
      EXPECT_EQ(blend.sources[0], k);
      EXPECT_FLOAT_EQ(blend.weights[0], 1.f);
    }
    VdtmStats stats;
    const RenderResult result = renderer.Render(TestCamera(), PoseAt(kCenters[k]), -1, &stats);
    const RasterResult raster = Rasterize(fx.mesh.mesh, TestCamera(), PoseAt(kCenters[k]));
    size_t checked = 0;
    for (int y = 0; y < kSize; ++y) {
      for (int x = 0; x < kSize; ++x) {
        const int face = raster.face_id[static_cast<size_t>(y) * kSize + x];
        EXPECT_EQ(result.coverage.at<uint8_t>(y, x), face >= 0 ? 255 : 0);
        if (face < 0) continue;
        const cv::Vec3b expected = Hidden(fx.mesh, face) ? kAtlas : kColors[k];
        ASSERT_EQ(result.image.at<cv::Vec3b>(y, x), expected) << "view " << k << " pixel " << x << "," << y;
        ++checked;
      }
    }
    EXPECT_GT(checked, 1000u);
    EXPECT_GT(stats.atlas_pixels, 0u);
    EXPECT_EQ(stats.atlas_pixels + stats.blended_pixels, result.covered_pixels);
  }
}

TEST(Vdtm, BetweenSourcesWeightsSumToOneAndColoursBlend) {
  const Fixture fx;
  const std::vector<SourceView> sources = Sources();
  const VdtmRenderer renderer(&fx.mesh, &fx.maps, &sources);
  const Eigen::Vector3d center = 0.5 * (kCenters[0] + kCenters[1]) + Eigen::Vector3d(0, 0.3, 0);
  const RenderResult result = renderer.Render(TestCamera(), PoseAt(center));
  const RasterResult raster = Rasterize(fx.mesh.mesh, TestCamera(), PoseAt(center));
  size_t mixed = 0;
  for (int y = 0; y < kSize; ++y) {
    for (int x = 0; x < kSize; ++x) {
      const int face = raster.face_id[static_cast<size_t>(y) * kSize + x];
      if (face < 0 || Hidden(fx.mesh, face)) continue;
      const FaceBlend blend = renderer.Blend(face, center);
      ASSERT_GE(blend.count, 1);
      ASSERT_LE(blend.count, 3);
      float sum = 0;
      cv::Vec3f expected(0, 0, 0);
      for (int i = 0; i < blend.count; ++i) {
        EXPECT_GE(blend.weights[i], 0.f);
        sum += blend.weights[i];
        expected += blend.weights[i] * cv::Vec3f(kColors[blend.sources[i]]);
        for (int j = 0; j < i; ++j) EXPECT_NE(blend.sources[i], blend.sources[j]);
      }
      EXPECT_NEAR(sum, 1.f, 1e-5);
      const cv::Vec3b got = result.image.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(got[c], expected[c], 1.0) << x << "," << y;
      mixed += blend.count >= 2 && got[0] > 10 && got[1] > 10;  // blue of a and green of b together
    }
  }
  EXPECT_GT(mixed, 100u);
}

TEST(Vdtm, ProjectionOutsideItsPhotoDropsTheView) {
  const Fixture fx;
  // View a's photo covers only world x > -0.8: u = 20 + 100 x / 4 < 0 left of that.
  std::vector<SourceView> sources = {Source(0, Camera::Pinhole(kSize, kSize, 100, 100, 20, kSize / 2.0)), Source(1),
                                     Source(2)};
  const VdtmRenderer renderer(&fx.mesh, &fx.maps, &sources);
  const Camera camera = TestCamera();
  const RenderResult result = renderer.Render(camera, PoseAt(kCenters[0]));
  size_t dropped = 0, kept = 0;
  for (int y = 0; y < kSize; ++y) {
    for (int x = 0; x < kSize; ++x) {
      const Eigen::Vector3d ray = PoseAt(kCenters[0]).Inverse().rotation * camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
      const Eigen::Vector3d p = kCenters[0] - kCenters[0].z() / ray.z() * ray;
      if (std::abs(p.x()) > 0.99 || std::abs(p.y()) > 0.99 || (p.x() < -0.45 && p.y() < -0.45)) continue;
      if (p.x() < -0.85) {  // a's only view is outside its photo: the face's next view by direction
        const cv::Vec3b got = result.image.at<cv::Vec3b>(y, x);
        EXPECT_TRUE(got == kColors[1] || got == kColors[2]) << x << "," << y << ": " << got;
        ++dropped;
      } else if (p.x() > -0.75) {
        EXPECT_EQ(result.image.at<cv::Vec3b>(y, x), kColors[0]) << x << "," << y;
        ++kept;
      }
    }
  }
  EXPECT_GT(dropped, 20u);
  EXPECT_GT(kept, 1000u);
}

TEST(Vdtm, LeaveOneOutNeverSamplesTheOwnPhoto) {
  const Fixture fx;
  const std::vector<SourceView> sources = Sources();
  const VdtmRenderer renderer(&fx.mesh, &fx.maps, &sources);
  for (int k = 0; k < 3; ++k) {
    for (size_t f = 0; f < fx.mesh.mesh.faces.size(); ++f) {
      const FaceBlend blend = renderer.Blend(static_cast<int>(f), kCenters[k], k);
      if (Hidden(fx.mesh, static_cast<int>(f))) {
        EXPECT_EQ(blend.count, 0);
        continue;
      }
      ASSERT_GE(blend.count, 1);  // the other views still see the face
      float sum = 0;
      for (int i = 0; i < blend.count; ++i) {
        EXPECT_NE(blend.sources[i], k);
        sum += blend.weights[i];
      }
      EXPECT_NEAR(sum, 1.f, 1e-5);
    }
    const RenderResult result = renderer.Render(TestCamera(), PoseAt(kCenters[k]), k);
    const int channel = k;  // colour k is pure in channel k (BGR)
    for (int y = 0; y < kSize; ++y) {
      for (int x = 0; x < kSize; ++x) {
        if (!result.coverage.at<uint8_t>(y, x)) continue;
        const cv::Vec3b got = result.image.at<cv::Vec3b>(y, x);
        if (got == kAtlas) continue;
        EXPECT_EQ(got[channel], 0) << "view " << k << " pixel " << x << "," << y;
      }
    }
  }
}

TEST(Vdtm, ViewsWithoutASourceAreNeverUsed) {
  const Fixture fx;
  const std::vector<SourceView> sources = {Source(0), Source(1)};  // "c" is held out
  const VdtmRenderer renderer(&fx.mesh, &fx.maps, &sources);
  EXPECT_EQ(renderer.MatchedViews(), 2);
  const RenderResult result = renderer.Render(TestCamera(), PoseAt(kCenters[2]));
  size_t covered = 0;
  for (int y = 0; y < kSize; ++y) {
    for (int x = 0; x < kSize; ++x) {
      if (!result.coverage.at<uint8_t>(y, x) || result.image.at<cv::Vec3b>(y, x) == kAtlas) continue;
      ++covered;
      EXPECT_EQ(result.image.at<cv::Vec3b>(y, x)[2], 0) << x << "," << y;  // no red of c
    }
  }
  EXPECT_GT(covered, 1000u);
}

// The plane seen from below (z < 0) shows its back, the inside no photo shows: vdtm draws none of
// it, where the rasterizer without culling covers most of the image.
TEST(Vdtm, BackFacesAreNotDrawn) {
  const Fixture fx;
  const std::vector<SourceView> sources = Sources();
  const VdtmRenderer renderer(&fx.mesh, &fx.maps, &sources);
  const Eigen::Vector3d below(0.3, 0.2, -4);
  const RasterResult raster = Rasterize(fx.mesh.mesh, TestCamera(), PoseAt(below));
  size_t drawable = 0;
  for (const int face : raster.face_id) drawable += face >= 0;
  ASSERT_GT(drawable, 1000u);
  VdtmStats stats;
  const RenderResult result = renderer.Render(TestCamera(), PoseAt(below), -1, &stats, 2);
  EXPECT_EQ(result.covered_pixels, 0u);
  EXPECT_EQ(cv::countNonZero(result.coverage), 0);
  EXPECT_EQ(stats.blended_pixels + stats.atlas_pixels, 0u);
  // From above, the same renderer draws the plane.
  EXPECT_GT(renderer.Render(TestCamera(), PoseAt(Eigen::Vector3d(0.3, 0.2, 4))).covered_pixels, 1000u);
}

TEST(Vdtm, FaceCountMismatchIsAnInputError) {
  const Fixture fx;
  ViewMaps maps = fx.maps;
  maps.faces.pop_back();
  const std::vector<SourceView> sources = Sources();
  EXPECT_THROW(VdtmRenderer(&fx.mesh, &maps, &sources), InputError);
}

// The adapter on a tiny workspace: the three photos as training views, a held-out view between a
// and b, the texture stage's files written by their writers; then without view_maps.bin, then
// without mesh.obj: the models are skipped, naming the file.
class VdtmStage : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() / ("ibmr_render_vdtm_test_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_ / "images");
    SparseModel model;
    model.cameras[1] = TestCamera();
    const Eigen::Vector3d centers[4] = {kCenters[0], kCenters[1], kCenters[2], kBetween};
    for (int i = 0; i < 4; ++i) {
      Image image;
      image.image_id = i + 1;
      image.camera_id = 1;
      image.name = std::string(1, static_cast<char>('a' + i)) + ".png";
      image.cam_from_world = PoseAt(centers[i]);
      model.images[image.image_id] = image;
      const cv::Vec3b color = i < 3 ? kColors[i] : cv::Vec3b(9, 9, 9);
      WriteImage((root_ / "images" / image.name).string(),
                 cv::Mat(kSize, kSize, CV_8UC3, cv::Scalar(color[0], color[1], color[2])));
    }
    WriteSparseModelText((root_ / "sparse").string(), model);
    const Fixture fx;
    fs::create_directories(root_ / "texture");
    WriteTexturedObj(fx.mesh, (root_ / "texture").string(), "mesh");
    ViewMaps maps = fx.maps;
    maps.view_names = {"a.png", "b.png", "c.png"};
    WriteViewMaps(maps, (root_ / "texture/view_maps.bin").string());
  }
  void TearDown() override { fs::remove_all(root_); }

  // Runs the stage with `proxies`, rendering d.png (held out) and a.png (a training view,
  // leave-one-out); returns renders.json.
  nlohmann::json Run(const std::vector<std::string>& proxies, nlohmann::json* metrics) {
    StageRegistry registry;
    RegisterStage_render(&registry);
    const Stage* stage = registry.Find("render");
    EXPECT_NE(stage, nullptr);
    StageContext context;
    context.workspace = Workspace(root_.string());
    context.role = stage->Role();
    context.heldout_images = {"d.png"};
    for (const ParamSpec& spec : stage->Parameters()) {
      if (spec.type == ParamType::kString) {
        context.params.Set(spec.key, spec.default_yaml);
      } else if (spec.type == ParamType::kInt) {
        context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
      } else if (spec.type == ParamType::kDouble) {
        context.params.Set(spec.key, std::stod(spec.default_yaml));
      } else if (spec.type == ParamType::kBool) {
        context.params.Set(spec.key, spec.default_yaml == "true");
      } else if (spec.type == ParamType::kDoubleList) {
        context.params.Set(spec.key, std::vector<double>{});
      } else {
        context.params.Set(spec.key, std::vector<std::string>{});
      }
    }
    context.params.Set("proxies", proxies);
    context.params.Set("views", std::vector<std::string>{"d.png", "a.png"});
    context.params.Set("supersample", int64_t{2});
    EXPECT_FALSE(stage->CheckParams(context.params).has_value());
    const std::vector<std::string> inputs = stage->Inputs(context);
    EXPECT_NE(std::find(inputs.begin(), inputs.end(), "texture"), inputs.end());
    NullProgress progress;
    context.progress = &progress;
    stage->Run(context);
    *metrics = context.metrics;
    return nlohmann::json::parse(std::ifstream((root_ / "renders/renders.json").string()));
  }

  static inline const Eigen::Vector3d kBetween = 0.5 * (kCenters[0] + kCenters[1]) + Eigen::Vector3d(0, 0.3, 0);
  fs::path root_;
};

TEST_F(VdtmStage, RendersTexturedAndVdtmAndTimesEveryModel) {
  nlohmann::json metrics;
  const nlohmann::json summary = Run({"vdtm", "textured", "plane"}, &metrics);
  ASSERT_EQ(summary["proxies"].size(), 3u);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(summary["proxies"][i]["status"], "rendered") << summary["proxies"][i];
  EXPECT_EQ(summary["primary"], "vdtm");
  EXPECT_EQ(summary["proxies"][0]["model"]["triangles"], 2 * kCells * kCells);
  EXPECT_EQ(summary["proxies"][0]["view_map_views_with_source"], 3);
  for (const char* model : {"vdtm", "textured", "plane"}) {
    ASSERT_TRUE(metrics.contains(std::string("ms_per_frame_") + model)) << metrics;
    EXPECT_GT(metrics[std::string("ms_per_frame_") + model].get<double>(), 0.0);
  }
  // The held-out view between a (blue) and b (green): a blend of both at the centre.
  const cv::Mat between = ReadImageColor((root_ / "renders/vdtm/d.png").string());
  const cv::Vec3b centre = between.at<cv::Vec3b>(kSize / 2, kSize / 2);
  EXPECT_GT(centre[0], 10);
  EXPECT_GT(centre[1], 10);
  EXPECT_EQ(centre[2], 0);
  // Training view a rendered leave-one-out: never its own blue.
  const cv::Mat own = ReadImageColor((root_ / "renders/vdtm/a.png").string());
  const cv::Mat coverage = ReadImageUnchanged((root_ / "renders/vdtm/a.coverage.png").string());
  size_t covered = 0;
  for (int y = 0; y < kSize; ++y) {
    for (int x = 0; x < kSize; ++x) {
      if (!coverage.at<uint8_t>(y, x)) continue;
      ++covered;
      const cv::Vec3b got = own.at<cv::Vec3b>(y, x);
      // Grey, green, red and their mixes have no more blue than min(green, red); any of a's blue has.
      EXPECT_LE(got[0], std::min(got[1], got[2]) + 2) << x << "," << y;
    }
  }
  EXPECT_GT(covered, 1000u);
  const nlohmann::json facts = nlohmann::json::parse(std::ifstream((root_ / "renders/vdtm/a.json").string()));
  EXPECT_EQ(facts["sources"], 2);
  EXPECT_GT(facts["atlas_fraction"].get<double>(), 0.0);
  // The textured model: the atlas's grey wherever the plane is.
  const cv::Mat flat = ReadImageColor((root_ / "renders/textured/d.png").string());
  EXPECT_EQ(flat.at<cv::Vec3b>(kSize / 2, kSize / 2), kAtlas);
}

TEST_F(VdtmStage, MissingTextureFilesAreSkippedNamingThem) {
  fs::remove(root_ / "texture/view_maps.bin");
  nlohmann::json metrics;
  nlohmann::json summary = Run({"vdtm", "textured", "plane"}, &metrics);
  EXPECT_EQ(summary["proxies"][0]["status"], "skipped");
  EXPECT_NE(summary["proxies"][0]["reason"].get<std::string>().find("texture/view_maps.bin"), std::string::npos);
  EXPECT_EQ(summary["proxies"][1]["status"], "rendered");
  EXPECT_EQ(summary["primary"], "textured");
  fs::remove(root_ / "texture/mesh.obj");
  summary = Run({"vdtm", "textured", "plane"}, &metrics);
  for (int i = 0; i < 2; ++i) {
    EXPECT_EQ(summary["proxies"][i]["status"], "skipped");
    EXPECT_NE(summary["proxies"][i]["reason"].get<std::string>().find("texture/mesh.obj"), std::string::npos);
  }
  EXPECT_EQ(summary["primary"], "plane");
}

}  // namespace
}  // namespace ibmr
