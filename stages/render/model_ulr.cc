// The ULR render models (Unstructured Lumigraph Rendering, seed 001 section 4.1; render.h) over
// a geometric proxy:
//   plane                    the plane at the mean inverse depth of the sparse points seen by the
//                            training views, facing the desired camera [U 218]; with no sparse
//                            points, through the point nearest to all training optical axes. The
//                            background fill of every other model is this model's render.
//   [name=]<path>.ply[@N][|<fallback>.ply...]
//                            a mesh (binary/ascii PLY), workspace-relative or absolute, decimated
//                            to N faces with @N; where a ray misses it, the first hit of the next
//                            fallback counts (surfels/mesh.ply|hull/hull.ply: the hull fills the
//                            surface's holes). Visibility from the proxy's depth in each source
//                            (WithProxyDepth); holes within proxy_extend_px of it take the nearest
//                            covered depth. A missing mesh skips the model; a missing fallback is
//                            ignored with a warning.
#include <spdlog/spdlog.h>

#include <climits>
#include <filesystem>

#include "pipeline/core/errors.h"
#include "pipeline/core/ply_io.h"
#include "stages/render/mesh_decimation.h"
#include "stages/render/render_model.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// ULR of one desired view over `surface` (at camera.Scaled(factor)) from `sources`, less the
// view's own photo when exclude_self applies.
ModelView RenderUlrView(const RenderScene& scene, const std::vector<SourceView>& sources, const DesiredView& view,
                        const Camera& camera, ProxySurface surface) {
  std::vector<SourceView> own;
  const std::vector<SourceView>* used = scene.SourcesWithout(sources, view.name, &own);
  ModelView drawn;
  drawn.sources = used->size();
  drawn.fine = UlrRenderer(used, scene.options).Render(camera, view.cam_from_world, surface);
  drawn.surface = std::move(surface);
  return drawn;
}

Camera Supersampled(const RenderScene& scene, const DesiredView& view) {
  return scene.factor > 1 ? view.camera.Scaled(scene.factor) : view.camera;
}

class PlaneModel : public RenderModel {
 public:
  PlaneModel(ModelEntry entry, const Workspace&) : RenderModel(std::move(entry)) {}
  std::vector<std::string> Inputs(const StageContext&) const override { return {}; }
  std::string SourcePath(const Workspace&) const override { return "plane"; }
  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json*) override {
    if (!scene.PlanePossible()) {
      throw InputError("render: plane proxy: no sparse points and the training optical axes are parallel; "
                       "list a mesh proxy instead");
    }
    return std::nullopt;
  }
  ModelView Render(const RenderScene& scene, const DesiredView& view) const override {
    Plane plane;
    std::string placed = "mean_inverse_depth";
    if (!PlaneAtMeanInverseDepth(scene.sparse_points, view.cam_from_world, &plane)) {
      plane.normal = view.cam_from_world.Inverse().rotation * Eigen::Vector3d::UnitZ();
      plane.point = scene.axes_point;
      placed = "nearest_to_axes";
    }
    const Camera camera = Supersampled(scene, view);
    ModelView drawn =
        RenderUlrView(scene, scene.sources, view, camera, PlaneSurface(plane, camera, view.cam_from_world));
    drawn.facts["plane"] = placed;
    return drawn;
  }
  nlohmann::json Size() const override { return {{"kind", "plane"}, {"elements", 1}, {"bytes", 4 * sizeof(double)}}; }
  bool IsBackground() const override { return true; }
};

class MeshModel : public RenderModel {
 public:
  MeshModel(ModelEntry entry, const Workspace& workspace) : RenderModel(std::move(entry)) {
    path_ = AbsolutePath(entry_.path, workspace);
    for (const std::string& fallback : entry_.fallbacks) fallback_paths_.push_back(AbsolutePath(fallback, workspace));
  }
  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.Relative(path_)};
    for (const std::string& path : fallback_paths_) inputs.push_back(context.workspace.Relative(path));
    return inputs;
  }
  std::string SourcePath(const Workspace& workspace) const override { return workspace.Relative(path_); }

  // The mesh read and decimated ahead (a decimation takes 5 s on one core for templeRing's 227k
  // faces, three of them in its config).
  std::function<void()> BackgroundWork() override {
    if (entry_.detail <= 0) return {};
    return [this] { read_ = ReadAndDecimate(); };
  }

  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) override {
    if (!read_) read_ = ReadAndDecimate();
    if (read_->skipped) return read_->skipped;
    meshes_.push_back(std::move(read_->mesh));
    read_.reset();
    for (const std::string& path : fallback_paths_) {
      TriangleMesh fallback = fs::exists(path) ? ReadMeshPly(path) : TriangleMesh();
      if (fallback.faces.empty() || !fallback.Validate().empty()) {
        spdlog::warn("[render] proxy {}: fallback {} is missing or has no usable faces; ignored", Name(), path);
        continue;
      }
      meshes_.push_back(std::move(fallback));
    }
    for (const TriangleMesh& mesh : meshes_) layers_.push_back(&mesh);
    if (meshes_.size() > 1) {
      (*facts)["fallbacks"] = nlohmann::json::array();
      for (const std::string& path : fallback_paths_) {
        (*facts)["fallbacks"].push_back(scene.context->workspace.Relative(path));
      }
    }
    sources_ = WithProxyDepth(scene.sources, layers_, scene.options.proxy_extend_px);
    return std::nullopt;
  }

  ModelView Render(const RenderScene& scene, const DesiredView& view) const override {
    const Camera camera = Supersampled(scene, view);
    return RenderUlrView(scene, sources_, view, camera,
                         MeshSurface(layers_, camera, view.cam_from_world, scene.options.proxy_extend_px * scene.factor));
  }

  // As a binary PLY stores the meshes drawn (decimated ones are not written): positions, normals
  // and colours per vertex, a count and three indices per face.
  nlohmann::json Size() const override {
    size_t triangles = 0, bytes = 0;
    for (const TriangleMesh* layer : layers_) {
      triangles += layer->faces.size();
      const size_t per_vertex = 12 + (layer->normals.empty() ? 0 : 12) + (layer->colors.empty() ? 0 : 3);
      bytes += layer->vertices.size() * per_vertex + layer->faces.size() * 13;
    }
    return {{"kind", "mesh"}, {"elements", triangles}, {"triangles", triangles}, {"bytes", bytes}};
  }

 private:
  struct ReadMesh {
    TriangleMesh mesh;
    std::optional<std::string> skipped;  // why the mesh cannot be drawn
  };
  ReadMesh ReadAndDecimate() const {
    ReadMesh read;
    if (!fs::exists(path_)) {
      read.skipped = path_ + " does not exist";
      return read;
    }
    read.mesh = ReadMeshPly(path_);
    const std::string invalid = read.mesh.Validate();
    if (read.mesh.faces.empty() || !invalid.empty()) {
      read.skipped = path_ + " has no usable faces" + (invalid.empty() ? "" : " (" + invalid + ")");
      return read;
    }
    if (entry_.detail > 0) Decimate(&read.mesh);
    return read;
  }

  void Decimate(TriangleMesh* mesh) const {
    const size_t before = mesh->faces.size();
    size_t refused = 0;
    *mesh = DecimateMesh(*mesh, static_cast<size_t>(entry_.detail), &refused);
    spdlog::info("[render] proxy {}: {} faces decimated to {}{}", Name(), before, mesh->faces.size(),
                 refused ? " (" + std::to_string(refused) + " non-manifold faces dropped)" : std::string());
    if (mesh->faces.size() > static_cast<size_t>(entry_.detail)) {
      spdlog::warn("[render] proxy {}: {} faces, over the budget of {}: OpenMesh refused the remaining "
                   "collapses (they would flip a face or break the manifold); its size in renders.json is "
                   "the faces kept",
                   Name(), mesh->faces.size(), entry_.detail);
    }
  }

  std::string path_;
  std::vector<std::string> fallback_paths_;
  std::optional<ReadMesh> read_;              // the mesh as read (and decimated), until Prepare takes it
  std::vector<TriangleMesh> meshes_;          // the mesh, then the fallbacks that could be read
  std::vector<const TriangleMesh*> layers_;
  std::vector<SourceView> sources_;           // with the proxy's depth (visibility)
};

// "ground_truth/mesh.ply" -> ground_truth_mesh; "hull/hull.ply" -> hull; "mesh.ply" -> mesh.
std::string MeshName(const ModelEntry& entry) {
  const fs::path path(entry.path);
  const std::string stem = path.stem().string();
  const std::string folder = path.parent_path().filename().string();
  return folder.empty() || folder == stem ? stem : folder + "_" + stem;
}

}  // namespace

RenderModelKind PlaneKind() {
  return NewRenderModelKind<PlaneModel>(
      "plane", "ULR over the plane at the mean inverse depth of the sparse points (seed 001 [U 218])");
}

// Any entry that names no other kind: a mesh path.
RenderModelKind MeshKind() {
  RenderModelKind kind = NewRenderModelKind<MeshModel>(
      "", "ULR over a mesh (decimated to N faces), fallback meshes filling where a ray misses it");
  kind.syntax = "<path>.ply[@N][|<fallback>.ply...]";
  kind.min_detail = 4;
  kind.max_detail = INT_MAX;
  kind.detail_meaning = "faces of a mesh";
  kind.default_name = MeshName;
  return kind;
}

}  // namespace ibmr
