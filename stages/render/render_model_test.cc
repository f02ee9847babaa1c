// The render model registry (render_model.h, render_models.cc): entries parsed to their kinds,
// names, options, @N details and fallbacks; unknown entries refused with the list of kinds; the
// stage's `proxies` documentation and checks drawn from the registry; and the hole extension every
// mesh model shares (ExtendIntoHoles of a raster); the fitted splats drawn over the background
// colour fitted with them.
#include "stages/render/render_model.h"

#include <gtest/gtest.h>

#include <unistd.h>

#include <filesystem>
#include <set>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/gaussian_splats.h"
#include "pipeline/core/rasterizer.h"
#include "pipeline/runner/config.h"

namespace ibmr {

void RegisterStage_render(StageRegistry* registry);

namespace {

const Stage& RenderStage() {
  static StageRegistry* registry = [] {
    auto* r = new StageRegistry();
    RegisterStage_render(r);
    return r;
  }();
  return *registry->Find("render");
}

TEST(RenderModelKinds, KeywordsAreUniqueAndOneKindTakesMeshPaths) {
  std::set<std::string> keywords;
  int mesh_kinds = 0;
  for (const RenderModelKind& kind : RenderModelKinds()) {
    EXPECT_TRUE(keywords.insert(kind.keyword).second) << kind.keyword;
    mesh_kinds += kind.keyword.empty();
    EXPECT_FALSE(kind.syntax.empty());
    EXPECT_FALSE(kind.summary.empty()) << kind.syntax;
    EXPECT_NE(kind.make, nullptr) << kind.syntax;
  }
  EXPECT_EQ(mesh_kinds, 1);
  for (const std::string keyword :
       {"plane", "splat_depth", "splat_depth_merged", "splat_surfels", "textured", "vdtm", "layers"}) {
    EXPECT_TRUE(keywords.count(keyword)) << keyword;
  }
}

TEST(ModelEntry, EachKindParsesToItsModelAndName) {
  struct Case {
    std::string entry, keyword, name, path, source_path;
  };
  const Workspace workspace("/ws");
  const std::vector<Case> cases = {
      {"plane", "plane", "plane", "", "plane"},
      {"hull/hull.ply", "", "hull", "hull/hull.ply", "hull/hull.ply"},
      {"ground_truth/mesh.ply", "", "ground_truth_mesh", "ground_truth/mesh.ply", "ground_truth/mesh.ply"},
      {"/data/scan.ply", "", "data_scan", "/data/scan.ply", "/data/scan.ply"},
      {"surfels=surfels/mesh.ply", "", "surfels", "surfels/mesh.ply", "surfels/mesh.ply"},
      {"splat_depth", "splat_depth", "splat_depth", "", "dense/stereo"},
      {"splat_depth_merged", "splat_depth_merged", "splat_depth_merged", "", "dense/stereo"},
      {"splat_surfels", "splat_surfels", "splat_surfels", "", "surfels/surfels.ply"},
      {"textured", "textured", "textured", "", "texture/mesh.obj"},
      {"vdtm", "vdtm", "vdtm", "", "texture/mesh.obj"},
      {"layers", "layers", "layers", "", "layers"},
  };
  for (const Case& c : cases) {
    const ModelEntry entry = ParseModelEntry(c.entry);
    EXPECT_EQ(entry.keyword, c.keyword) << c.entry;
    EXPECT_EQ(entry.name, c.name) << c.entry;
    EXPECT_EQ(entry.path, c.path) << c.entry;
    EXPECT_EQ(CheckModelEntry(entry), "") << c.entry;
    const std::unique_ptr<RenderModel> model = MakeRenderModel(c.entry, workspace);
    EXPECT_EQ(model->Name(), c.name) << c.entry;
    EXPECT_EQ(model->SourcePath(workspace), c.source_path) << c.entry;
    EXPECT_EQ(model->IsBackground(), c.keyword == "plane") << c.entry;
    EXPECT_EQ(model->MadeFromEveryPhoto(), c.keyword == "textured" || c.keyword == "splat_surfels") << c.entry;
  }
  EXPECT_TRUE(MakeRenderModel("ground_truth/mesh.ply", workspace)->FromTruth(workspace));
  EXPECT_FALSE(MakeRenderModel("hull/hull.ply", workspace)->FromTruth(workspace));
}

TEST(ModelEntry, OptionsDetailsAndFallbacks) {
  ModelEntry entry = ParseModelEntry("splat_depth:truth");
  EXPECT_EQ(entry.keyword, "splat_depth");
  EXPECT_EQ(entry.option, "truth");
  EXPECT_EQ(entry.name, "splat_depth_truth");
  entry = ParseModelEntry("splat_depth_truth=splat_depth:truth");
  EXPECT_EQ(entry.name, "splat_depth_truth");
  EXPECT_EQ(ParseModelEntry("splat_depth_merged:photometric").name, "splat_depth_merged_photometric");

  entry = ParseModelEntry("splat_depth@4");
  EXPECT_EQ(entry.detail, 4);
  EXPECT_EQ(entry.name, "splat_depth_4");
  entry = ParseModelEntry("surfels_20k=surfels/mesh.ply@20000");
  EXPECT_EQ(entry.detail, 20000);
  EXPECT_EQ(entry.name, "surfels_20k");
  EXPECT_EQ(entry.path, "surfels/mesh.ply");
  EXPECT_EQ(ParseModelEntry("surfels/mesh.ply@5000").name, "surfels_mesh_5000");

  entry = ParseModelEntry("surfels_hull=surfels/mesh.ply@1000|hull/hull.ply|/abs/other.ply");
  EXPECT_EQ(entry.keyword, "");
  EXPECT_EQ(entry.path, "surfels/mesh.ply");
  EXPECT_EQ(entry.detail, 1000);
  EXPECT_EQ(entry.fallbacks, (std::vector<std::string>{"hull/hull.ply", "/abs/other.ply"}));
  const Workspace workspace("/ws");
  StageContext context;
  context.workspace = workspace;
  context.params = DefaultParams(RenderStage(), ".");
  EXPECT_EQ(MakeRenderModel("surfels_hull=surfels/mesh.ply|hull/hull.ply|/abs/other.ply", workspace)->Inputs(context),
            (std::vector<std::string>{"surfels/mesh.ply", "hull/hull.ply", "/abs/other.ply"}));
  EXPECT_EQ(MakeRenderModel("splat_depth:truth", workspace)->Inputs(context),
            std::vector<std::string>{"ground_truth/depth"});
  EXPECT_EQ(MakeRenderModel("vdtm", workspace)->Inputs(context), std::vector<std::string>{"texture"});
}

TEST(ModelEntry, DetailsOutOfTheKindsRangeAreRefusedNamingTheEntry) {
  const auto error = [](const std::string& text) { return CheckModelEntry(ParseModelEntry(text)); };
  EXPECT_NE(error("plane@3").find("@N applies to"), std::string::npos) << error("plane@3");
  EXPECT_NE(error("vdtm@3").find("\"vdtm@3\""), std::string::npos);
  EXPECT_NE(error("hull.ply@3").find("at least 4"), std::string::npos) << error("hull.ply@3");
  EXPECT_NE(error("splat_depth@17").find("at most 16"), std::string::npos) << error("splat_depth@17");
  EXPECT_EQ(error("splat_depth@16"), "");
  EXPECT_NE(error("hull.ply@x").find("positive whole number"), std::string::npos);
  EXPECT_NE(error("hull.ply@0").find("positive whole number"), std::string::npos);
  EXPECT_NE(error("splat_depth:bogus").find("geometric, photometric or truth"), std::string::npos);
}

TEST(ModelEntry, UnknownKindIsAClearErrorListingTheKinds) {
  for (const std::string text : {"splat_dept", "vdtm2", "name=surfels/mesh.obj", "plane:x", "textured:a"}) {
    try {
      ParseModelEntry(text);
      ADD_FAILURE() << text << " parsed";
    } catch (const InputError& e) {
      const std::string message = e.what();
      EXPECT_NE(message.find("\"" + text + "\""), std::string::npos) << message;
      for (const RenderModelKind& kind : RenderModelKinds()) {
        EXPECT_NE(message.find(kind.syntax), std::string::npos) << kind.syntax << " missing from: " << message;
      }
    }
  }
  EXPECT_THROW(ParseModelEntry(""), InputError);
  EXPECT_THROW(ParseModelEntry("name="), InputError);
  // Through the stage's check: the key and the same list.
  Params params = DefaultParams(RenderStage(), ".");
  params.Set("proxies", std::vector<std::string>{"plane", "vdtms"});
  const std::optional<ParamError> error = RenderStage().CheckParams(params);
  ASSERT_TRUE(error.has_value());
  EXPECT_EQ(error->key, "proxies");
  EXPECT_NE(error->message.find("splat_depth_merged"), std::string::npos) << error->message;
  // The background is a model that can serve as one: the plane, or none.
  params.Set("proxies", std::vector<std::string>{"plane"});
  for (const std::string background : {"hull/hull.ply", "vdtm", "bogus"}) {
    params.Set("background", background);
    const std::optional<ParamError> refused = RenderStage().CheckParams(params);
    ASSERT_TRUE(refused.has_value()) << background;
    EXPECT_EQ(refused->key, "background");
  }
  for (const std::string background : {"plane", "none"}) {
    params.Set("background", background);
    EXPECT_FALSE(RenderStage().CheckParams(params).has_value()) << background;
  }
}

// `ibmr stages` prints the proxies parameter's documentation: every kind of the registry.
TEST(ModelEntry, TheStagesListingNamesEveryKind) {
  for (const ParamSpec& spec : RenderStage().Parameters()) {
    if (spec.key != "proxies") continue;
    for (const RenderModelKind& kind : RenderModelKinds()) {
      EXPECT_NE(spec.doc.find(kind.syntax + ": " + kind.summary), std::string::npos) << kind.syntax;
    }
    return;
  }
  ADD_FAILURE() << "no proxies parameter";
}

// The hole extension of mesh models drawn with their faces (textured, vdtm) gives a raster the
// depths ExtendIntoHoles gives its depth map, each hole it reaches taking the face and
// barycentrics of the pixel its depth came from.
TEST(ExtendIntoHoles, ARasterTakesTheFacesOfTheDepthsItExtends) {
  TriangleMesh mesh;
  mesh.vertices = {{-0.3f, -0.3f, 2.f}, {0.3f, -0.3f, 2.f}, {0.3f, 0.3f, 2.f}, {-0.3f, 0.3f, 2.f}, {0.4f, -0.3f, 3.f},
                   {0.9f, -0.3f, 3.f}, {0.9f, 0.3f, 3.f}};
  mesh.faces = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}};
  const Camera camera = Camera::Pinhole(64, 48, 60, 60, 32, 24);
  RasterResult raster = Rasterize(mesh, camera, Rigid3d());
  const RasterResult before = raster;
  DepthMap depth = raster.depth;
  ExtendIntoHoles(&depth, 3);
  const std::vector<uint8_t> extended = ExtendIntoHoles(&raster, 3);
  EXPECT_EQ(raster.depth.data, depth.data);
  size_t reached = 0;
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const size_t i = static_cast<size_t>(y) * camera.width + x;
      if (before.face_id[i] >= 0) {
        EXPECT_FALSE(extended[i]);
        EXPECT_EQ(raster.face_id[i], before.face_id[i]);
        continue;
      }
      EXPECT_EQ(extended[i] != 0, IsValidDepth(depth.data[i])) << x << "," << y;
      if (!extended[i]) continue;
      ++reached;
      ASSERT_GE(raster.face_id[i], 0);
      // The face's depth plane: the near square (z = 2) or the far triangle (z = 3).
      EXPECT_FLOAT_EQ(raster.depth.data[i], raster.face_id[i] == 2 ? 3.f : 2.f);
    }
  }
  EXPECT_GT(reached, 0u);
  RasterResult untouched = before;
  const std::vector<uint8_t> none = ExtendIntoHoles(&untouched, 0);
  EXPECT_EQ(untouched.face_id, before.face_id);
  EXPECT_EQ(std::count(none.begin(), none.end(), 1), 0);
}

// Where splat_fit fitted the background colour with the splats (splat_fit/background.json
// "fitted"), the colour is part of the model: drawn behind the splats, every pixel covered; where
// it was given (the capture's), the model leaves it to the stage's fill: over black, the
// transmittance as the coverage.
TEST(SplatFitModel, DrawsTheBackgroundFittedWithTheSplats) {
  const std::filesystem::path root =
      std::filesystem::temp_directory_path() / ("ibmr_splat_fit_model_" + std::to_string(::getpid()));
  std::filesystem::create_directories(root / "splat_fit");
  GaussianSplats splats;
  splats.Add({0, 0, 2}, RotationWithNormal({0, 0, -1}), {std::log(0.2f), std::log(0.2f)}, 0.99f, {1.0f, 0.5f, 0.25f});
  WriteGaussianSplatsPly((root / "splat_fit/splats.ply").string(), splats, "test");
  const Workspace workspace(root.string());
  DesiredView view;
  view.camera = Camera::Pinhole(64, 48, 60, 60, 32, 24);
  for (const bool fitted : {true, false}) {
    WriteFileAtomic((root / "splat_fit/background.json").string(),
                    std::string("{\"rgb\": [0.2, 0.4, 0.8], \"fitted\": ") + (fitted ? "true" : "false") + "}\n");
    const std::unique_ptr<RenderModel> model = MakeRenderModel("splat_fit", workspace);
    nlohmann::json facts;
    ASSERT_EQ(model->Prepare(RenderScene(), &facts), std::nullopt);
    const ModelView drawn = model->Render(RenderScene(), view);
    const cv::Vec3b corner = drawn.fine.image.at<cv::Vec3b>(0, 0), centre = drawn.fine.image.at<cv::Vec3b>(24, 32);
    EXPECT_GE(centre[2], 245) << "the disc's red, nearly opaque at its centre";
    if (fitted) {
      EXPECT_EQ(corner, cv::Vec3b(204, 102, 51)) << "BGR of the fitted colour";
      EXPECT_EQ(drawn.fine.covered_pixels, 64u * 48u);
    } else {
      EXPECT_EQ(corner, cv::Vec3b(0, 0, 0));
      EXPECT_EQ(drawn.fine.coverage.at<uint8_t>(0, 0), 0);
      EXPECT_LT(drawn.fine.covered_pixels, 64u * 48u / 2);
    }
  }
  WriteFileAtomic((root / "splat_fit/background.json").string(), "{\"rgb\": [0.2], \"fitted\": true}\n");
  nlohmann::json facts;
  const auto error = MakeRenderModel("splat_fit", workspace)->Prepare(RenderScene(), &facts);
  ASSERT_TRUE(error.has_value());
  EXPECT_NE(error->find("background.json"), std::string::npos) << *error;
  std::filesystem::remove_all(root);
}

}  // namespace
}  // namespace ibmr
