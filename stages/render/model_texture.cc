// The render models of the texture stage's outputs (seed 003):
//   textured   the mesh drawn with its atlas (texture/mesh.obj with mesh.mtl and atlas_<page>.png;
//              textured.h): one colour per surface point, the same from every direction
//   vdtm       view-dependent texture mapping (seed 003 §7-8; vdtm.h): per face and frame, the view
//              map of texture/view_maps.bin blends at most 3 training photos; faces no photo sees
//              take the atlas (§6). exclude_self drops the rendered view's own photo from every blend.
// Both are mesh models: holes within proxy_extend_px of the mesh take the nearest covered pixel's
// depth and face (ExtendIntoHoles), and vdtm tests visibility against the same maps as ULR's mesh
// proxies (WithProxyDepth). A missing or unreadable texture/mesh.obj or texture/view_maps.bin skips
// the model.
#include <spdlog/spdlog.h>

#include <filesystem>
#include <memory>

#include "pipeline/core/errors.h"
#include "pipeline/core/textured_mesh.h"
#include "pipeline/core/view_maps.h"
#include "stages/render/render_model.h"
#include "stages/render/textured.h"
#include "stages/render/vdtm.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// What textured and vdtm share: the texture stage's mesh and atlas, read once.
class TextureModel : public RenderModel {
 public:
  TextureModel(ModelEntry entry, const Workspace& workspace)
      : RenderModel(std::move(entry)), path_(workspace.Path("texture/mesh.obj")) {}

  // mesh.obj with its mesh.mtl and atlas pages (and view_maps.bin): the texture stage's folder.
  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.Relative(fs::path(path_).parent_path().string())};
  }
  std::string SourcePath(const Workspace& workspace) const override { return workspace.Relative(path_); }

  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) override {
    if (!fs::exists(path_)) return path_ + " does not exist (run the texture stage)";
    try {
      if (const std::optional<std::string> missing = CheckFiles()) return missing;
      textured_ = ReadTexturedObj(path_);
      const std::string invalid = textured_.Validate();
      if (textured_.mesh.faces.empty() || !invalid.empty()) {
        return path_ + " has no usable faces" + (invalid.empty() ? "" : " (" + invalid + ")");
      }
      PrepareViews(scene, facts);
    } catch (const InputError& e) {  // unreadable or inconsistent files: like a missing mesh, not fatal
      return std::string(e.what());
    } catch (const IoError& e) {
      return std::string(e.what());
    }
    return std::nullopt;
  }

  // Its triangles, and the bytes of mesh.obj, mesh.mtl, the atlas pages and any other file
  // (view maps) as stored.
  nlohmann::json Size() const override {
    const fs::path folder = fs::path(path_).parent_path();
    std::vector<fs::path> files = {path_, fs::path(path_).replace_extension(".mtl")};
    for (size_t page = 0; page < textured_.pages.size(); ++page) {
      files.push_back(folder / ("atlas_" + std::to_string(page) + ".png"));
    }
    for (const std::string& file : MoreFiles()) files.push_back(file);
    uintmax_t bytes = 0;
    for (const fs::path& file : files) {
      std::error_code ec;
      const uintmax_t size = fs::file_size(file, ec);
      if (!ec) bytes += size;
    }
    const size_t triangles = textured_.mesh.faces.size();
    return {{"kind", SizeKind()},
            {"elements", triangles},
            {"triangles", triangles},
            {"pages", textured_.pages.size()},
            {"bytes", bytes}};
  }

 protected:
  Camera Supersampled(const RenderScene& scene, const DesiredView& view) const {
    return scene.factor > 1 ? view.camera.Scaled(scene.factor) : view.camera;
  }
  // A further file the model needs, missing: the reason it is skipped.
  virtual std::optional<std::string> CheckFiles() const { return std::nullopt; }
  // After the mesh is read: what the model derives for its views.
  virtual void PrepareViews(const RenderScene&, nlohmann::json*) {}
  virtual std::vector<std::string> MoreFiles() const { return {}; }
  virtual std::string SizeKind() const = 0;

  std::string path_;
  TexturedMesh textured_;
};

class TexturedModel : public TextureModel {
 public:
  using TextureModel::TextureModel;
  ModelView Render(const RenderScene& scene, const DesiredView& view) const override {
    ModelView drawn;
    drawn.fine = RenderTextured(textured_, Supersampled(scene, view), view.cam_from_world,
                                scene.options.proxy_extend_px * scene.factor);
    return drawn;
  }
  bool MadeFromEveryPhoto() const override { return true; }

 protected:
  std::string SizeKind() const override { return "textured_mesh"; }
};

class VdtmModel : public TextureModel {
 public:
  VdtmModel(ModelEntry entry, const Workspace& workspace)
      : TextureModel(std::move(entry), workspace), view_maps_path_(workspace.Path("texture/view_maps.bin")) {}

  ModelView Render(const RenderScene& scene, const DesiredView& view) const override {
    // Leave-one-out: the view's own photo is never a source (exclude_self).
    const int self = scene.SelfSource(view.name);
    VdtmStats stats;
    ModelView drawn;
    drawn.fine = renderer_->Render(Supersampled(scene, view), view.cam_from_world, self, &stats,
                                   scene.options.proxy_extend_px * scene.factor);
    if (drawn.fine.covered_pixels > 0) {
      drawn.facts["atlas_fraction"] = static_cast<double>(stats.atlas_pixels) / drawn.fine.covered_pixels;
    }
    const bool self_mapped = self >= 0 && std::find(view_maps_.view_names.begin(), view_maps_.view_names.end(),
                                                    view.name) != view_maps_.view_names.end();
    drawn.sources = static_cast<size_t>(renderer_->MatchedViews() - (self_mapped ? 1 : 0));
    return drawn;
  }

 protected:
  std::optional<std::string> CheckFiles() const override {
    if (fs::exists(view_maps_path_)) return std::nullopt;
    return view_maps_path_ + " does not exist (run the texture stage)";
  }
  void PrepareViews(const RenderScene& scene, nlohmann::json* facts) override {
    view_maps_ = ReadViewMaps(view_maps_path_);
    sources_ = WithProxyDepth(scene.sources, {&textured_.mesh}, scene.options.proxy_extend_px);
    renderer_ = std::make_unique<VdtmRenderer>(&textured_, &view_maps_, &sources_, scene.options.visibility_epsilon);
    const size_t views = view_maps_.view_names.size();
    (*facts)["view_maps"] = scene.context->workspace.Relative(view_maps_path_);
    (*facts)["view_map_views"] = views;
    (*facts)["view_map_views_with_source"] = renderer_->MatchedViews();
    if (renderer_->MatchedViews() < static_cast<int>(views)) {
      spdlog::warn("[render] proxy {}: {} of the {} views of {} are not training views here; never sampled", Name(),
                   views - renderer_->MatchedViews(), views, view_maps_path_);
    }
  }
  std::vector<std::string> MoreFiles() const override { return {view_maps_path_}; }
  std::string SizeKind() const override { return "vdtm"; }

 private:
  std::string view_maps_path_;
  ViewMaps view_maps_;
  std::vector<SourceView> sources_;  // with the mesh's depth (visibility)
  std::unique_ptr<VdtmRenderer> renderer_;
};

}  // namespace

RenderModelKind TexturedKind() {
  return NewRenderModelKind<TexturedModel>("textured", "the texture stage's mesh drawn with its atlas (texture/mesh.obj)");
}

RenderModelKind VdtmKind() {
  return NewRenderModelKind<VdtmModel>(
      "vdtm", "view-dependent texture mapping: per face the view map's at most three photos (seed 003, "
              "texture/view_maps.bin)");
}

}  // namespace ibmr
