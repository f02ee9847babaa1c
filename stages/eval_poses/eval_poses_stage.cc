// Adapter of the eval_poses stage: compares sparse/ (the model downstream stages use, e.g. the
// sfm stage's) with ground_truth/sparse/ (the known cameras import wrote, kept by sfm), writes
// eval_poses/poses.json and the figures into the record's metrics. Also `ibmr eval-poses MODEL TRUTH`.
#include <spdlog/spdlog.h>

#include <filesystem>
#include <iostream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/stage_api.h"
#include "stages/eval_poses/eval_poses.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

nlohmann::json ToJson(const PoseEvaluation& eval) {
  nlohmann::json cameras = nlohmann::json::array();
  for (const CameraPoseError& c : eval.cameras) {
    cameras.push_back({{"name", c.name}, {"registered", c.registered}, {"rotation_error_deg", c.rotation_deg},
                       {"centre_error_over_ring_diameter", c.centre_fraction}, {"focal_error_fraction", c.focal_fraction}});
  }
  return {{"registered", eval.registered}, {"total", eval.total}, {"unregistered_images", eval.unregistered},
          {"ring_diameter", eval.ring_diameter}, {"similarity_scale", eval.scale},
          {"median_rotation_error_deg", eval.median_rotation_deg}, {"mean_rotation_error_deg", eval.mean_rotation_deg},
          {"max_rotation_error_deg", eval.max_rotation_deg},
          {"median_centre_error_over_ring_diameter", eval.median_centre_fraction},
          {"max_centre_error_over_ring_diameter", eval.max_centre_fraction},
          {"median_focal_error_fraction", eval.median_focal_fraction},
          {"alignment", "similarity fitted to centres and orientations"},
          {"centre_only_alignment",
           {{"median_rotation_error_deg", eval.centre_only.median_rotation_deg},
            {"mean_rotation_error_deg", eval.centre_only.mean_rotation_deg},
            {"max_rotation_error_deg", eval.centre_only.max_rotation_deg},
            {"median_centre_error_over_ring_diameter", eval.centre_only.median_centre_fraction},
            {"max_centre_error_over_ring_diameter", eval.centre_only.max_centre_fraction}}},
          {"identical_to_truth", eval.identical_to_truth}, {"cameras", cameras}};
}

void Log(const PoseEvaluation& eval) {
  if (eval.identical_to_truth) {
    spdlog::warn("[eval_poses] the model is the truth itself (every pose equal): nothing is measured; did sfm fall "
                 "back to the known cameras? (see records/sfm.json)");
  }
  spdlog::info("[eval_poses] {} of {} registered; rotation error median {:.3f} deg (max {:.3f}); centre error median "
               "{:.3f}% of the ring diameter (max {:.3f}%); focal error median {:.3f}%",
               eval.registered, eval.total, eval.median_rotation_deg, eval.max_rotation_deg,
               100 * eval.median_centre_fraction, 100 * eval.max_centre_fraction, 100 * eval.median_focal_fraction);
  spdlog::info("[eval_poses] aligned by the centres only: rotation error median {:.3f} deg, centre error median "
               "{:.3f}%",
               eval.centre_only.median_rotation_deg, 100 * eval.centre_only.median_centre_fraction);
}

class EvalPosesStage : public Stage {
 public:
  std::string Name() const override { return "eval_poses"; }
  std::string Summary() const override {
    return "Pose errors of the estimated model (sfm/sparse/) against the known one (sparse/) after a similarity alignment";
  }
  std::string Version() const override { return "2"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override {
    return {{"min_common", ParamType::kInt, "3", "Cameras needed in both models for the alignment; >= 3"},
            {"truth", ParamType::kString, "sparse", "Workspace-relative folder of the true model (import's known cameras)"}};
  }
  std::optional<ParamError> CheckParams(const Params& params) const override {
    EvalPosesOptions options;
    options.min_common = static_cast<int>(params.Int("min_common"));
    std::string error;
    if (!options.Check(&error)) return ParamError{"min_common", error.substr(error.find(':') + 2)};
    return std::nullopt;
  }
  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.SparseRelative(), context.params.String("truth")};
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"eval_poses"}; }

  void Run(StageContext& context) const override {
    const std::string truth_dir = context.workspace.Path(context.params.String("truth"));
    if (!fs::exists(truth_dir + "/images.txt")) {
      throw InputError("eval_poses.truth: " + truth_dir + "/images.txt is missing; import writes known "
                       "cameras to sparse/ (run import with known cameras, then sfm)");
    }
    EvalPosesOptions options;
    options.min_common = static_cast<int>(context.params.Int("min_common"));
    const PoseEvaluation eval =
        EvaluatePoses(ReadSparseModelText(context.workspace.SparseDir()), ReadSparseModelText(truth_dir), options);
    context.metrics = ToJson(eval);
    WriteFileAtomic(context.workspace.Path("eval_poses/poses.json"), context.metrics.dump(2));
    Log(eval);
  }
};

int EvalPosesCommand(const std::vector<std::string>& args) {
  if (args.size() != 2 || args[0] == "--help") {
    std::cout << "usage: ibmr eval-poses MODEL_DIR TRUTH_DIR   (COLMAP text models; prints JSON)\n";
    return args.size() == 1 && args[0] == "--help" ? 0 : 2;
  }
  try {
    const PoseEvaluation eval = EvaluatePoses(ReadSparseModelText(args[0]), ReadSparseModelText(args[1]), EvalPosesOptions());
    std::cout << ToJson(eval).dump(2) << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
}

}  // namespace

void RegisterStage_eval_poses(StageRegistry* registry) {
  registry->Add(std::make_unique<EvalPosesStage>());
  registry->AddCommand({"eval-poses", "Pose errors of a COLMAP text model against true cameras", EvalPosesCommand});
}

}  // namespace ibmr
