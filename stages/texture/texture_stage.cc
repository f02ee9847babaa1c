// Adapter of the texture stage: inverse texture mapping of a mesh from the training views (seed
// 000 §6 lines 4587-4654), its view selection, exposure gains and seam leveling
// (view_selection.h, color_leveling.h), the atlas with object-space hole filling (seed 003 §6,
// texture_atlas.h), and the polygon view maps of view-dependent texture mapping (seed 003 §7,
// face_view_maps.h).
//
// Reads `mesh` (default surfels/mesh.ply; any triangle mesh PLY: the hull, a user's mesh), the
// model and undistorted images of the workspace (training views only). Faces are turned toward
// the views that see them, and views that disagree with a face's other views dropped
// (face_visibility.h). Images are streamed: two passes over the views (visibility, quality and
// colours; then the patches), each image in memory only while its view is worked on.
// Writes texture/mesh.obj + mesh.mtl + atlas_<page>.png, texture/mesh.glb (binary glTF, pages
// embedded) and texture/view_maps.bin (pipeline/core/view_maps.h). The record counts faces seen
// and unseen, patches, pages, the seam step at the seam vertices before and after leveling and
// across the seams in the written atlas (seam_step_atlas), the gains, and the view selection's
// energy per sweep.
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <mutex>

#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/textured_mesh.h"
#include "pipeline/core/undistorted_cameras.h"
#include "pipeline/core/view_maps.h"
#include "stages/texture/color_leveling.h"
#include "stages/texture/face_view_maps.h"
#include "stages/texture/face_visibility.h"
#include "stages/texture/texture_atlas.h"
#include "stages/texture/view_selection.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

TextureOptions ToOptions(const Params& p) {
  TextureOptions o;
  o.smoothness = p.Double("smoothness");
  o.max_iterations = static_cast<int>(p.Int("max_iterations"));
  o.visibility_epsilon = p.Double("visibility_epsilon");
  o.min_cos_angle = p.Double("min_cos_angle");
  o.consistency_tolerance = p.Double("consistency_tolerance");
  o.gain_compensation = p.Bool("gain_compensation");
  o.gain_sigma = p.Double("gain_sigma");
  o.seam_leveling = p.Bool("seam_leveling");
  o.leveling_smoothness = p.Double("leveling_smoothness");
  o.max_texture_size = static_cast<int>(p.Int("max_texture_size"));
  o.padding = static_cast<int>(p.Int("padding"));
  o.hole_cell = static_cast<int>(p.Int("hole_cell"));
  o.view_map_grid = static_cast<int>(p.Int("view_map_grid"));
  o.view_map_partial_penalty = p.Double("view_map_partial_penalty");
  return o;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

class TextureStage : public Stage {
 public:
  std::string Name() const override { return "texture"; }
  std::string Summary() const override {
    return "Texture atlas of a mesh from the training views (view selection, gains, seam leveling, hole filling) "
           "and view maps for view-dependent texture mapping (texture/)";
  }
  // 2: faces turned, photo-consistency, partly seen views in the view maps; 3: hidden and back ones
  // too; 4: those count view_map_partial_penalty farther in the grid.
  std::string Version() const override { return "4"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }

  std::vector<ParamSpec> Parameters() const override {
    const TextureOptions d;
    return {
        {"mesh", ParamType::kString, "surfels/mesh.ply", "triangle mesh to texture (PLY), workspace-relative or absolute"},
        {"smoothness", ParamType::kDouble, std::to_string(d.smoothness), "Potts weight of the view selection (data costs in [-1, 0]), >= 0"},
        {"max_iterations", ParamType::kInt, std::to_string(d.max_iterations), "sweeps of iterated conditional modes, [1, 1000]"},
        {"visibility_epsilon", ParamType::kDouble, std::to_string(d.visibility_epsilon), "z-buffer tolerance, fraction of depth, (0, 0.5)"},
        {"min_cos_angle", ParamType::kDouble, std::to_string(d.min_cos_angle), "faces seen more obliquely (cosine) are not used, [0, 1)"},
        {"consistency_tolerance", ParamType::kDouble, std::to_string(d.consistency_tolerance),
         "drop a face's views whose luminance is off its views' median by more than this fraction (>= 20 levels); 0: off, [0, 10]"},
        {"gain_compensation", ParamType::kBool, "true", "solve per-view exposure gains"},
        {"gain_sigma", ParamType::kDouble, std::to_string(d.gain_sigma), "prior sigma of a gain around 1, > 0"},
        {"seam_leveling", ParamType::kBool, "true", "global seam leveling (per-vertex colour offsets)"},
        {"leveling_smoothness", ParamType::kDouble, std::to_string(d.leveling_smoothness), "weight of equal offsets along edges, > 0"},
        {"max_texture_size", ParamType::kInt, std::to_string(d.max_texture_size), "largest atlas page side, texels, [64, 32768]"},
        {"padding", ParamType::kInt, std::to_string(d.padding), "image texels around each patch, [0, 64]"},
        {"hole_cell", ParamType::kInt, std::to_string(d.hole_cell), "texels per side of an unseen face's cell, [3, 64]"},
        {"view_map_grid", ParamType::kInt, std::to_string(d.view_map_grid), "view map samples per side, [2, 256]"},
        {"view_map_partial_penalty", ParamType::kDouble, std::to_string(d.view_map_partial_penalty),
         "radians a partly seen view counts farther in the view maps' nearest-view choice, [0, 10]"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (params.String("mesh").empty()) return ParamError{"mesh", "must name a mesh file (e.g. surfels/mesh.ply or hull/hull.ply)"};
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {context.workspace.SparseRelative(), context.workspace.ImagesRelative(), MeshRelative(context)};
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"texture"}; }

  void Run(StageContext& context) const override {
    const TextureOptions options = ToOptions(context.params);
    const std::string mesh_path = MeshPath(context);
    if (!fs::exists(mesh_path)) {
      throw InputError("texture.mesh: " + mesh_path + " does not exist (run the surfels stage, or set texture.mesh to a mesh such as hull/hull.ply)");
    }
    TriangleMesh mesh = ReadMeshPly(mesh_path);
    const std::string invalid = mesh.Validate();
    if (!invalid.empty()) throw InputError(mesh_path + ": " + invalid);
    if (mesh.faces.empty()) throw InputError(mesh_path + ": the mesh has no faces; nothing to texture (a point cloud? mesh it first)");
    FaceGeometry geometry = FaceGeometry::Of(mesh);
    size_t degenerate = 0;
    for (const Eigen::Vector3d& n : geometry.normals) degenerate += n.isZero();
    if (degenerate > 0) {
      spdlog::warn("[texture] {}: {} degenerate face(s) (zero area); no view sees them, they are hole-filled", mesh_path, degenerate);
    }

    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    if (names.empty()) throw InputError(context.workspace.SparseDir() + ": no training view to texture from");
    std::vector<TextureView> views(names.size());
    std::vector<Eigen::Vector3d> centers(names.size());
    for (size_t v = 0; v < names.size(); ++v) {
      const Image& image = *model.FindImage(names[v]);
      const Camera& camera = model.CameraOf(image);
      RequireUndistorted(camera, names[v], context.workspace.SparseDir() + "/cameras.txt", "texture");
      views[v] = {camera, image.cam_from_world};
      centers[v] = image.Center();
    }
    const auto load = [&](size_t v) {
      cv::Mat image = ReadImageColor(context.workspace.ImagesDir() + "/" + names[v]);
      if (image.cols != views[v].camera.width || image.rows != views[v].camera.height) {
        throw InputError(context.workspace.ImagesDir() + "/" + names[v] + ": image is " + std::to_string(image.cols) + "x" +
                         std::to_string(image.rows) + " but its camera says " + std::to_string(views[v].camera.width) + "x" +
                         std::to_string(views[v].camera.height));
      }
      return image;
    };

    // Pass 1: visibility and quality per view (seed 003 §5).
    auto start = std::chrono::steady_clock::now();
    std::vector<std::vector<std::pair<int, FaceObservation>>> seen(names.size());
    context.progress->Begin("texture: visibility", names.size());
    tbb::parallel_for(size_t{0}, names.size(), [&](size_t v) {
      ObserveView(mesh, geometry, views[v].camera, views[v].cam_from_world, load(v), static_cast<int>(v), options, &seen[v]);
      context.progress->Advance(1, names[v]);
    });
    context.progress->End();
    FaceObservations observations(mesh.faces.size());
    size_t zero_views = 0;
    for (size_t v = 0; v < names.size(); ++v) {
      if (seen[v].empty()) {
        ++zero_views;
        spdlog::warn("[texture] view {} sees no face of the mesh entirely (is the mesh in front of it?)", names[v]);
      }
      for (const auto& [f, o] : seen[v]) observations[f].push_back(o);
      std::vector<std::pair<int, FaceObservation>>().swap(seen[v]);
    }
    const size_t flipped = OrientFaces(&observations, &mesh, &geometry);
    // The view maps keep every view that sees a face (VDTM blends them by direction, and a view
    // that disagrees is often the one nearest the desired direction); the atlas, one view per
    // face, takes only the consistent ones.
    const FaceObservations visible = observations;
    size_t partial = 0;
    for (std::vector<FaceObservation>& list : observations) {
      const size_t before = list.size();
      list.erase(std::remove_if(list.begin(), list.end(), [](const FaceObservation& o) { return !o.SeesWhole(); }), list.end());
      partial += before - list.size();
    }
    context.metrics["observations_partial"] = partial;
    const size_t inconsistent = options.consistency_tolerance > 0 ? RemoveInconsistentViews(options.consistency_tolerance, &observations) : 0;
    context.metrics["faces_flipped"] = flipped;
    context.metrics["views_dropped_inconsistent"] = inconsistent;
    if (flipped > 0) spdlog::info("[texture] {} face(s) turned toward the views that see them", flipped);
    context.metrics["seconds_visibility"] = SecondsSince(start);
    context.metrics["views_seeing_nothing"] = zero_views;

    // View selection, gains, layout.
    start = std::chrono::steady_clock::now();
    const std::vector<std::array<int, 3>> adjacency = FaceAdjacency(mesh);
    const ViewSelection selection = SelectViews(observations, adjacency, options.smoothness, options.max_iterations);
    context.metrics["selection_energies"] = selection.energies;
    context.metrics["seconds_selection"] = SecondsSince(start);
    std::vector<double> gains(names.size(), 1.0);
    if (options.gain_compensation) gains = SolveGains(observations, static_cast<int>(names.size()), options.gain_sigma);
    context.metrics["gains"] = gains;
    TexturedMesh textured;
    const AtlasLayout layout = LayoutAtlas(mesh, selection.labels, adjacency, views, options, &textured);
    SeamLeveling leveling(mesh, selection.labels);

    // Pass 2: the patches per view.
    start = std::chrono::steady_clock::now();
    context.progress->Begin("texture: patches", names.size());
    tbb::parallel_for(size_t{0}, names.size(), [&](size_t v) {
      const cv::Mat image = load(v);
      CopyPatches(layout, static_cast<int>(v), image, gains[v], &textured);
      context.progress->Advance(1, names[v]);
    });
    context.progress->End();
    context.metrics["seconds_patches"] = SecondsSince(start);
    start = std::chrono::steady_clock::now();
    leveling.SetColorsFromFaces(observations, gains);
    context.metrics["seam_vertices"] = leveling.SeamVertices();
    context.metrics["seam_step_before"] = leveling.MeanSeamStep(false);
    if (options.seam_leveling) {
      if (leveling.Solve(options.leveling_smoothness)) {
        ApplyLeveling(layout, leveling, options.padding, &textured);
      } else {
        spdlog::warn("[texture] seam leveling: the solver failed; the atlas is written without it");
      }
    }
    context.metrics["seam_step_after"] = leveling.MeanSeamStep(options.seam_leveling);
    context.metrics["seam_step_atlas"] = SeamStepInAtlas(textured, selection.labels, adjacency);
    const size_t unreached = FillHoles(layout, selection.labels, observations, gains, adjacency, &textured);
    context.metrics["seconds_leveling"] = SecondsSince(start);

    size_t seen_faces = 0;
    for (int label : selection.labels) seen_faces += label >= 0;
    size_t patches = 0;
    for (const AtlasPatch& patch : layout.patches) patches += patch.label >= 0;
    context.metrics["faces"] = mesh.faces.size();
    context.metrics["faces_seen"] = seen_faces;
    context.metrics["faces_unseen"] = layout.hole_faces;
    context.metrics["faces_unseen_without_seen_neighbour"] = unreached;
    context.metrics["patches"] = patches;
    context.metrics["pages"] = textured.pages.size();
    nlohmann::json sizes = nlohmann::json::array();
    for (const cv::Mat& page : textured.pages) sizes.push_back({page.cols, page.rows});
    context.metrics["page_sizes"] = sizes;
    spdlog::info("[texture] {} faces: {} seen, {} hole-filled; {} patches on {} page(s); seam step {:.1f} -> {:.1f}",
                 mesh.faces.size(), seen_faces, layout.hole_faces, patches, textured.pages.size(),
                 static_cast<double>(context.metrics["seam_step_before"]), static_cast<double>(context.metrics["seam_step_after"]));

    // Outputs.
    start = std::chrono::steady_clock::now();
    const std::string folder = context.workspace.Path("texture");
    fs::create_directories(folder);
    const std::string check = textured.Validate();
    if (!check.empty()) throw std::runtime_error("texture: internal: the atlas is inconsistent: " + check);
    WriteTexturedObj(textured, folder, "mesh");
    WriteTexturedGlb(textured, folder + "/mesh.glb");
    WriteViewMaps(BuildViewMaps(geometry, visible, centers, names, options.view_map_grid, options.view_map_partial_penalty), folder + "/view_maps.bin");
    RemoveStalePages(folder, textured.pages.size());
    context.metrics["seconds_write"] = SecondsSince(start);
  }

 private:
  // Pages atlas_<n>.png beyond this run's count, left by a run with more pages (a smaller
  // max_texture_size): no material names them, but they would stay in the stage's hashed output.
  static void RemoveStalePages(const std::string& folder, size_t pages) {
    for (const auto& entry : fs::directory_iterator(folder)) {
      const std::string name = entry.path().filename().string();
      if (name.rfind("atlas_", 0) != 0 || entry.path().extension() != ".png") continue;
      const std::string number = name.substr(6, name.size() - 10);
      if (number.empty() || number.find_first_not_of("0123456789") != std::string::npos) continue;
      if (number.size() > 9 || std::stoull(number) >= pages) fs::remove(entry.path());
    }
  }

  static std::string MeshPath(const StageContext& context) {
    const std::string mesh = context.params.String("mesh");
    return fs::path(mesh).is_absolute() ? mesh : context.workspace.Path(mesh);
  }
  static std::string MeshRelative(const StageContext& context) {
    const std::string mesh = context.params.String("mesh");
    return fs::path(mesh).is_absolute() ? context.workspace.Relative(mesh) : mesh;
  }
};

}  // namespace

void RegisterStage_texture(StageRegistry* registry) { registry->Add(std::make_unique<TextureStage>()); }

}  // namespace ibmr
