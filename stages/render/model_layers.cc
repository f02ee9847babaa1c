// The `layers` render model: the layered_stereo stage's sprites with depth (layers/<image>/;
// seed 000 lines 5625-5811 and 12080-12355; layers.h): the layers_references reference views
// nearest in viewing direction, each composited back to front, blended 1 / angle^2. With
// exclude_self a training view does not use its own reference set. A workspace without any
// training view's layers skips the model.
#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/layered_sprites.h"
#include "stages/render/layers.h"
#include "stages/render/render_model.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// The most layers in one reference set under `folder` (layers/<image>/layers.json, small files)
// and the largest depth complexity (a set's layers' pixels over its sprite size), or
// layered_stereo's largest max_layers (16) for both when there is none yet (planned before that
// stage runs) or one cannot be read: an estimate must not fall short.
struct LayerSetsExtent {
  int layers = 0;
  double complexity = 0;
};
LayerSetsExtent LargestLayerSets(const std::string& folder) {
  constexpr int kMaxLayers = 16;
  const LayerSetsExtent unknown{kMaxLayers, kMaxLayers};
  LayerSetsExtent largest;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().filename() != "layers.json") continue;
    try {
      const nlohmann::json j = nlohmann::json::parse(ReadFile(it->path().string()));
      const double area = j.at("width").get<double>() * j.at("height").get<double>();
      double covered = 0;
      for (const auto& layer : j.at("layers")) covered += layer.at("pixels").get<double>();
      if (!(area > 0)) return unknown;
      largest.layers = std::max(largest.layers, static_cast<int>(j.at("layers").size()));
      largest.complexity = std::max(largest.complexity, covered / area);
    } catch (const std::exception&) {
      return unknown;
    }
  }
  return ec || largest.layers == 0 ? unknown : largest;
}

class LayersModel : public RenderModel {
 public:
  LayersModel(ModelEntry entry, const Workspace& workspace)
      : RenderModel(std::move(entry)), folder_(workspace.Path("layers")) {}

  std::vector<std::string> Inputs(const StageContext&) const override { return {"layers"}; }
  std::string SourcePath(const Workspace& workspace) const override { return workspace.Relative(folder_); }

  // At the supersampled size: 24 bytes a pixel (the blend's sums 20, the drawn image 4), the
  // raster of a window of rows (kCompositeWindowBytes) and 24 bytes for each layer drawn over a
  // pixel (LayerFragments), counted as the sets' largest depth complexity (their layers' pixels
  // over the sprite size: 1.3-1.8 on the castle) and a quarter more, as a desired view sees the
  // layers from elsewhere; at the sprites' size (the training images'), the `layers_references`
  // sets a view reads (8 bytes a pixel a layer) and one layer's mesh (60 bytes a pixel at most).
  // The castle at full size, the layers alone with the plane that fills their holes: 2 references
  // 2976 MB estimated, 2260 MB measured; 3 (configs/photos.yaml) 3252 MB estimated, 2742 MB measured.
  double ViewBytes(const StageContext& context, double pixels) const override {
    const double factor = static_cast<double>(context.params.Int("supersample"));
    const LayerSetsExtent extent = LargestLayerSets(folder_);
    const double references = static_cast<double>(context.params.Int("layers_references"));
    return pixels * factor * factor * (24.0 + 24.0 * std::min<double>(extent.layers, 1.25 * extent.complexity)) +
           static_cast<double>(kCompositeWindowBytes) + pixels * (references * 8.0 * extent.layers + 60.0);
  }

  // Every training view's layers/<image>/ that exists, each read whole here (so that a broken set
  // skips the model before any view is drawn) and kept as its header only: a view reads the sets
  // it is drawn from again.
  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) override {
    std::vector<LayerSet> sets;
    std::vector<std::string> folders;
    try {
      for (const std::string& name : scene.training) {
        const std::string folder = folder_ + "/" + name;
        if (!fs::exists(folder + "/layers.json")) continue;
        sets.push_back(ReadLayerSet(folder));
        for (SpriteLayer& layer : sets.back().layers) layer.rgba.release(), layer.residual.release();
        folders.push_back(folder);
      }
    } catch (const InputError& e) {
      return std::string(e.what());
    } catch (const IoError& e) {
      return std::string(e.what());
    }
    if (sets.empty()) return folder_ + " holds no training view's layers (run the layered_stereo stage)";
    Eigen::Vector3d centre = scene.axes_point;
    if (!scene.sparse_points.empty()) {
      centre.setZero();
      for (const Eigen::Vector3d& p : scene.sparse_points) centre += p;
      centre /= static_cast<double>(scene.sparse_points.size());
    }
    references_ = static_cast<int>(scene.context->params.Int("layers_references"));
    renderer_ = std::make_unique<LayersRenderer>(std::move(sets), std::move(folders), references_, centre);
    (*facts)["reference_views"] = renderer_->Sets();
    return std::nullopt;
  }

  ModelView Render(const RenderScene& scene, const DesiredView& view) const override {
    const Camera camera = scene.factor > 1 ? view.camera.Scaled(scene.factor) : view.camera;
    // Leave-one-out: a training view's own layers reproduce its photo (angle 0).
    const bool self = scene.exclude_self && renderer_->HasSet(view.name);
    ModelView drawn;
    drawn.fine = renderer_->Render(camera, view.cam_from_world, self ? view.name : std::string());
    drawn.sources = std::min<size_t>(renderer_->Sets() - (self ? 1 : 0), static_cast<size_t>(references_));
    return drawn;
  }

  // The layer count and the bytes of their files (sprites, residual depth).
  nlohmann::json Size() const override {
    uintmax_t bytes = 0;
    std::error_code ec;
    for (const auto& entry : fs::recursive_directory_iterator(folder_, ec)) {
      const std::string name = entry.path().filename().string();
      if (entry.is_regular_file() && name.rfind("layer_", 0) == 0) bytes += entry.file_size();
    }
    return {{"kind", "layers"}, {"elements", renderer_->Layers()}, {"reference_views", renderer_->Sets()}, {"bytes", bytes}};
  }

 private:
  std::string folder_;
  int references_ = 0;
  std::unique_ptr<LayersRenderer> renderer_;
};

std::optional<ParamError> CheckLayersParams(const Params& params) {
  if (params.Int("layers_references") < 1 || params.Int("layers_references") > 16) {
    return ParamError{"layers_references", "must be in [1, 16], got " + std::to_string(params.Int("layers_references"))};
  }
  return std::nullopt;
}

}  // namespace

RenderModelKind LayersKind() {
  RenderModelKind kind = NewRenderModelKind<LayersModel>(
      "layers", "the layered_stereo stage's sprites with depth (layers/<view>/): the layers_references nearest "
                "reference views, each composited back to front, blended by 1/angle^2");
  kind.params = {{"layers_references", ParamType::kInt, "2",
                  "layers: reference views blended per desired view (the nearest in viewing direction), in [1, 16]",
                  {}}};
  kind.check_params = CheckLayersParams;
  return kind;
}

}  // namespace ibmr
