// Adapter of the render stage: renders the held-out views of sparse/ (or the views listed in
// `views`, or a camera given by `novel_look_at`) from the training views only, once per model of
// `proxies` (render_model.h; each kind in a model_*.cc, registered in render_models.cc). The first
// model that can be prepared is the primary; one whose input is missing is skipped with a warning.
// Shared here: the views to draw, supersampling and box-filtered downsampling, the background
// fill, the files and the records. exclude_self: each model leaves a training view's own photo
// out where it can (RenderModel::MadeFromEveryPhoto: a warning where it cannot).
// Metrics per model: ms_per_frame_<name> (mean wall time of one view's render and downsampling;
// views run concurrently: it compares the models of one run), prepare_seconds_<name>,
// seconds_<name> (preparation included) and the model's own (RenderModel::AddMetrics).
// Writes renders/<model>/<stem>.png, <stem>.coverage.png (255 covered) and <stem>.json (the
// view's coverage, sources, files), the primary's copies as renders/<stem>.png and .coverage.png,
// and renders/renders.json. With `background: plane`, every other model's holes are also filled
// from the plane model's render of the view (drawn once: the plane model takes it) in
// <stem>.filled.png and .filled.coverage.png, scored apart; with `background: capture` (`auto`'s
// choice where import composited the photos on a colour, background.json), every model's render
// is composited over that colour instead, so that its filled scores are figures over the whole
// image as the published protocols give them (a view rendered without a fill loses
// such files of an earlier run). Two views with one stem, or two models with one name, are refused.
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/capture_info.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/process_memory.h"
#include "pipeline/core/stage_api.h"
#include "stages/render/background_tasks.h"
#include "stages/render/render_model.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) { return std::chrono::duration<double>(Clock::now() - start).count(); }

// One view drawn by a model at the output size, with its facts for <stem>.json.
struct DrawnView {
  RenderResult result;
  nlohmann::json facts;  // "sources" and the model's own
  double seconds = 0;    // the render's wall time
};

DrawnView Draw(const RenderModel& model, const RenderScene& scene, const DesiredView& view) {
  const auto start = Clock::now();
  ModelView drawn = model.Render(scene, view);
  DrawnView out;
  const int factor = model.DrawsAtOutputSize() ? 1 : scene.factor;
  out.result = factor <= 1 ? std::move(drawn.fine)  // Downsample would return it as it is
                           : Downsample(drawn.fine, drawn.surface ? *drawn.surface : HitsOf(drawn.fine), factor);
  out.facts = std::move(drawn.facts);
  out.facts["sources"] = drawn.sources;
  out.seconds = SecondsSince(start);
  return out;
}

class RenderStage : public Stage {
 public:
  std::string Name() const override { return "render"; }
  std::string Summary() const override {
    return "Image-based rendering of held-out views from the training views by each model of render.proxies (ULR "
           "over plane / mesh proxies, splats, textured mesh, view-dependent texture mapping, layers)";
  }
  // 2: splat models, background fill; 3: elliptical splat footprints; 4: model sizes; 5: textured
  // and vdtm models (texture stage), ms_per_frame_<model> metrics; 6: vdtm per-pixel depth test;
  // 7: no frame times in renders.json (the record has them); 8: partly covered silhouette pixels
  // keep their coverage as alpha; 9: vdtm culls back faces.
  std::string Version() const override { return "9"; }
  HoldoutRole Role() const override { return HoldoutRole::kScoring; }
  // Shards are held-out views: each renders every model for its views; the merge gathers them
  // and writes renders.json.
  bool Shardable() const override { return true; }
  std::vector<std::string> ShardViews(const StageContext& context) const override {
    if (!fs::exists(context.workspace.SparseDir() + "/images.txt")) return {};
    std::vector<std::string> names = PhotoViewNames(context);
    if (!context.params.DoubleList("novel_look_at").empty()) names.push_back("novel");
    std::sort(names.begin(), names.end());
    return names;
  }
  // One view's buffers, for the model that needs the most (models run one after the other;
  // RenderModel::ViewBytes).
  double ViewMemoryMb(const StageContext& context) const override {
    const double pixels = LargestTrainingImage(context).Pixels();
    double bytes = 0;
    for (const auto& model : Models(context)) bytes = std::max(bytes, model->ViewBytes(context, pixels));
    return bytes / 1048576.0;
  }

  std::vector<ParamSpec> Parameters() const override;
  std::optional<ParamError> CheckParams(const Params& params) const override;

  // Workspace-relative where the file lies inside the workspace, so that the cache key does not
  // depend on where the workspace sits (a sweep's variants, a copy, a cluster's mount point).
  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.ImagesRelative(), context.workspace.SparseRelative()};
    if (context.params.String("background") == "auto" || context.params.String("background") == "capture") {
      inputs.push_back(kBackgroundFile);
    }
    for (const auto& model : Models(context)) {
      for (const std::string& input : model->Inputs(context)) {
        if (std::find(inputs.begin(), inputs.end(), input) == inputs.end()) inputs.push_back(input);
      }
    }
    return inputs;
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"renders"}; }
  std::vector<DrawnModel> DrawsModels(const StageContext& context) const override {
    std::vector<DrawnModel> drawn;
    for (const auto& model : Models(context)) drawn.push_back({model->Name(), model->Inputs(context)});
    return drawn;
  }

  void Run(StageContext& context) const override;

 private:
  static std::vector<std::unique_ptr<RenderModel>> Models(const StageContext& context) {
    std::vector<std::unique_ptr<RenderModel>> models;
    for (const std::string& entry : context.params.StringList("proxies")) {
      models.push_back(MakeRenderModel(entry, context.workspace));
    }
    return models;
  }
  // The photographed views to render: render.views, else the held-out ones (those scored, where
  // the holdout policy scores a subset of them).
  static std::vector<std::string> PhotoViewNames(const StageContext& context) {
    std::vector<std::string> names = context.params.StringList("views");
    if (!names.empty()) return names;
    const std::set<std::string>& views = context.scored_heldout.empty() ? context.heldout_images : context.scored_heldout;
    return std::vector<std::string>(views.begin(), views.end());
  }
  // The colour every model's holes take (render.background capture, or auto where the capture
  // has one); nullopt: the plane's render or nothing fills them.
  static std::optional<cv::Vec3b> CaptureColour(const StageContext& context) {
    const std::string& mode = context.params.String("background");
    if (mode != "auto" && mode != "capture") return std::nullopt;
    const std::optional<CaptureBackground> background = ReadCaptureBackground(context.workspace);
    if (!background && mode == "capture") {
      throw InputError("render.background: capture: the capture has no background colour (" +
                       context.workspace.Path(kBackgroundFile) +
                       " absent or empty: its photos had no alpha to composite); use plane or none");
    }
    if (!background) return std::nullopt;
    return background->bgr;
  }
  // Draws every desired view with `model`, writes their files and returns renders.json's entry.
  static nlohmann::json RenderModelViews(StageContext& context, const RenderScene& scene, const RenderModel& model,
                                         const std::vector<DesiredView>& desired, bool is_primary,
                                         const std::map<std::string, DrawnView>& background,
                                         const std::optional<cv::Vec3b>& colour, ShardFinished* shard_done);
};

std::vector<ParamSpec> RenderStage::Parameters() const {
  std::vector<ParamSpec> params = {
      {"proxies", ParamType::kStringList, "[plane]",
       "render models in order (the first present is primary), each [name=]ENTRY, one of:\n" +
           DescribeRenderModelKinds("        ") + "      (a model's name, renders/<name>/, is its keyword or file "
                                               "stem by default, \"_N\" added for @N)",
       {}},
      {"views", ParamType::kStringList, "[]", "image names of sparse/ to render; empty: every held-out view", {}},
      {"exclude_self", ParamType::kBool, "true", "never use the rendered view's own photo (leave-one-out)", {}},
      {"k", ParamType::kInt, "4", "cameras in the blending neighbourhood, the k-th is the threshold, in [2, 64]", {}},
      {"alpha", ParamType::kDouble, "1", "weight of the angle penalty (radians), >= 0", {}},
      {"beta", ParamType::kDouble, "0", "weight of the resolution penalty (per scene unit), >= 0", {}},
      {"gamma", ParamType::kDouble, "1", "weight of the field-of-view penalty, >= 0", {}},
      {"epipole_consistent", ParamType::kBool, "true", "multiply weights by 1/penalty (exact epipole consistency)", {}},
      {"fov_margin", ParamType::kDouble, "0.05",
       "border band where the field-of-view penalty rises, fraction of min(width, height), in (0, 0.5)", {}},
      {"max_penalty", ParamType::kDouble, "3.14159265358979",
       "penalty of a missing camera when fewer than k are usable; caps the threshold, > 0", {}},
      {"visibility_epsilon", ParamType::kDouble, "0.01", "relative depth tolerance of visibility, in (0, 1)", {}},
      {"proxy_extend_px", ParamType::kInt, "0",
       "mesh models (ULR's meshes, textured, vdtm): holes within this many pixels of the mesh take the nearest "
       "covered depth (desired view and sources' visibility), in [0, 16]",
       {}},
      {"supersample", ParamType::kInt, "1", "sub-samples per pixel side, box-filtered (anti-aliased silhouettes), in [1, 4]",
       {}},
      {"background", ParamType::kString, "auto",
       "fills every model's holes in a second image <view>.filled.png, scored apart: capture (the colour import "
       "composited transparent photos on, background.json), plane (the plane proxy), none, or auto (capture where "
       "the capture has one, else plane)",
       {}},
      {"novel_look_at", ParamType::kDoubleList, "[]",
       "extra camera: eye x y z, target x y z [, up x y z] (intrinsics of the first training view); rendered as "
       "novel.png",
       {}},
  };
  // Each kind's own keys (splat_*, layers_references, ...).
  for (const RenderModelKind& kind : RenderModelKinds()) params.insert(params.end(), kind.params.begin(), kind.params.end());
  return params;
}

std::optional<ParamError> RenderStage::CheckParams(const Params& params) const {
  std::string error;
  if (!ToRenderOptions(params).Check(&error)) return ParamError::FromCheck(error);
  for (const RenderModelKind& kind : RenderModelKinds()) {
    if (!kind.check_params) continue;
    if (std::optional<ParamError> kind_error = kind.check_params(params)) return kind_error;
  }
  const std::string background = params.String("background");
  // The background is drawn by the model its value names, one that can serve as one (the plane).
  bool serves = background == "none" || background == "capture" || background == "auto";
  try {
    serves = serves || MakeRenderModel(background, Workspace("."))->IsBackground();
  } catch (const InputError&) {
  }
  if (!serves) return ParamError{"background", "must be auto, capture, plane or none, got \"" + background + "\""};
  if (params.Int("supersample") < 1 || params.Int("supersample") > 4) {
    return ParamError{"supersample", "must be in [1, 4], got " + std::to_string(params.Int("supersample"))};
  }
  const std::vector<double> look = params.DoubleList("novel_look_at");
  if (look.size() != 0 && look.size() != 6 && look.size() != 9) {
    return ParamError{"novel_look_at", "expected 0, 6 or 9 numbers (eye, target[, up]), got " + std::to_string(look.size())};
  }
  if (!look.empty()) {
    const Eigen::Vector3d eye(look[0], look[1], look[2]), target(look[3], look[4], look[5]);
    if (!eye.allFinite() || !target.allFinite() || !((target - eye).norm() > 0)) {
      return ParamError{"novel_look_at", "eye (the first 3 numbers) and target (the next 3) must be distinct finite "
                                         "points; move the target to where the camera should look"};
    }
  }
  if (const std::string error = CheckModelEntries(params.StringList("proxies")); !error.empty()) {
    return ParamError{"proxies", error};
  }
  return std::nullopt;
}

void RenderStage::Run(StageContext& context) const {
  const SparseModel sparse = context.LoadModel();
  if (sparse.images.empty()) throw InputError(context.workspace.SparseDir() + ": no posed image; run import or sfm first");
  RenderScene scene;
  LoadRenderScene(context, sparse, &scene);
  // A shard renders its views only; the per-view loops then run unsharded over them (the marks
  // are per model and view), and it ends before the files that gather every view.
  const std::set<std::string> shard = std::move(context.shard_views);
  context.shard_views.clear();
  const std::vector<DesiredView> desired = DesiredViews(context, sparse, scene, PhotoViewNames(context), shard);
  ShardFinished shard_done;

  // The background that fills every other model's holes (`background: plane`), one per view, in
  // memory only (no per-view checkpoint: a resumed run needs it for every view it renders). A
  // background that cannot be placed (no sparse points, parallel axes) fills nothing.
  std::map<std::string, DrawnView> background;
  const std::optional<cv::Vec3b> colour = CaptureColour(context);
  if (colour) {
    spdlog::info("[render] holes filled with the capture's background (B, G, R) = ({}, {}, {})", (*colour)[0], (*colour)[1],
                 (*colour)[2]);
  } else if (context.params.String("background") != "none") {
    const std::string& mode = context.params.String("background");
    std::unique_ptr<RenderModel> model = MakeRenderModel(mode == "auto" ? "plane" : mode, context.workspace);
    nlohmann::json facts;
    bool prepared = false;
    try {
      prepared = !model->Prepare(scene, &facts).has_value();
    } catch (const InputError&) {
    }
    if (prepared) {
      std::vector<DrawnView> drawn(desired.size());
      context.progress->Begin("background (" + model->Name() + ")", desired.size());
      tbb::parallel_for(size_t{0}, desired.size(), [&](size_t i) {
        drawn[i] = Draw(*model, scene, desired[i]);
        context.progress->Advance(1, desired[i].stem);
      });
      context.progress->End();
      for (size_t i = 0; i < desired.size(); ++i) background[desired[i].stem] = std::move(drawn[i]);
    }
  }

  nlohmann::json models_json = nlohmann::json::array();
  std::string primary;
  fs::create_directories(context.workspace.Path("renders"));
  // Every model made from its entry first (cheap), their background work (RenderModel::
  // BackgroundWork) run in order on one thread while the models draw.
  std::vector<std::unique_ptr<RenderModel>> models;
  for (const std::string& entry : context.params.StringList("proxies")) {
    models.push_back(MakeRenderModel(entry, context.workspace));
  }
  // A model made by a stage the run's plan skipped is not drawn, even where an earlier run left
  // its files: the capture is not one it serves.
  std::vector<std::string> skipped_because(models.size());
  for (size_t m = 0; m < models.size(); ++m) {
    // A model that lost the run's race is not drawn at full size (the background model still is:
    // the other models' holes take its colours).
    if (const auto lost = context.left_out_models.find(models[m]->Name());
        lost != context.left_out_models.end() && !models[m]->IsBackground()) {
      skipped_because[m] = lost->second;
    }
    for (const std::string& input : models[m]->Inputs(context)) {
      if (const std::string* reason = context.SkippedBy(input); reason != nullptr && skipped_because[m].empty()) {
        skipped_because[m] = "its input " + input + " comes from a stage the plan skipped (" + *reason + ")";
      }
    }
  }
  BackgroundTasks background_work;
  std::vector<std::shared_future<void>> prepared_ahead;
  for (size_t m = 0; m < models.size(); ++m) {
    prepared_ahead.push_back(background_work.Add(skipped_because[m].empty() ? models[m]->BackgroundWork()
                                                                             : std::function<void()>()));
  }
  for (size_t m = 0; m < models.size(); ++m) {
    // What the last model held goes back to the system before the next one loads (the full-size
    // castle: 1130 -> 577 MB held before the layers, after the splats' 20 M samples).
    ReleaseFreeHeap();
    const auto start = Clock::now();
    prepared_ahead[m].get();  // rethrows what the model's background work threw
    const std::unique_ptr<RenderModel> model = std::move(models[m]);
    nlohmann::json facts = nlohmann::json::object();
    const std::optional<std::string> reason =
        skipped_because[m].empty() ? model->Prepare(scene, &facts) : std::optional<std::string>(skipped_because[m]);
    if (reason) {
      if (skipped_because[m].empty()) {
        spdlog::warn("[render] proxy {}: {}; skipped", model->Name(), *reason);
      } else {  // the plan's decision, said once already by the runner
        spdlog::info("[render] proxy {}: {}; skipped", model->Name(), *reason);
      }
      models_json.push_back({{"name", model->Name()},
                             {"path", model->SourcePath(context.workspace)},
                             {"status", "skipped"},
                             {"reason", *reason},
                             {"left_out_by_plan", !skipped_because[m].empty()}});
      continue;
    }
    context.metrics["prepare_seconds_" + model->Name()] = SecondsSince(start);
    const bool is_primary = primary.empty();
    if (is_primary) primary = model->Name();
    nlohmann::json pj = RenderModelViews(context, scene, *model, desired, is_primary, background, colour, &shard_done);
    pj.update(facts);
    models_json.push_back(pj);
    model->AddMetrics(&context.metrics);
    context.metrics["seconds_" + model->Name()] = SecondsSince(start);
    spdlog::info("[render] proxy {}: {} views in {:.2f} s", model->Name(), desired.size(), SecondsSince(start));
  }
  // Each view rendered by every model: the mark a shard's success is read from (UnfinishedViews).
  for (const DesiredView& view : desired) context.checkpoint.MarkDone(view.name);
  if (!shard.empty()) throw shard_done;
  if (primary.empty() && !desired.empty()) {
    throw InputError("render.proxies: none of the listed proxies exists (see the warnings above); list plane or "
                     "an existing mesh");
  }
  const nlohmann::json summary = {{"primary", primary},
                                  {"proxies", models_json},
                                  {"training_views", scene.training},
                                  {"options", context.params.ToJson()}};
  WriteFileAtomic(context.workspace.Path("renders/renders.json"), summary.dump(2) + "\n");
  context.metrics["views"] = desired.size();
  context.metrics["sources"] = scene.training.size();
  context.metrics["primary_proxy"] = primary;
}

nlohmann::json RenderStage::RenderModelViews(StageContext& context, const RenderScene& scene, const RenderModel& model,
                                             const std::vector<DesiredView>& desired, bool is_primary,
                                             const std::map<std::string, DrawnView>& background,
                                             const std::optional<cv::Vec3b>& colour, ShardFinished* shard_done) {
  const std::string name = model.Name();
  if (scene.exclude_self && model.MadeFromEveryPhoto()) {
    std::string in_model;
    for (const DesiredView& view : desired) {
      if (scene.SelfSource(view.name) >= 0) in_model += (in_model.empty() ? "" : ", ") + view.name;
    }
    if (!in_model.empty()) {
      spdlog::warn("[render] proxy {}: the training views {} are not held out: the model was made from their "
                   "photos too, so their scores are optimistic (exclude_self cannot apply); score held-out views",
                   name, in_model);
    }
  }
  const std::string folder = context.workspace.Path("renders/" + name);
  fs::create_directories(folder);
  std::vector<std::string> keys;
  for (const DesiredView& view : desired) keys.push_back(name + "__" + view.stem);
  std::mutex mutex;
  double frame_seconds = 0;  // the views' render times (not the file writes)
  size_t frames = 0;
  const PerViewSummary rendered = ForEachView(context, "render " + name, keys, [&](const std::string& key) -> nlohmann::json {
    const DesiredView& view = desired[std::find(keys.begin(), keys.end(), key) - keys.begin()];
    const auto fill = background.find(view.stem);
    // The background's model takes its render (drawn once), its time counted as this model's.
    DrawnView drawn = model.IsBackground() && fill != background.end() ? fill->second : Draw(model, scene, view);
    // What the drawing freed back to the system: placed in the heap's free space, it would stay
    // resident beside the next view's (the full-size castle's splat_depth after four other
    // models: 1294 MB held before the first view, 1932 MB after it).
    ReleaseFreeHeap();
    {
      std::lock_guard<std::mutex> lock(mutex);
      frame_seconds += drawn.seconds;
      ++frames;
    }
    const RenderResult& result = drawn.result;
    WriteImage(folder + "/" + view.stem + ".png", result.image);
    WriteImage(folder + "/" + view.stem + ".coverage.png", result.coverage);
    if (is_primary) {
      WriteImage(context.workspace.Path("renders/" + view.stem + ".png"), result.image);
      WriteImage(context.workspace.Path("renders/" + view.stem + ".coverage.png"), result.coverage);
    }
    nlohmann::json vj = {{"image", view.name},
                         {"render", "renders/" + name + "/" + view.stem + ".png"},
                         {"coverage", static_cast<double>(result.covered_pixels) /
                                          (static_cast<double>(view.camera.width) * view.camera.height)}};
    vj.update(drawn.facts);
    if (colour || (!model.IsBackground() && fill != background.end())) {
      const RenderResult filled = colour ? FillWithColour(result, *colour) : FillHoles(result, fill->second.result);
      WriteImage(folder + "/" + view.stem + ".filled.png", filled.image);
      WriteImage(folder + "/" + view.stem + ".filled.coverage.png", filled.coverage);
      vj["filled"] = "renders/" + name + "/" + view.stem + ".filled.png";
    } else {
      // No fill this time (background: none, or the background's own model): a filled image of
      // an earlier run would be stale beside the new render.
      std::error_code ec;
      fs::remove(folder + "/" + view.stem + ".filled.png", ec);
      fs::remove(folder + "/" + view.stem + ".filled.coverage.png", ec);
    }
    // The view's facts beside its images: a resumed run skips views already rendered and gathers
    // every view's facts from these files.
    WriteFileAtomic(folder + "/" + view.stem + ".json", vj.dump(2) + "\n");
    return {};
  });
  shard_done->computed += rendered.computed;
  shard_done->resumed += rendered.resumed;
  nlohmann::json views_json = nlohmann::json::object();
  for (const DesiredView& view : desired) {
    const std::string facts = folder + "/" + view.stem + ".json";
    if (fs::exists(facts)) views_json[view.name] = nlohmann::json::parse(ReadFile(facts));
  }
  if (frames > 0) {
    // Mean wall time of one view's render in this run (views run concurrently: compare models of
    // one run, e.g. vdtm with ULR over the same mesh). In the record only: renders.json, an output,
    // is the same for the same work, whatever the machine did.
    context.metrics["ms_per_frame_" + name] = 1e3 * frame_seconds / frames;
  }
  nlohmann::json model_size = model.Size();
  // A model drawn from ground truth is a reference, not a reconstruction: select skips it.
  if (model.FromTruth(context.workspace)) model_size["from_truth"] = true;
  return {{"name", name},
          {"path", model.SourcePath(context.workspace)},
          {"status", "rendered"},
          {"primary", is_primary},
          {"views", views_json},
          {"model", model_size}};
}

}  // namespace

void RegisterStage_render(StageRegistry* registry) { registry->Add(std::make_unique<RenderStage>()); }

}  // namespace ibmr
