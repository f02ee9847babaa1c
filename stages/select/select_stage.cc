// Adapter of the select stage (see select.h): reads the held-out scores (scores/heldout.json) and
// the model sizes the render stage reports (renders/renders.json), writes scores/selection.json:
// every scored model by size with its held-out error, the size-error envelope, the best, and the
// chosen one (smallest within tolerance_db of the best) with its gap.
#include <spdlog/spdlog.h>

#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/heldout_scores.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/stage_api.h"
#include "stages/select/select.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

nlohmann::json ToJson(const ModelCandidate& m) {
  return {{"name", m.name},         {"kind", m.kind},   {"bytes", m.bytes},
          {"elements", m.elements}, {"psnr", m.psnr},   {"coverage", m.coverage}};
}

class SelectStage : public Stage {
 public:
  std::string Name() const override { return "select"; }
  std::string Summary() const override {
    return "Model selection: the smallest rendered model within a tolerance of the best held-out PSNR";
  }
  std::string Version() const override { return "2"; }  // 2: means over views not near a training camera
  HoldoutRole Role() const override { return HoldoutRole::kScoring; }
  std::vector<ParamSpec> Parameters() const override {
    return {
        {"metric", ParamType::kString, "photo_psnr",
         "held-out mean compared (photo_psnr counts holes as black; psnr: covered pixels only; filled_photo_psnr, "
         "mask_psnr)",
         {}},
        {"tolerance_db", ParamType::kDouble, "0.5", "the chosen model is within this of the best, in [0, 20]", {}},
    };
  }
  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    return std::nullopt;
  }
  std::vector<std::string> Inputs(const StageContext&) const override {
    return {"scores/heldout.json", "renders/renders.json"};
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"scores/selection.json"}; }

  void Run(StageContext& context) const override {
    const SelectionOptions options = ToOptions(context.params);
    const nlohmann::json scores = ReadStageJson(context.workspace.Path("scores/heldout.json"), "score", "select");
    const nlohmann::json renders = ReadStageJson(context.workspace.Path("renders/renders.json"), "render", "select");
    const nlohmann::json sizes = ModelSizes(renders);
    std::vector<ModelCandidate> candidates;
    nlohmann::json unranked = nlohmann::json::array();
    const nlohmann::json proxies = scores.value("proxies", nlohmann::json::object());
    for (const auto& [name, proxy] : proxies.items()) {
      const nlohmann::json mean = HeldoutMeans(proxy);
      const auto size = sizes.find(name);
      if (size != sizes.end() && size->is_object() && size->value("from_truth", false)) {
        unranked.push_back({{"name", name}, {"reason", "drawn from ground truth: a reference, not a model"}});
        continue;
      }
      if (!mean.contains(options.metric) || !mean[options.metric].is_number() || size == sizes.end()) {
        unranked.push_back({{"name", name},
                            {"reason", size == sizes.end() ? "renders/renders.json gives no size (re-run render)"
                                                           : "no held-out " + options.metric}});
        continue;
      }
      ModelCandidate m;
      m.name = name;
      m.kind = size->value("kind", "");
      m.bytes = size->value("bytes", 0.0);
      m.elements = size->value("elements", 0.0);
      m.psnr = mean[options.metric].get<double>();
      m.coverage = mean.value("coverage", 0.0);
      candidates.push_back(m);
    }
    if (candidates.empty()) {
      throw InputError("select: no model in scores/heldout.json has a held-out " + options.metric +
                       " and a size in renders/renders.json; re-run render and score, or set select.metric");
    }
    const Selection selection = SelectModel(candidates, options);
    nlohmann::json models = nlohmann::json::array();
    for (const ModelCandidate& m : selection.by_size) models.push_back(ToJson(m));
    nlohmann::json envelope = nlohmann::json::array();
    for (size_t i : selection.envelope) envelope.push_back(selection.by_size[i].name);
    const ModelCandidate& chosen = selection.by_size[selection.chosen];
    const ModelCandidate& best = selection.by_size[selection.best];
    const nlohmann::json out = {{"metric", options.metric},
                                {"tolerance_db", options.tolerance_db},
                                {"chosen", ToJson(chosen)},
                                {"best", ToJson(best)},
                                {"gap_db", selection.gap_db},
                                {"size_ratio", best.bytes > 0 ? chosen.bytes / best.bytes : 0.0},
                                {"models", models},
                                {"envelope", envelope},
                                {"unranked", unranked}};
    WriteFileAtomic(context.workspace.Path("scores/selection.json"), out.dump(2) + "\n");
    context.metrics["chosen"] = chosen.name;
    context.metrics["chosen_bytes"] = chosen.bytes;
    context.metrics["best"] = best.name;
    context.metrics["gap_db"] = selection.gap_db;
    spdlog::info("[select] {} of {} models: chosen {} ({:.0f} bytes, {} {:.2f} dB), best {} ({:.0f} bytes, {:.2f} dB), "
                 "gap {:.2f} dB",
                 options.metric, candidates.size(), chosen.name, chosen.bytes, options.metric, chosen.psnr, best.name,
                 best.bytes, best.psnr, selection.gap_db);
  }

 private:
  static SelectionOptions ToOptions(const Params& params) {
    SelectionOptions options;
    options.metric = params.String("metric");
    options.tolerance_db = params.Double("tolerance_db");
    return options;
  }
};

}  // namespace

void RegisterStage_select(StageRegistry* registry) { registry->Add(std::make_unique<SelectStage>()); }

}  // namespace ibmr
