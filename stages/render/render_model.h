// A render model: one entry of `render.proxies` (a plane or mesh proxy drawn by ULR, seed 001; a
// point splat model, seed 004; the textured mesh or view-dependent texture mapping, seed 003;
// sprites with depth, seed 000), behind one interface that the render stage drives
// (render_stage.cc): the stage builds each model from its entry, hashes its inputs, asks its
// memory per view, prepares it once, then has it draw each desired view and reports its size and
// metrics. The stage owns what every model shares: the views to draw, supersampling and
// downsampling, the background fill, the files, renders.json and the records.
//
// Adding a model: write model_<kind>.cc (model_layers.cc is a small one) with a subclass of
// RenderModel in an anonymous namespace and a function `RenderModelKind <Name>Kind()` returning
// NewRenderModelKind<YourModel>("keyword", "what it draws") (plus any @N range, option, own keys);
// list the file in CMakeLists.txt and add the one line `X(<Name>)` to IBMR_RENDER_MODEL_KINDS in
// render_models.cc. The entry parser, the stage's checks, the error for an unknown entry and
// `ibmr stages` learn of it from there. Per-pixel loops stay inside the model's own functions:
// the stage calls a model once per view.
#pragma once

#include <nlohmann/json.hpp>

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "pipeline/core/mesh.h"
#include "pipeline/core/params.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/workspace.h"
#include "stages/render/render.h"
#include "stages/render/render_scene.h"

namespace ibmr {

// One entry of `render.proxies` as written, before any file is read:
//   [name=]<keyword>[:option][@N]   a model kind named by its keyword (plane, splat_depth:truth, ...)
//   [name=]<path>[@N][|<path>...]   any other entry: a mesh (the kind with an empty keyword), with
//                                   fallback meshes after `|`
struct ModelEntry {
  std::string entry;                   // as written in the config
  std::string name;                    // renders/<name>/; a default from the kind when not given
  std::string keyword;                 // the kind's keyword; empty: a mesh path
  std::string option;                  // after "keyword:" (splat_depth:TYPE); empty when none
  std::string path;                    // a mesh entry's path as written (workspace-relative or absolute)
  std::vector<std::string> fallbacks;  // a mesh entry's fallback paths as written
  int detail = 0;                      // "@N": N; 0 when absent, -1 when N is not a whole number
};

// One view drawn by a model at the supersampled size.
struct ModelView {
  RenderResult fine;       // at camera.Scaled(factor)
  // Which sub-samples met the model, when it is not the coverage: ULR's proxy hits, where
  // sub-samples that no source sees are holes left out of the box filter's mean instead of black.
  std::optional<ProxySurface> surface;
  size_t sources = 0;      // source views the model drew from for this view
  nlohmann::json facts = nlohmann::json::object();  // more facts for <stem>.json (plane, atlas_fraction)
};

class RenderModel {
 public:
  explicit RenderModel(ModelEntry entry) : entry_(std::move(entry)) {}
  virtual ~RenderModel() = default;
  RenderModel(const RenderModel&) = delete;
  RenderModel& operator=(const RenderModel&) = delete;

  const std::string& Name() const { return entry_.name; }
  const ModelEntry& Entry() const { return entry_; }

  // What the model reads, workspace-relative where inside it (the cache key; `ibmr stages`).
  virtual std::vector<std::string> Inputs(const StageContext& context) const = 0;
  // One desired view's peak bytes while this model draws it, `pixels` the largest training image.
  // Default: 88 bytes a supersampled pixel (ULR, splats and texture models: colour, depth, weights
  // and blend sums, measured on the full-size Sceaux castle, 2832x2128 at supersample 2: 2.0 GB).
  virtual double ViewBytes(const StageContext& context, double pixels) const;
  // renders.json's "path": what the model is drawn from, workspace-relative.
  virtual std::string SourcePath(const Workspace& workspace) const = 0;

  // Preparation that needs nothing but the model's own files (reading and decimating a mesh),
  // returned as a task the stage runs on one background thread, in the order of render.proxies,
  // while the models before it draw: single-threaded work such as OpenMesh's decimation then fills
  // a core the drawing leaves idle. Prepare is called after the task has finished; an exception
  // the task throws is rethrown there. Default: none.
  virtual std::function<void()> BackgroundWork() { return {}; }
  // Reads and prepares the model once. Returns the reason it is skipped (a missing or unusable
  // file, logged and listed in renders.json) or nullopt; adds its facts to `facts` (renders.json's
  // entry). Throws InputError when the run cannot go on.
  virtual std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) = 0;
  // Draws one desired view at camera.Scaled(scene.factor). Called concurrently for several views.
  virtual ModelView Render(const RenderScene& scene, const DesiredView& view) const = 0;

  // Kind, elements and bytes of the prepared model, for `select` (renders.json "model").
  virtual nlohmann::json Size() const = 0;
  // True when the model is a reference drawn from ground truth, not a reconstruction.
  virtual bool FromTruth(const Workspace& workspace) const;
  // True when the model was made from every photo, so exclude_self cannot hold a training view
  // out of it (a warning says so).
  virtual bool MadeFromEveryPhoto() const { return false; }
  // True for a model whose samples are already filtered at about the output resolution (the
  // volume's bilinearly read planes): Render draws it at the output size (camera, not
  // camera.Scaled(factor)) and the stage does not supersample it.
  virtual bool DrawsAtOutputSize() const { return false; }
  // True for the model the background fill is drawn with: it takes the background's render of a
  // view instead of drawing it again, and is not filled itself.
  virtual bool IsBackground() const { return false; }
  // Adds the model's own metrics (keys ending in _<name>) after every view is drawn.
  virtual void AddMetrics(nlohmann::json* metrics) const;

 protected:
  ModelEntry entry_;
};

// A kind of model: how entries name it and how it is made.
struct RenderModelKind {
  std::string keyword;   // the entry's word ("plane", "splat_depth"); empty: any other entry, a mesh path
  std::string syntax;    // as the user writes it, e.g. "splat_depth[:TYPE][@N]"
  std::string summary;   // one line for `ibmr stages` and the README
  int max_detail = 0;    // "@N" accepted up to this (0: not at all)
  int min_detail = 1;
  std::string detail_meaning;  // what N counts ("faces", "pixels of a block side")
  bool takes_option = false;   // "keyword:option"
  // The entry's kind-specific error (an option it does not know), or "" when fine.
  std::string (*check_entry)(const ModelEntry& entry) = nullptr;
  // The kind's own keys of the render stage (declared whatever the config lists), and their
  // checks, run for every config (nullptr: none).
  std::vector<ParamSpec> params;
  std::optional<ParamError> (*check_params)(const Params& params) = nullptr;
  // The entry's default name when it gives none (without the "_N" of a detail); nullptr: the keyword.
  std::string (*default_name)(const ModelEntry& entry) = nullptr;
  std::unique_ptr<RenderModel> (*make)(ModelEntry entry, const Workspace& workspace) = nullptr;
};

// A kind named `keyword` (syntax: the keyword alone) whose models are built as
// Model(ModelEntry, const Workspace&); the caller sets the other fields.
template <typename Model>
RenderModelKind NewRenderModelKind(std::string keyword, std::string summary) {
  RenderModelKind kind;
  kind.syntax = keyword;
  kind.keyword = std::move(keyword);
  kind.summary = std::move(summary);
  kind.make = [](ModelEntry entry, const Workspace& workspace) -> std::unique_ptr<RenderModel> {
    return std::make_unique<Model>(std::move(entry), workspace);
  };
  return kind;
}

// Every registered kind, in the order they are listed (render_models.cc).
const std::vector<RenderModelKind>& RenderModelKinds();
// One line per kind, indent + "syntax: summary", for `ibmr stages` and messages.
std::string DescribeRenderModelKinds(const std::string& indent);

// Parses an entry's syntax (name, keyword or path, option, @N, fallbacks) and gives it its default
// name. Throws InputError naming the entry and listing the kinds when it is empty or malformed.
ModelEntry ParseModelEntry(const std::string& entry);
// The kind of a parsed entry (the mesh kind for paths).
const RenderModelKind& KindOf(const ModelEntry& entry);
// The entry's errors that need no file: @N out of the kind's range, an unknown option. "" when none.
std::string CheckModelEntry(const ModelEntry& entry);
// The first error of a list of entries (`proxies`): empty, unparsable, two with one name (both
// would write renders/<name>/), or CheckModelEntry's. "" when none.
std::string CheckModelEntries(const std::vector<std::string>& entries);
// Parses and builds the model of an entry; paths resolve against `workspace`.
std::unique_ptr<RenderModel> MakeRenderModel(const std::string& entry, const Workspace& workspace);

// `path` absolute: as given when absolute, else inside the workspace.
std::string AbsolutePath(const std::string& path, const Workspace& workspace);

}  // namespace ibmr
