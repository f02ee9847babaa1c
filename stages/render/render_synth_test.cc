// End-to-end held-out-view cross-validation on a synthetic scene (seed 000 lines 5906-5920 with
// seed 001's renderer): synth object_ring -> render (true mesh and plane proxies, every 8th view
// held out) -> score. Acceptance: the true mesh predicts held-out views at >= 35 dB over covered
// pixels, and beats the plane proxy by a margin in the same run.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_synth(StageRegistry* registry);
void RegisterStage_render(StageRegistry* registry);
void RegisterStage_score(StageRegistry* registry);

namespace {

// Every declared parameter at its default (parsed from the declaration's YAML text).
Params Defaults(const Stage& stage) {
  Params params;
  for (const ParamSpec& spec : stage.Parameters()) {
    std::string text = spec.default_yaml;
    if (text.size() >= 2 && text.front() == '"' && text.back() == '"') text = text.substr(1, text.size() - 2);
    switch (spec.type) {
      case ParamType::kInt: params.Set(spec.key, static_cast<int64_t>(std::stoll(text))); break;
      case ParamType::kDouble: params.Set(spec.key, std::stod(text)); break;
      case ParamType::kBool: params.Set(spec.key, text == "true"); break;
      case ParamType::kIntList: params.Set(spec.key, std::vector<int64_t>{}); break;
      case ParamType::kDoubleList: params.Set(spec.key, std::vector<double>{}); break;
      case ParamType::kStringList: params.Set(spec.key, std::vector<std::string>{}); break;
      default: params.Set(spec.key, text); break;
    }
  }
  return params;
}

void RunStage(const StageRegistry& registry, const std::string& name, const Workspace& workspace,
              const std::set<std::string>& heldout, const std::function<void(Params*)>& configure) {
  const Stage* stage = registry.Find(name);
  ASSERT_NE(stage, nullptr) << name;
  StageContext context;
  context.workspace = workspace;
  context.role = stage->Role();
  context.heldout_images = heldout;
  context.params = Defaults(*stage);
  configure(&context.params);
  const auto error = stage->CheckParams(context.params);
  ASSERT_FALSE(error.has_value()) << name << "." << error->key << ": " << error->message;
  NullProgress progress;
  context.progress = &progress;
  stage->Run(context);
}

TEST(RenderSynth, TrueMeshPredictsHeldOutViewsAndBeatsPlane) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_render_synth_test_" + std::to_string(::getpid()));
  fs::remove_all(root);
  const Workspace workspace(root.string());
  StageRegistry registry;
  RegisterStage_synth(&registry);
  RegisterStage_render(&registry);
  RegisterStage_score(&registry);
  RunStage(registry, "synth", workspace, {}, [](Params* p) {
    p->Set("scene", std::string("object_ring"));
    p->Set("views", int64_t{24});
    p->Set("width", int64_t{320});
    p->Set("height", int64_t{240});
  });
  // The runner's `every: 8` policy: views 0, 8, 16 of the sorted names.
  const SparseModel model = ReadSparseModelText(workspace.SparseDir());
  std::vector<std::string> names;
  for (int id : model.ImageIdsByName()) names.push_back(model.images.at(id).name);
  std::set<std::string> heldout;
  for (size_t i = 0; i < names.size(); i += 8) heldout.insert(names[i]);
  RunStage(registry, "render", workspace, heldout, [](Params* p) {
    p->Set("proxies", std::vector<std::string>{"ground_truth/mesh.ply", "plane", "hull/hull.ply",
                                               "splat_truth=splat_depth:truth"});
    p->Set("supersample", int64_t{2});  // the synthetic photos are anti-aliased (2x2) too
  });
  RunStage(registry, "score", workspace, heldout, [](Params*) {});
  const nlohmann::json scores = nlohmann::json::parse(std::ifstream(workspace.Path("scores/heldout.json")));
  const nlohmann::json& mesh = scores["proxies"]["ground_truth_mesh"];
  const nlohmann::json& plane = scores["proxies"]["plane"];
  ASSERT_EQ(mesh["status"], "scored") << scores.dump(2);
  ASSERT_EQ(plane["status"], "scored");
  EXPECT_EQ(scores["proxies"]["hull"]["status"], "skipped");  // no carve stage ran
  ASSERT_EQ(mesh["views"].size(), heldout.size());
  for (const auto& [name, view] : mesh["views"].items()) {
    EXPECT_GE(view["psnr"].get<double>(), 35.0) << name;
    EXPECT_GT(view["coverage"].get<double>(), 0.05) << name;
  }
  const double mesh_psnr = mesh["mean"]["psnr"].get<double>(), plane_psnr = plane["mean"]["psnr"].get<double>();
  std::cout << "held-out mean PSNR: true mesh " << mesh_psnr << " dB, plane " << plane_psnr << " dB; SSIM "
            << mesh["mean"]["ssim"] << " vs " << plane["mean"]["ssim"] << "\n";
  EXPECT_GT(mesh_psnr, plane_psnr + 3.0) << "better geometry must predict held-out views better";
  EXPECT_TRUE(fs::exists(workspace.Path("scores/ground_truth_mesh/" + fs::path(*heldout.begin()).stem().string() + ".png")));
  // Splatting the training views' true depth maps (seed 004) predicts the held-out views without a
  // mesh: inside the lit pixels, holes black (the templeRing protocol), and over covered pixels.
  const nlohmann::json& splat = scores["proxies"]["splat_truth"];
  ASSERT_EQ(splat["status"], "scored") << scores.dump(2);
  for (const auto& [name, view] : splat["views"].items()) {
    EXPECT_GE(view["photo_psnr"].get<double>(), 29.0) << name;  // 29.7-32.5 measured at 320x240 (34 at 640x480)
    EXPECT_GE(view["photo_coverage"].get<double>(), 0.99) << name;
    // With the plane filling what the model leaves uncovered, no view scores below the plane alone.
    EXPECT_GE(view["filled_photo_psnr"].get<double>(), plane["views"][name]["photo_psnr"].get<double>()) << name;
  }
  EXPECT_GE(splat["mean"]["photo_psnr"].get<double>(), 29.5);
  std::cout << "held-out splat of true depth maps: " << splat["mean"]["photo_psnr"] << " dB on lit pixels, "
            << splat["mean"]["psnr"] << " dB covered\n";
  if (!::testing::Test::HasFailure()) fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
