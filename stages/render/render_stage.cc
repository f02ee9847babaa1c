// Adapter of the render stage (Unstructured Lumigraph Rendering, seed 001 section 4.1; see
// render.h): renders the held-out views of sparse/ (or the views listed in `views`, or a camera
// given by `novel_look_at`) from the training views only, once per proxy.
//
// Proxies (`proxies`, in order; the first one present is the primary):
//   plane                    plane at the mean inverse depth of the sparse points seen by training
//                            views, facing the desired camera [U 218]; with no sparse points, through
//                            the point nearest to all training optical axes
//   <path> or <name>=<path>  a mesh (binary/ascii PLY), workspace-relative or absolute; visibility
//                            from its depth in each source camera. A missing file is skipped with a
//                            warning and listed as skipped in renders/renders.json.
//   <name>=<path>|<fallback>...  a mesh with fallbacks: where a ray misses the first mesh, the
//                            first hit of the next one counts (e.g. surfels/mesh.ply|hull/hull.ply:
//                            the hull fills the surface's holes); a missing fallback is ignored with
//                            a warning.
//   splat_depth[:TYPE]       point splatting of the training views' depth maps (seed 004; splat.h):
//                            dense/stereo/depth_maps/<view>.<TYPE>.bin (TYPE: splat_depth_type by
//                            default; "truth": ground_truth/depth/<view>.bin) with the photos,
//                            skins and outliers flagged (depth_images.h), every drawable sample kept
//   splat_depth_merged       the same after tile merging [N 4.6]: one sample per surface point
//   splat_surfels            the oriented discs of surfels/surfels.ply
//   textured                 the texture stage's mesh drawn with its atlas (texture/mesh.obj with
//                            mesh.mtl and atlas_<page>.png; textured.h): one colour per surface point
//   vdtm                     view-dependent texture mapping (seed 003 §7-8; vdtm.h): per face and
//                            frame, the view map of texture/view_maps.bin blends at most 3 training
//                            photos; faces no photo sees take the atlas of texture/mesh.obj (§6).
//                            exclude_self drops the rendered view's own photo from every blend.
//   A missing texture/mesh.obj or texture/view_maps.bin skips textured / vdtm like a missing mesh.
//   layers                   the layered_stereo stage's sprites with depth (layers/<image>/; layers.h):
//                            the layers_references reference views nearest in viewing direction,
//                            each composited back to front, blended 1 / angle^2
// exclude_self (leave-one-out, for training views listed in `views`): ULR and vdtm leave the view's
// photo out of every blend, splat_depth its depth samples (its depth map still took part in the
// model's skin test and tile merging), layers its reference set. textured and splat_surfels are one
// model made from every photo: a warning says such views are not held out. Held-out views are
// never sources, so this changes nothing for them.
// Metrics per model: ms_per_frame_<name>, the mean wall time of one view's render (supersampled
// render and downsampling, not the file writes; views run concurrently, so it compares models of
// one run, not machines), and seconds_<name> for the whole model including its preparation.
// Writes renders/<proxy>/<image stem>.png, <image stem>.coverage.png (255 covered) and
// <image stem>.json (the view's coverage, sources, files) per proxy,
// the primary proxy's copies as renders/<image stem>.png and .coverage.png, and renders/renders.json.
// With `background: plane`, every other model's holes are also filled from the plane proxy's render
// of the same view: <image stem>.filled.png and .filled.coverage.png, listed as the view's "filled"
// and scored apart by score (a view rendered without a fill loses any such files of an earlier run).
// Views whose images share a stem are refused (their files would collide), as are two proxies with
// one name.
#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <map>
#include <memory>
#include <set>
#include <charconv>
#include <filesystem>
#include <mutex>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/layered_sprites.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/process_memory.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/textured_mesh.h"
#include "pipeline/core/undistorted_cameras.h"
#include "pipeline/core/view_maps.h"
#include "stages/render/depth_image_io.h"
#include "stages/render/mesh_decimation.h"
#include "stages/render/render.h"
#include "stages/render/splat.h"
#include "stages/render/layers.h"
#include "stages/render/textured.h"
#include "stages/render/vdtm.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

enum class ModelKind { kPlane, kMesh, kSplatDepth, kSplatDepthMerged, kSplatSurfels, kTextured, kVdtm, kLayers };

struct ProxySpec {
  std::string name;
  ModelKind kind = ModelKind::kMesh;
  std::string path;                    // empty for the plane and the depth-image splats; absolute otherwise
  std::string view_maps;               // vdtm: absolute path of the view maps
  std::string depth_type;              // splat_depth[:TYPE]: the depth maps drawn (empty: splat_depth_type)
  std::vector<std::string> fallbacks;  // absolute paths of meshes that fill where `path` misses
  int detail = 0;                      // "@N": a mesh decimated to N faces; depth images at 1/N resolution
};

std::string Absolute(const std::string& path, const Workspace& workspace) {
  return fs::path(path).is_absolute() ? path : workspace.Path(path);
}

// "plane" | "path" | "name=path", each with an optional "@N" (smaller models for selection: a mesh
// decimated to N faces, splat_depth from every N x N block). A default name: the file stem,
// prefixed by its folder when the stem alone says little ("ground_truth/mesh.ply" ->
// ground_truth_mesh; "hull/hull.ply" -> hull), and "_N" for a detail.
ProxySpec ParseProxy(const std::string& entry, const Workspace& workspace) {
  ProxySpec spec;
  std::string path = entry;
  const size_t eq = entry.find('=');
  if (eq != std::string::npos) {
    spec.name = entry.substr(0, eq);
    path = entry.substr(eq + 1);
  }
  const size_t at = path.find('@');
  std::string detail_suffix;
  if (at != std::string::npos) {
    const size_t end = std::min(path.find('|', at), path.size());
    detail_suffix = path.substr(at + 1, end - at - 1);
    int value = 0;
    const auto [last, error] = std::from_chars(detail_suffix.data(), detail_suffix.data() + detail_suffix.size(), value);
    spec.detail = error == std::errc() && last == detail_suffix.data() + detail_suffix.size() ? value : -1;
    path.erase(at, end - at);
  }
  const auto name_or = [&](const std::string& fallback) {
    if (spec.name.empty()) spec.name = fallback + (spec.detail > 0 ? "_" + detail_suffix : "");
  };
  for (const std::string splat : {"splat_depth:", "splat_depth_merged:"}) {
    if (path.rfind(splat, 0) == 0) {
      spec.depth_type = path.substr(splat.size());
      path = splat.substr(0, splat.size() - 1);
      name_or(path + "_" + spec.depth_type);
    }
  }
  if (path == "plane" || path == "splat_depth" || path == "splat_depth_merged") {
    spec.kind = path == "plane"         ? ModelKind::kPlane
                : path == "splat_depth" ? ModelKind::kSplatDepth
                                        : ModelKind::kSplatDepthMerged;
    name_or(path);
    return spec;
  }
  if (path == "splat_surfels") {
    spec.kind = ModelKind::kSplatSurfels;
    name_or(path);
    spec.path = workspace.Path("surfels/surfels.ply");
    return spec;
  }
  if (path == "layers") {
    spec.kind = ModelKind::kLayers;
    name_or(path);
    spec.path = workspace.Path("layers");
    return spec;
  }
  if (path == "textured" || path == "vdtm") {
    spec.kind = path == "textured" ? ModelKind::kTextured : ModelKind::kVdtm;
    name_or(path);
    spec.path = workspace.Path("texture/mesh.obj");
    if (spec.kind == ModelKind::kVdtm) spec.view_maps = workspace.Path("texture/view_maps.bin");
    return spec;
  }
  for (size_t bar = path.rfind('|'); bar != std::string::npos; bar = path.rfind('|')) {
    spec.fallbacks.insert(spec.fallbacks.begin(), Absolute(path.substr(bar + 1), workspace));
    path = path.substr(0, bar);
  }
  const fs::path p(path);
  spec.path = Absolute(path, workspace);
  {
    const std::string stem = p.stem().string();
    const std::string folder = p.parent_path().filename().string();
    name_or(folder.empty() || folder == stem ? stem : folder + "_" + stem);
  }
  return spec;
}

std::string Stem(const std::string& image_name) { return fs::path(image_name).stem().string(); }

// Which sub-samples a model drew, for Downsample, where that is its coverage (splats, textured
// meshes: every drawn sub-sample has a colour).
ProxySurface HitsOf(const RenderResult& fine) {
  ProxySurface surface;
  surface.width = fine.coverage.cols;
  surface.height = fine.coverage.rows;
  surface.hit.assign(static_cast<size_t>(surface.width) * surface.height, 0);
  for (int y = 0; y < surface.height; ++y) {
    const uint8_t* row = fine.coverage.ptr<uint8_t>(y);
    for (int x = 0; x < surface.width; ++x) surface.hit[static_cast<size_t>(y) * surface.width + x] = row[x] != 0;
  }
  return surface;
}

Camera PinholeOf(const Camera& camera, const std::string& image_name, const Workspace& workspace) {
  RequireUndistorted(camera, image_name, workspace.SparseDir() + "/cameras.txt", "render");
  return camera;
}

class RenderStage : public Stage {
 public:
  std::string Name() const override { return "render"; }
  std::string Summary() const override {
    return "Image-based rendering of held-out views from the training views (ULR over plane / mesh proxies, "
           "splats, textured mesh, view-dependent texture mapping)";
  }
  // 2: splat models, background fill; 3: elliptical splat footprints; 4: model sizes; 5: textured
  // and vdtm models (texture stage), ms_per_frame_<model> metrics; 6: vdtm per-pixel depth test;
  // 7: no frame times in renders.json (the record has them).
  std::string Version() const override { return "8"; }
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
  // One view's buffers, for the model that needs the most (models run one after the other): ULR,
  // splats and texture models 88 bytes per supersampled pixel (colour, depth, weights and blend
  // accumulators), as measured on the full-size Sceaux castle (2832x2128, supersample 2: 2.0 GB a
  // view besides the 0.4 GB of sources and program). `layers`, at the supersampled size: 24 bytes a
  // pixel (the blend's sums 20, the drawn image 4), the raster of a window of rows
  // (kCompositeWindowBytes) and 24 bytes for each layer drawn over a pixel (LayerFragments),
  // counted as the sets' largest depth complexity (their layers' pixels over the sprite size:
  // 1.3-1.8 on the castle) and a quarter more, as a desired view sees the layers from elsewhere; at
  // the sprites' size (the training images'), the `layers_references` sets a view reads (8 bytes a
  // pixel a layer) and one layer's mesh (60 bytes a pixel at most). The castle at full size, the
  // layers alone with the plane that fills their holes: 2 references 2976 MB estimated, 2260 MB
  // measured; 3 (configs/photos.yaml) 3252 MB estimated, 2742 MB measured.
  double ViewMemoryMb(const StageContext& context) const override {
    const double pixels = LargestTrainingImage(context).Pixels();
    const double factor = static_cast<double>(context.params.Int("supersample"));
    double bytes = pixels * factor * factor * 88.0;
    for (const std::string& entry : context.params.StringList("proxies")) {
      const ProxySpec spec = ParseProxy(entry, context.workspace);
      if (spec.kind != ModelKind::kLayers) continue;
      const LayerSetsExtent extent = LargestLayerSets(spec.path);
      const double references = static_cast<double>(context.params.Int("layers_references"));
      bytes = std::max(bytes, pixels * factor * factor * (24.0 + 24.0 * std::min<double>(extent.layers, 1.25 * extent.complexity)) +
                                  static_cast<double>(kCompositeWindowBytes) + pixels * (references * 8.0 * extent.layers + 60.0));
    }
    return bytes / 1048576.0;
  }
  // The most layers in one reference set under `folder` (layers/<image>/layers.json, small files)
  // and the largest depth complexity (a set's layers' pixels over its sprite size), or
  // layered_stereo's largest max_layers (16) for both when there is none yet (planned before that
  // stage runs) or one cannot be read: an estimate must not fall short.
  struct LayerSetsExtent {
    int layers = 0;
    double complexity = 0;
  };
  static LayerSetsExtent LargestLayerSets(const std::string& folder) {
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
  // The photographed views to render: render.views, else the held-out ones.
  static std::vector<std::string> PhotoViewNames(const StageContext& context) {
    std::vector<std::string> names = context.params.StringList("views");
    if (names.empty()) names.assign(context.heldout_images.begin(), context.heldout_images.end());
    return names;
  }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"proxies", ParamType::kStringList, "[plane]",
         "proxies in order (the first present is primary): plane, or a mesh path (workspace-relative), or name=path",
         {}},
        {"views", ParamType::kStringList, "[]", "image names of sparse/ to render; empty: every held-out view", {}},
        {"exclude_self", ParamType::kBool, "true", "never use the rendered view's own photo (leave-one-out)", {}},
        {"k", ParamType::kInt, "4", "cameras in the blending neighbourhood, the k-th is the threshold, in [2, 64]", {}},
        {"alpha", ParamType::kDouble, "1", "weight of the angle penalty (radians), >= 0", {}},
        {"beta", ParamType::kDouble, "0", "weight of the resolution penalty (per scene unit), >= 0", {}},
        {"gamma", ParamType::kDouble, "1", "weight of the field-of-view penalty, >= 0", {}},
        {"epipole_consistent", ParamType::kBool, "true", "multiply weights by 1/penalty (exact epipole consistency)",
         {}},
        {"fov_margin", ParamType::kDouble, "0.05",
         "border band where the field-of-view penalty rises, fraction of min(width, height), in (0, 0.5)", {}},
        {"max_penalty", ParamType::kDouble, "3.14159265358979",
         "penalty of a missing camera when fewer than k are usable; caps the threshold, > 0", {}},
        {"visibility_epsilon", ParamType::kDouble, "0.01", "relative depth tolerance of visibility, in (0, 1)", {}},
        {"proxy_extend_px", ParamType::kInt, "0",
         "mesh proxies: holes within this many pixels of the mesh take the nearest covered depth (desired view and "
         "sources' visibility), in [0, 16]",
         {}},
        {"supersample", ParamType::kInt, "1",
         "sub-samples per pixel side, box-filtered (anti-aliased silhouettes), in [1, 4]", {}},
        {"background", ParamType::kString, "plane",
         "fills every model's holes in a second image <view>.filled.png, scored apart: plane (the plane proxy) or "
         "none",
         {}},
        {"layers_references", ParamType::kInt, "2",
         "layers: reference views blended per desired view (the nearest in viewing direction), in [1, 16]", {}},
        {"splat_depth_type", ParamType::kString, "geometric",
         "depth maps splat_depth draws: geometric (multi_depth), photometric (plane_sweep) or truth "
         "(ground_truth/depth); an entry splat_depth:TYPE overrides it",
         {}},
        {"splat_radius_scale", ParamType::kDouble, "1",
         "scales the splats' radii (source pixel half-diagonals, surfel radii), in (0, 8]", {}},
        {"splat_max_radius_px", ParamType::kDouble, "8", "bound on a splat's radius in output pixels, in [0.5, 256]",
         {}},
        {"splat_max_stretch", ParamType::kDouble, "2",
         "bound on a depth sample's footprint along its tangent plane, in source pixels, in [1, 16]; "
         "larger trusts the normals at grazing angles (true depth: 4 -> +1.6 dB, stereo depth: -0.1 to -0.3 dB)",
         {}},
        {"splat_depth_tolerance", ParamType::kDouble, "0.05",
         "relative depth band of samples blended at a pixel, in (0, 1)", {}},
        {"splat_angle_epsilon_deg", ParamType::kDouble, "0.5",
         "softens the 1/angle^2 weight of a sample's source ray, in (0, 90]", {}},
        {"splat_k", ParamType::kInt, "4",
         "source views blended per pixel by splat_depth (ULR's k); 0: all, weighted 1/angle^2, in [0, 8]", {}},
        {"splat_min_confidence", ParamType::kDouble, "0", "depth samples below this confidence are not drawn, in [0, 1]",
         {}},
        {"skin_tolerance", ParamType::kDouble, "0.02", "relative free-space margin of skin detection, in (0, 1)", {}},
        {"skin_views", ParamType::kInt, "8", "views each depth image is tested against for skins (0: none), in [0, 64]",
         {}},
        {"free_space_views", ParamType::kInt, "2",
         "a depth sample in front of the depth of this many of the skin_views views is dropped (0: kept), in [0, 64]",
         {}},
        {"color_tolerance", ParamType::kInt, "0",
         "a depth sample whose colour differs by more than this (0-255) from most views that see its surface is "
         "dropped (0: no colour test), in [0, 255]",
         {}},
        {"merge_tolerance", ParamType::kDouble, "0.01", "relative depth agreement of merged samples, in (0, 1)", {}},
        {"merge_views", ParamType::kInt, "8", "views a depth sample is compared with when merging, in [1, 64]", {}},
        {"novel_look_at", ParamType::kDoubleList, "[]",
         "extra camera: eye x y z, target x y z [, up x y z] (intrinsics of the first training view); rendered as "
         "novel.png",
         {}},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    if (!ToSplatOptions(params).Check(&error) || !ToDepthImageOptions(params).Check(&error)) {
      // The YAML keys carry a prefix the options structs do not know.
      const ParamError e = ParamError::FromCheck(error);
      static const std::set<std::string> unprefixed = {"skin_tolerance", "skin_views", "free_space_views", "color_tolerance",
                                                       "merge_tolerance", "merge_views", "tile_size"};
      return ParamError{unprefixed.count(e.key) ? e.key : (e.key == "min_confidence" ? "splat_min_confidence" : "splat_" + e.key),
                        e.message};
    }
    const std::string background = params.String("background");
    if (background != "plane" && background != "none") {
      return ParamError{"background", "must be plane or none, got \"" + background + "\""};
    }
    const auto bad_type = [](const std::string& type) {
      return type != "geometric" && type != "photometric" && type != "truth";
    };
    if (bad_type(params.String("splat_depth_type"))) {
      return ParamError{"splat_depth_type",
                        "must be geometric, photometric or truth, got \"" + params.String("splat_depth_type") + "\""};
    }
    if (params.Int("supersample") < 1 || params.Int("supersample") > 4) {
      return ParamError{"supersample", "must be in [1, 4], got " + std::to_string(params.Int("supersample"))};
    }
    const size_t look = params.DoubleList("novel_look_at").size();
    if (look != 0 && look != 6 && look != 9) {
      return ParamError{"novel_look_at", "expected 0, 6 or 9 numbers (eye, target[, up]), got " + std::to_string(look)};
    }
    if (look != 0) {
      const std::vector<double> v = params.DoubleList("novel_look_at");
      const Eigen::Vector3d eye(v[0], v[1], v[2]), target(v[3], v[4], v[5]);
      if (!eye.allFinite() || !target.allFinite() || !((target - eye).norm() > 0)) {
        return ParamError{"novel_look_at", "eye (the first 3 numbers) and target (the next 3) must be distinct finite "
                                           "points; move the target to where the camera should look"};
      }
    }
    if (params.Int("layers_references") < 1 || params.Int("layers_references") > 16) {
      return ParamError{"layers_references", "must be in [1, 16], got " + std::to_string(params.Int("layers_references"))};
    }
    if (params.StringList("proxies").empty()) return ParamError{"proxies", "list at least one proxy (e.g. [plane])"};
    std::map<std::string, std::string> entry_of_name;  // each model writes renders/<name>/
    for (const std::string& entry : params.StringList("proxies")) {
      if (entry.empty() || entry.back() == '=') return ParamError{"proxies", "empty proxy entry \"" + entry + "\""};
      const ProxySpec spec = ParseProxy(entry, Workspace("."));
      const auto [named, fresh] = entry_of_name.emplace(spec.name, entry);
      if (!fresh) {
        return ParamError{"proxies", "\"" + named->second + "\" and \"" + entry + "\" are both named \"" + spec.name +
                                         "\" (both would write renders/" + spec.name +
                                         "/); name one, e.g. " + spec.name + "_2=" +
                                         entry.substr(entry.find('=') == std::string::npos ? 0 : entry.find('=') + 1)};
      }
      if (!spec.depth_type.empty() && bad_type(spec.depth_type)) {
        return ParamError{"proxies", "\"" + entry + "\": depth type must be geometric, photometric or truth"};
      }
      if (entry.find('@') != std::string::npos && spec.detail <= 0) {
        return ParamError{"proxies", "\"" + entry + "\": @N needs a positive whole number (faces of a mesh, block size of splat_depth)"};
      }
      if (spec.kind == ModelKind::kMesh && spec.detail > 0 && spec.detail < 4) {
        return ParamError{"proxies", "\"" + entry + "\": a mesh needs at least 4 faces"};
      }
      if ((spec.kind == ModelKind::kSplatDepth || spec.kind == ModelKind::kSplatDepthMerged) && spec.detail > 16) {
        return ParamError{"proxies", "\"" + entry + "\": splat_depth blocks are at most 16 pixels wide"};
      }
      if (spec.detail > 0 && spec.kind != ModelKind::kMesh && spec.kind != ModelKind::kSplatDepth &&
          spec.kind != ModelKind::kSplatDepthMerged) {
        return ParamError{"proxies", "\"" + entry + "\": @N applies to meshes and splat_depth only"};
      }
    }
    return std::nullopt;
  }

  // Workspace-relative where the file lies inside the workspace, so that the cache key does not
  // depend on where the workspace sits (a sweep's variants, a copy, a cluster's mount point).
  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.ImagesRelative(), context.workspace.SparseRelative()};
    for (const std::string& entry : context.params.StringList("proxies")) {
      const ProxySpec spec = ParseProxy(entry, context.workspace);
      if (spec.kind == ModelKind::kSplatDepth || spec.kind == ModelKind::kSplatDepthMerged) {
        const std::string type = spec.depth_type.empty() ? context.params.String("splat_depth_type") : spec.depth_type;
        inputs.push_back(type == "truth" ? "ground_truth/depth" : "dense/stereo");
      }
      if (spec.kind == ModelKind::kLayers) {
        inputs.push_back("layers");
        continue;
      }
      if (spec.kind == ModelKind::kTextured || spec.kind == ModelKind::kVdtm) {
        // mesh.obj with its mesh.mtl and atlas pages (and view_maps.bin): the texture stage's folder.
        const std::string folder = context.workspace.Relative(fs::path(spec.path).parent_path().string());
        if (std::find(inputs.begin(), inputs.end(), folder) == inputs.end()) inputs.push_back(folder);
        continue;
      }
      if (!spec.path.empty()) inputs.push_back(context.workspace.Relative(spec.path));
      for (const std::string& fallback : spec.fallbacks) inputs.push_back(context.workspace.Relative(fallback));
    }
    return inputs;
  }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"renders"}; }

  void Run(StageContext& context) const override {
    const RenderOptions options = ToOptions(context.params);
    const SparseModel model = context.LoadModel();
    if (model.images.empty()) throw InputError(context.workspace.SparseDir() + ": no posed image; run import or sfm first");

    // Source views: training images only; a held-out photo's pixels are never read.
    std::vector<std::string> training;
    for (const std::string& name : context.TrainingImageNames(model)) {
      if (!context.IsHeldOut(name)) training.push_back(name);
    }
    if (training.empty()) throw InputError("render: every image is held out; nothing to render from (check holdout)");
    std::vector<SourceView> sources(training.size());
    tbb::parallel_for(size_t{0}, training.size(), [&](size_t i) {
      const Image& image = *model.FindImage(training[i]);
      sources[i].name = image.name;
      sources[i].camera = PinholeOf(model.CameraOf(image), image.name, context.workspace);
      sources[i].cam_from_world = image.cam_from_world;
      sources[i].image = ReadImageColor(context.workspace.ImagesDir() + "/" + image.name);
      if (sources[i].image.cols != sources[i].camera.width || sources[i].image.rows != sources[i].camera.height) {
        throw InputError(context.workspace.ImagesDir() + "/" + image.name + ": image is " +
                         std::to_string(sources[i].image.cols) + "x" + std::to_string(sources[i].image.rows) +
                         " but its camera says " + std::to_string(sources[i].camera.width) + "x" +
                         std::to_string(sources[i].camera.height));
      }
    });

    // Desired views.
    struct Desired {
      std::string name, stem;
      Camera camera;
      Rigid3d cam_from_world;
    };
    std::vector<Desired> desired;
    for (const std::string& name : PhotoViewNames(context)) {
      const Image* image = model.FindImage(name);
      if (!image) throw InputError("render.views: no image named \"" + name + "\" in " + context.workspace.SparseDir());
      desired.push_back({name, Stem(name), PinholeOf(model.CameraOf(*image), name, context.workspace), image->cam_from_world});
    }
    const std::vector<double> look = context.params.DoubleList("novel_look_at");
    if (!look.empty()) {
      const Eigen::Vector3d eye(look[0], look[1], look[2]), target(look[3], look[4], look[5]);
      const Eigen::Vector3d up = look.size() == 9 ? Eigen::Vector3d(look[6], look[7], look[8]) : Eigen::Vector3d(0, 0, 1);
      desired.push_back({"novel", "novel", sources[0].camera, LookAt(eye, target, up)});
    }
    if (desired.empty()) {
      spdlog::warn("[render] no view to render: the config holds no view out (holdout) and lists no render.views");
    }
    // Every file of a view is named by its image's stem (renders/<proxy>/<stem>.png, the checkpoint
    // keys): two views with one stem (view_000.png and view_000.jpg, left/0001.jpg and
    // right/0001.jpg) would overwrite each other's renders and be scored against the wrong photo.
    {
      std::map<std::string, std::string> view_of_stem;
      for (const Desired& view : desired) {
        const auto [other, fresh] = view_of_stem.emplace(view.stem, view.name);
        if (!fresh) {
          throw InputError("render: views \"" + other->second + "\" and \"" + view.name +
                           "\" would both be written as renders/<proxy>/" + view.stem +
                           ".png (same file stem); rename one of the images (in " + context.workspace.ImagesDir() +
                           " and " + context.workspace.SparseDir() + "/images.txt), or render only one of them " +
                           "(render.views, holdout)");
        }
      }
    }
    // A shard renders its views only; its per-view loops below then run unsharded over them (the
    // marks are per model and view), and it ends before the files that gather every view.
    const std::set<std::string> shard = std::move(context.shard_views);
    context.shard_views.clear();
    if (!shard.empty()) {
      std::string unknown;
      for (const std::string& name : shard) {
        const bool known = std::any_of(desired.begin(), desired.end(), [&](const Desired& d) { return d.name == name; });
        if (!known) unknown += (unknown.empty() ? "" : ", ") + name;
      }
      if (!unknown.empty()) throw InputError("--views: not among render's views (held out or render.views): " + unknown);
      desired.erase(std::remove_if(desired.begin(), desired.end(), [&](const Desired& d) { return !shard.count(d.name); }),
                    desired.end());
    }
    ShardFinished shard_done;

    // Plane proxy inputs: sparse points seen by a training view, else the point nearest to the axes.
    std::vector<Eigen::Vector3d> sparse_points;
    std::set<int> training_ids;
    for (const std::string& name : training) training_ids.insert(model.FindImage(name)->image_id);
    for (const auto& [id, point] : model.points) {
      // A non-finite point would make the plane's depth and the layers' scene centre NaN (a black
      // render reported as rendered); it says nothing about where the scene is.
      if (!point.xyz.allFinite()) continue;
      bool seen = point.track.empty();
      for (const TrackElement& element : point.track) seen = seen || training_ids.count(element.image_id) > 0;
      if (seen) sparse_points.push_back(point.xyz);
    }
    std::vector<Eigen::Vector3d> centers, directions;
    for (const std::string& name : training) {
      centers.push_back(model.FindImage(name)->Center());
      directions.push_back(model.FindImage(name)->ViewingDirection());
    }
    Eigen::Vector3d axes_point = Eigen::Vector3d::Zero();
    const bool have_axes_point = PointNearestToAxes(centers, directions, &axes_point);

    const int factor = static_cast<int>(context.params.Int("supersample"));
    // Leave-one-out sources of a desired view (a training view rendered from the others).
    const auto sources_for = [&](const std::vector<SourceView>& all, const Desired& view, std::vector<SourceView>* own) {
      const bool has_self = std::any_of(all.begin(), all.end(), [&](const SourceView& s) { return s.name == view.name; });
      if (!context.params.Bool("exclude_self") || !has_self) return &all;  // no copy (nor of depth maps)
      for (const SourceView& s : all) {
        if (s.name != view.name) own->push_back(s);
      }
      return static_cast<const std::vector<SourceView>*>(own);
    };
    // ULR over a plane (no `layers`) or meshes (the first hit of the first mesh that covers a pixel).
    const auto render_ulr = [&](const std::vector<SourceView>& all, const std::vector<const TriangleMesh*>& layers,
                                const Desired& view, std::string* plane_kind, size_t* used_sources) {
      std::vector<SourceView> own;
      const std::vector<SourceView>* used = sources_for(all, view, &own);
      *used_sources = used->size();
      const Camera camera = factor > 1 ? view.camera.Scaled(factor) : view.camera;
      ProxySurface surface;
      if (layers.empty()) {
        Plane plane;
        if (PlaneAtMeanInverseDepth(sparse_points, view.cam_from_world, &plane)) {
          *plane_kind = "mean_inverse_depth";
        } else {
          plane.normal = view.cam_from_world.Inverse().rotation * Eigen::Vector3d::UnitZ();
          plane.point = axes_point;
          *plane_kind = "nearest_to_axes";
        }
        surface = PlaneSurface(plane, camera, view.cam_from_world);
      } else {
        surface = MeshSurface(layers, camera, view.cam_from_world, options.proxy_extend_px * factor);
      }
      const UlrRenderer renderer(used, options);
      return Downsample(renderer.Render(camera, view.cam_from_world, surface), surface, factor);
    };
    const bool plane_possible = !sparse_points.empty() || have_axes_point;

    // The background that fills every other model's holes (`background: plane`), one per view: the
    // plane model's render, which that model then takes as it is (drawn twice, the same pixels: 10 s
    // of the full-size castle's 84).
    struct Background {
      RenderResult result;
      std::string plane_kind;
      size_t used_sources = 0;
      double seconds = 0;  // its render's wall time
    };
    std::map<std::string, Background> background;
    if (context.params.String("background") == "plane" && plane_possible) {
      // In memory only (no per-view checkpoint): a resumed run needs it for every view it renders.
      std::vector<Background> results(desired.size());
      context.progress->Begin("background (plane)", desired.size());
      tbb::parallel_for(size_t{0}, desired.size(), [&](size_t i) {
        const auto start = std::chrono::steady_clock::now();
        Background& b = results[i];
        b.result = render_ulr(sources, {}, desired[i], &b.plane_kind, &b.used_sources);
        b.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        context.progress->Advance(1, desired[i].stem);
      });
      context.progress->End();
      for (size_t i = 0; i < desired.size(); ++i) background[desired[i].stem] = std::move(results[i]);
    }

    nlohmann::json proxies_json = nlohmann::json::array();
    std::string primary;
    fs::create_directories(context.workspace.Path("renders"));
    for (const std::string& entry : context.params.StringList("proxies")) {
      // What the last proxy's model held goes back to the system before the next one loads (the
      // full-size castle: 1130 -> 577 MB held before the layers, after the splats' 20 M samples).
      ReleaseFreeHeap();
      const ProxySpec spec = ParseProxy(entry, context.workspace);
      const bool is_mesh = spec.kind == ModelKind::kMesh;
      nlohmann::json pj = {{"name", spec.name},
                           {"path", spec.kind == ModelKind::kPlane ? "plane"
                                    : spec.path.empty()            ? std::string("dense/stereo")
                                                                   : context.workspace.Relative(spec.path)}};
      const auto skip = [&](const std::string& reason) {
        spdlog::warn("[render] proxy {}: {}; skipped", spec.name, reason);
        pj["status"] = "skipped";
        pj["reason"] = reason;
        proxies_json.push_back(pj);
      };
      TriangleMesh mesh;
      if (is_mesh) {
        if (!fs::exists(spec.path)) {
          skip(spec.path + " does not exist");
          continue;
        }
        mesh = ReadMeshPly(spec.path);
        const std::string invalid = mesh.Validate();
        if (mesh.faces.empty() || !invalid.empty()) {
          skip(spec.path + " has no usable faces" + (invalid.empty() ? "" : " (" + invalid + ")"));
          continue;
        }
        if (spec.detail > 0) {
          const size_t before = mesh.faces.size();
          size_t refused = 0;
          mesh = DecimateMesh(mesh, static_cast<size_t>(spec.detail), &refused);
          spdlog::info("[render] proxy {}: {} faces decimated to {}{}", spec.name, before, mesh.faces.size(),
                       refused ? " (" + std::to_string(refused) + " non-manifold faces dropped)" : std::string());
          if (mesh.faces.size() > static_cast<size_t>(spec.detail)) {
            spdlog::warn("[render] proxy {}: {} faces, over the budget of {}: OpenMesh refused the remaining "
                         "collapses (they would flip a face or break the manifold); its size in renders.json is "
                         "the faces kept",
                         spec.name, mesh.faces.size(), spec.detail);
          }
        }
      }
      // Texture models: the texture stage's mesh and atlas, and for vdtm its view maps.
      const bool is_texture = spec.kind == ModelKind::kTextured || spec.kind == ModelKind::kVdtm;
      TexturedMesh textured;
      ViewMaps view_maps;
      std::unique_ptr<VdtmRenderer> vdtm;
      std::vector<SourceView> vdtm_sources;  // the sources with the textured mesh's depth (per-pixel visibility)
      if (is_texture) {
        const auto prepare_start = std::chrono::steady_clock::now();
        if (!fs::exists(spec.path)) {
          skip(spec.path + " does not exist (run the texture stage)");
          continue;
        }
        if (!spec.view_maps.empty() && !fs::exists(spec.view_maps)) {
          skip(spec.view_maps + " does not exist (run the texture stage)");
          continue;
        }
        try {
          textured = ReadTexturedObj(spec.path);
          const std::string invalid = textured.Validate();
          if (textured.mesh.faces.empty() || !invalid.empty()) {
            skip(spec.path + " has no usable faces" + (invalid.empty() ? "" : " (" + invalid + ")"));
            continue;
          }
          if (spec.kind == ModelKind::kVdtm) {
            view_maps = ReadViewMaps(spec.view_maps);
            vdtm_sources = sources;  // shares pixels
            tbb::parallel_for(size_t{0}, vdtm_sources.size(), [&](size_t i) {
              vdtm_sources[i].proxy_depth = MeshDepth(textured.mesh, vdtm_sources[i].camera, vdtm_sources[i].cam_from_world);
            });
            vdtm = std::make_unique<VdtmRenderer>(&textured, &view_maps, &vdtm_sources, options.visibility_epsilon);
          }
        } catch (const InputError& e) {  // unreadable or inconsistent files: like a missing mesh, not fatal
          skip(e.what());
          continue;
        } catch (const IoError& e) {
          skip(e.what());
          continue;
        }
        if (vdtm) {
          pj["view_maps"] = context.workspace.Relative(spec.view_maps);
          pj["view_map_views"] = view_maps.view_names.size();
          pj["view_map_views_with_source"] = vdtm->MatchedViews();
          if (vdtm->MatchedViews() < static_cast<int>(view_maps.view_names.size())) {
            spdlog::warn("[render] proxy {}: {} of the {} views of {} are not training views here; never sampled",
                         spec.name, view_maps.view_names.size() - vdtm->MatchedViews(), view_maps.view_names.size(),
                         spec.view_maps);
          }
        }
        context.metrics["prepare_seconds_" + spec.name] =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - prepare_start).count();
      }
      std::vector<TriangleMesh> fallbacks;
      for (const std::string& path : spec.fallbacks) {
        TriangleMesh fallback = fs::exists(path) ? ReadMeshPly(path) : TriangleMesh();
        if (fallback.faces.empty() || !fallback.Validate().empty()) {
          spdlog::warn("[render] proxy {}: fallback {} is missing or has no usable faces; ignored", spec.name, path);
          continue;
        }
        fallbacks.push_back(std::move(fallback));
      }
      std::vector<const TriangleMesh*> layers;
      if (is_mesh) layers.push_back(&mesh);
      for (const TriangleMesh& fallback : fallbacks) layers.push_back(&fallback);
      if (!fallbacks.empty()) {
        pj["fallbacks"] = nlohmann::json::array();
        for (const std::string& path : spec.fallbacks) pj["fallbacks"].push_back(context.workspace.Relative(path));
      }
      if (spec.kind == ModelKind::kPlane && !plane_possible) {
        throw InputError("render: plane proxy: no sparse points and the training optical axes are parallel; "
                         "list a mesh proxy instead");
      }
      // Layers: every training view's layers/<image>/ that exists, each read whole here (so that a
      // broken set skips the model before any view is drawn) and kept as its header only: a view
      // reads the sets it is drawn from again.
      std::unique_ptr<LayersRenderer> layered;
      if (spec.kind == ModelKind::kLayers) {
        std::vector<LayerSet> sets;
        std::vector<std::string> folders;
        try {
          for (const std::string& name : training) {
            const std::string folder = spec.path + "/" + name;
            if (!fs::exists(folder + "/layers.json")) continue;
            sets.push_back(ReadLayerSet(folder));
            for (SpriteLayer& layer : sets.back().layers) layer.rgba.release(), layer.residual.release();
            folders.push_back(folder);
          }
        } catch (const InputError& e) {
          skip(e.what());
          continue;
        } catch (const IoError& e) {
          skip(e.what());
          continue;
        }
        if (sets.empty()) {
          skip(spec.path + " holds no training view's layers (run the layered_stereo stage)");
          continue;
        }
        Eigen::Vector3d centre = axes_point;
        if (!sparse_points.empty()) {
          centre.setZero();
          for (const Eigen::Vector3d& p : sparse_points) centre += p;
          centre /= static_cast<double>(sparse_points.size());
        }
        layered = std::make_unique<LayersRenderer>(std::move(sets), std::move(folders),
                                                   static_cast<int>(context.params.Int("layers_references")), centre);
        pj["reference_views"] = layered->Sets();
      }
      const auto start = std::chrono::steady_clock::now();
      // Splat models: the samples once, then any number of views.
      SplatCloud cloud;
      if (spec.kind == ModelKind::kSplatSurfels) {
        if (!fs::exists(spec.path)) {
          skip(spec.path + " does not exist (run the surfels stage)");
          continue;
        }
        cloud = CloudFromSurfels(ReadPointCloudPly(spec.path), 0.f);
        if (cloud.size() == 0) {
          skip(spec.path + " holds no finite surfel");
          continue;
        }
        pj["samples"] = cloud.size();
      } else if (spec.kind == ModelKind::kSplatDepth || spec.kind == ModelKind::kSplatDepthMerged) {
        SplatModelStats stats;
        try {
          stats = BuildDepthSplats(context, model, training,
                                   spec.depth_type.empty() ? context.params.String("splat_depth_type") : spec.depth_type,
                                   spec.kind == ModelKind::kSplatDepthMerged, std::max(1, spec.detail), &cloud);
        } catch (const InputError& e) {  // no depth maps (yet): like a missing mesh, not fatal
          skip(e.what());
          continue;
        }
        pj["samples_before_merge"] = stats.drawable;
        pj["samples"] = cloud.size();
        pj["skin_connections"] = stats.skins;
        pj["outliers"] = stats.outliers;
        pj["merged_away"] = stats.merged;
        context.metrics["prepare_seconds_" + spec.name] = stats.seconds;
        context.metrics["samples_" + spec.name] = cloud.size();
      }
      pj["model"] = is_texture ? TexturedModelSize(spec, textured)
                    : layered  ? LayersModelSize(spec, *layered)
                               : ModelSize(spec, layers, cloud);
      // A model drawn from ground truth is a reference, not a reconstruction: select skips it.
      const bool splat_depth = spec.kind == ModelKind::kSplatDepth || spec.kind == ModelKind::kSplatDepthMerged;
      const std::string depth_type = spec.depth_type.empty() ? context.params.String("splat_depth_type") : spec.depth_type;
      const bool from_truth = (splat_depth && depth_type == "truth") ||
                              context.workspace.Relative(spec.path).rfind("ground_truth/", 0) == 0;
      if (from_truth) pj["model"]["from_truth"] = true;
      const bool is_primary = primary.empty();
      if (is_primary) primary = spec.name;
      std::vector<SourceView> proxy_sources = sources;  // shares pixels; depth maps per proxy
      if (is_mesh) {
        tbb::parallel_for(size_t{0}, proxy_sources.size(), [&](size_t i) {
          proxy_sources[i].proxy_depth =
              MeshDepth(layers, proxy_sources[i].camera, proxy_sources[i].cam_from_world, options.proxy_extend_px);
        });
      }
      const SplatOptions splat_options = ToSplatOptions(context.params);
      // Leave-one-out (exclude_self) for a training view among the desired ones: ULR, vdtm, layers
      // and splat_depth leave its own photo (and depth, layers) out below. A texture atlas or surfels
      // are one model made from every photo: such a view is not held out there.
      const bool exclude_self = context.params.Bool("exclude_self");
      if (exclude_self && (spec.kind == ModelKind::kTextured || spec.kind == ModelKind::kSplatSurfels)) {
        std::string in_model;
        for (const Desired& view : desired) {
          if (std::find(training.begin(), training.end(), view.name) != training.end()) {
            in_model += (in_model.empty() ? "" : ", ") + view.name;
          }
        }
        if (!in_model.empty()) {
          spdlog::warn("[render] proxy {}: the training views {} are not held out: the model was made from their "
                       "photos too, so their scores are optimistic (exclude_self cannot apply); score held-out views",
                       spec.name, in_model);
        }
      }
      const std::string folder = context.workspace.Path("renders/" + spec.name);
      fs::create_directories(folder);
      std::mutex mutex;
      nlohmann::json views_json = nlohmann::json::object();
      std::vector<std::string> keys;
      for (const Desired& view : desired) keys.push_back(spec.name + "__" + view.stem);
      double splat_seconds = 0, splat_megapixels = 0;
      double frame_seconds = 0;  // every model: the views' render times (not the file writes)
      size_t frames = 0;
      const PerViewSummary rendered = ForEachView(context, "render " + spec.name, keys, [&](const std::string& key) -> nlohmann::json {
        const Desired& view = desired[std::find(keys.begin(), keys.end(), key) - keys.begin()];
        std::string plane_kind;
        size_t used_sources = 0;
        RenderResult result;
        double atlas_fraction = -1;  // vdtm: covered sub-samples coloured by the atlas
        auto frame_start = std::chrono::steady_clock::now();
        const auto drawn = background.find(view.stem);
        if (spec.kind == ModelKind::kPlane && layers.empty() && drawn != background.end()) {
          result = drawn->second.result;
          plane_kind = drawn->second.plane_kind;
          used_sources = drawn->second.used_sources;
          frame_start -= std::chrono::duration_cast<std::chrono::steady_clock::duration>(
              std::chrono::duration<double>(drawn->second.seconds));  // its time counts as this model's
        } else if (spec.kind == ModelKind::kPlane || is_mesh) {
          result = render_ulr(proxy_sources, layers, view, &plane_kind, &used_sources);
        } else if (layered) {
          const Camera camera = factor > 1 ? view.camera.Scaled(factor) : view.camera;
          // Leave-one-out: a training view's own layers reproduce its photo (angle 0).
          const bool self = exclude_self && layered->HasSet(view.name);
          const RenderResult fine = layered->Render(camera, view.cam_from_world, self ? view.name : std::string());
          result = Downsample(fine, HitsOf(fine), factor);
          used_sources = std::min<size_t>(layered->Sets() - (self ? 1 : 0),
                                          static_cast<size_t>(context.params.Int("layers_references")));
        } else if (is_texture) {
          const Camera camera = factor > 1 ? view.camera.Scaled(factor) : view.camera;
          RenderResult fine;
          if (vdtm) {
            // Leave-one-out: the view's own photo is never a source (exclude_self).
            int self = -1;
            if (context.params.Bool("exclude_self")) {
              for (size_t i = 0; i < sources.size(); ++i) {
                if (sources[i].name == view.name) self = static_cast<int>(i);
              }
            }
            VdtmStats stats;
            fine = vdtm->Render(camera, view.cam_from_world, self, &stats);
            if (fine.covered_pixels > 0) atlas_fraction = static_cast<double>(stats.atlas_pixels) / fine.covered_pixels;
            const bool self_mapped = self >= 0 && std::find(view_maps.view_names.begin(), view_maps.view_names.end(),
                                                            view.name) != view_maps.view_names.end();
            used_sources = static_cast<size_t>(vdtm->MatchedViews() - (self_mapped ? 1 : 0));
          } else {
            fine = RenderTextured(textured, camera, view.cam_from_world);
          }
          result = Downsample(fine, HitsOf(fine), factor);
        } else {
          const auto splat_start = std::chrono::steady_clock::now();
          const Camera camera = factor > 1 ? view.camera.Scaled(factor) : view.camera;
          // Leave-one-out: the depth samples of a training view's own depth map (and photo) are not
          // drawn; the cloud's sources are the training views in order (LoadDepthImages).
          int self = -1;
          if (exclude_self && spec.kind != ModelKind::kSplatSurfels) {
            const auto found = std::find(training.begin(), training.end(), view.name);
            if (found != training.end()) self = static_cast<int>(found - training.begin());
          }
          const SplatImage splats = RenderSplats(cloud, camera, view.cam_from_world, splat_options, self);
          RenderResult fine;
          fine.image = splats.image;
          fine.coverage = splats.coverage;
          fine.covered_pixels = splats.covered_pixels;
          result = Downsample(fine, HitsOf(fine), factor);
          used_sources = spec.kind == ModelKind::kSplatSurfels ? 0 : training.size() - (self >= 0 ? 1 : 0);
          const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - splat_start).count();
          std::lock_guard<std::mutex> lock(mutex);
          splat_seconds += seconds;
          splat_megapixels += 1e-6 * view.camera.width * view.camera.height;
        }
        // What the drawing freed back to the system: placed in the heap's free space, it would stay
        // resident beside the next view's (the full-size castle's splat_depth after four other
        // models: 1294 MB held before the first view, 1932 MB after it).
        ReleaseFreeHeap();
        {
          const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - frame_start).count();
          std::lock_guard<std::mutex> lock(mutex);
          frame_seconds += seconds;
          ++frames;
        }
        WriteImage(folder + "/" + view.stem + ".png", result.image);
        WriteImage(folder + "/" + view.stem + ".coverage.png", result.coverage);
        if (is_primary) {
          WriteImage(context.workspace.Path("renders/" + view.stem + ".png"), result.image);
          WriteImage(context.workspace.Path("renders/" + view.stem + ".coverage.png"), result.coverage);
        }
        nlohmann::json vj = {{"image", view.name},
                             {"render", "renders/" + spec.name + "/" + view.stem + ".png"},
                             {"coverage", static_cast<double>(result.covered_pixels) /
                                              (static_cast<double>(view.camera.width) * view.camera.height)},
                             {"sources", used_sources}};
        if (!plane_kind.empty()) vj["plane"] = plane_kind;
        if (atlas_fraction >= 0) vj["atlas_fraction"] = atlas_fraction;
        const auto fill = background.find(view.stem);
        if (spec.kind != ModelKind::kPlane && fill != background.end()) {
          const RenderResult filled = FillHoles(result, fill->second.result);
          WriteImage(folder + "/" + view.stem + ".filled.png", filled.image);
          WriteImage(folder + "/" + view.stem + ".filled.coverage.png", filled.coverage);
          vj["filled"] = "renders/" + spec.name + "/" + view.stem + ".filled.png";
        } else {
          // No fill this time (background: none, or the plane proxy): a filled image of an earlier
          // run would be stale beside the new render.
          std::error_code ec;
          fs::remove(folder + "/" + view.stem + ".filled.png", ec);
          fs::remove(folder + "/" + view.stem + ".filled.coverage.png", ec);
        }
        // The view's facts beside its images: a resumed run skips views already rendered and
        // gathers every view's facts from these files.
        WriteFileAtomic(folder + "/" + view.stem + ".json", vj.dump(2) + "\n");
        return {};
      });
      shard_done.computed += rendered.computed;
      shard_done.resumed += rendered.resumed;
      for (const Desired& view : desired) {
        const std::string facts = folder + "/" + view.stem + ".json";
        if (fs::exists(facts)) views_json[view.name] = nlohmann::json::parse(ReadFile(facts));
      }
      const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      pj["status"] = "rendered";
      pj["primary"] = is_primary;
      pj["views"] = views_json;
      if (cloud.size() > 0 && splat_megapixels > 0) {
        // Speed of the splatting alone: milliseconds per output megapixel per million samples.
        context.metrics["ms_per_megapixel_per_million_splats_" + spec.name] =
            1e3 * splat_seconds / splat_megapixels / (1e-6 * cloud.size());
      }
      if (frames > 0) {
        // Mean wall time of one view's render in this run (views run concurrently: compare models of
        // one run, e.g. vdtm with ULR over the same mesh). In the record only: renders.json, an
        // output, is the same for the same work, whatever the machine did.
        context.metrics["ms_per_frame_" + spec.name] = 1e3 * frame_seconds / frames;
      }
      proxies_json.push_back(pj);
      context.metrics["seconds_" + spec.name] = seconds;
      spdlog::info("[render] proxy {}: {} views in {:.2f} s", spec.name, desired.size(), seconds);
    }
    // Each view rendered by every model: the mark a shard's success is read from (UnfinishedViews).
    for (const Desired& view : desired) context.checkpoint.MarkDone(view.name);
    if (!shard.empty()) throw shard_done;
    if (primary.empty() && !desired.empty()) {
      throw InputError("render.proxies: none of the listed proxies exists (see the warnings above); list plane or "
                       "an existing mesh");
    }
    nlohmann::json summary = {{"primary", primary},
                              {"proxies", proxies_json},
                              {"training_views", training},
                              {"options", context.params.ToJson()}};
    WriteFileAtomic(context.workspace.Path("renders/renders.json"), summary.dump(2) + "\n");
    context.metrics["views"] = desired.size();
    context.metrics["sources"] = training.size();
    context.metrics["primary_proxy"] = primary;
  }

 private:
  struct SplatModelStats {
    size_t drawable = 0, skins = 0, outliers = 0, merged = 0;
    double seconds = 0;
  };

  // The splat_depth model: the training views' depth images, flagged, skins found, merged [N 4.3-4.6].
  static SplatModelStats BuildDepthSplats(StageContext& context, const SparseModel& model,
                                          const std::vector<std::string>& training, const std::string& depth_type,
                                          bool merge, int block, SplatCloud* cloud) {
    const auto start = std::chrono::steady_clock::now();
    DepthImageOptions options = ToDepthImageOptions(context.params);
    options.merge = merge;
    std::vector<DepthImage> images =
        LoadDepthImages(context.workspace, model, training, depth_type);
    if (block > 1) {
      for (DepthImage& image : images) image = DownsampleDepthImage(image, block);
    }
    SplatModelStats stats;
    for (DepthImage& image : images) {
      FlagSamples(&image, options.min_confidence);
      for (const uint8_t flag : image.flags) stats.drawable += IsDrawable(flag);
    }
    stats.skins = DetectSkins(&images, options, &stats.outliers);
    stats.merged = MergeTiles(&images, options);
    const size_t views = images.size();
    *cloud = CloudFromDepthImages(std::move(images));
    // The depth images' memory back to the system: when the models before this one left the heap
    // with free space, the images were placed there, and free() keeps such memory resident (the
    // full-size castle after vdtm: 1757 -> 1042 MB held while the views are drawn).
    ReleaseFreeHeap();
    stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    spdlog::info("[render] splat_depth{} ({}): {} views, {} samples, {} skin connections, {} outliers, {} merged "
                 "away -> {} splats ({:.1f} s)",
                 merge ? "_merged" : "", depth_type, views, stats.drawable, stats.skins, stats.outliers, stats.merged,
                 cloud->size(), stats.seconds);
    return stats;
  }

  // How much model a proxy is, for selection by held-out error against size: its kind, its
  // elements (triangles or samples) and bytes (meshes as binary PLY, surfels as their file, depth
  // samples as an RGBD image stores them, 3 colour and 4 depth bytes each; a plane is 4 numbers).
  static nlohmann::json ModelSize(const ProxySpec& spec, const std::vector<const TriangleMesh*>& layers,
                                  const SplatCloud& cloud) {
    const auto file_bytes = [](const std::string& path) {
      std::error_code ec;
      const auto size = fs::file_size(path, ec);
      return ec ? uintmax_t{0} : size;
    };
    switch (spec.kind) {
      case ModelKind::kPlane:
        return {{"kind", "plane"}, {"elements", 1}, {"bytes", 4 * sizeof(double)}};
      case ModelKind::kMesh: {
        // As a binary PLY stores the meshes drawn (decimated ones are not written): positions,
        // normals and colours per vertex, a count and three indices per face.
        size_t triangles = 0, bytes = 0;
        for (const TriangleMesh* layer : layers) {
          triangles += layer->faces.size();
          const size_t per_vertex = 12 + (layer->normals.empty() ? 0 : 12) + (layer->colors.empty() ? 0 : 3);
          bytes += layer->vertices.size() * per_vertex + layer->faces.size() * 13;
        }
        return {{"kind", "mesh"}, {"elements", triangles}, {"triangles", triangles}, {"bytes", bytes}};
      }
      case ModelKind::kSplatSurfels:
        return {{"kind", "surfels"}, {"elements", cloud.size()}, {"bytes", file_bytes(spec.path)}};
      default:
        return {{"kind", "depth_samples"}, {"elements", cloud.size()}, {"bytes", cloud.size() * 7}};
    }
  }

  // The layers' size: the layer count and the bytes of their files (sprites, residual depth).
  static nlohmann::json LayersModelSize(const ProxySpec& spec, const LayersRenderer& layered) {
    uintmax_t bytes = 0;
    std::error_code ec;
    for (const auto& entry : fs::recursive_directory_iterator(spec.path, ec)) {
      const std::string name = entry.path().filename().string();
      if (entry.is_regular_file() && name.rfind("layer_", 0) == 0) bytes += entry.file_size();
    }
    return {{"kind", "layers"}, {"elements", layered.Layers()}, {"reference_views", layered.Sets()}, {"bytes", bytes}};
  }

  // A texture model's size: its triangles, and the bytes of mesh.obj, mesh.mtl, the atlas pages
  // and, for vdtm, the view maps (as the files store them).
  static nlohmann::json TexturedModelSize(const ProxySpec& spec, const TexturedMesh& textured) {
    const fs::path folder = fs::path(spec.path).parent_path();
    std::vector<fs::path> files = {spec.path, fs::path(spec.path).replace_extension(".mtl")};
    for (size_t page = 0; page < textured.pages.size(); ++page) files.push_back(folder / ("atlas_" + std::to_string(page) + ".png"));
    if (!spec.view_maps.empty()) files.push_back(spec.view_maps);
    uintmax_t bytes = 0;
    for (const fs::path& file : files) {
      std::error_code ec;
      const uintmax_t size = fs::file_size(file, ec);
      if (!ec) bytes += size;
    }
    const size_t triangles = textured.mesh.faces.size();
    return {{"kind", spec.kind == ModelKind::kVdtm ? "vdtm" : "textured_mesh"},
            {"elements", triangles},
            {"triangles", triangles},
            {"pages", textured.pages.size()},
            {"bytes", bytes}};
  }

  static SplatOptions ToSplatOptions(const Params& params) {
    SplatOptions options;
    options.radius_scale = params.Double("splat_radius_scale");
    options.max_radius_px = params.Double("splat_max_radius_px");
    options.max_stretch = params.Double("splat_max_stretch");
    options.depth_tolerance = params.Double("splat_depth_tolerance");
    options.angle_epsilon_deg = params.Double("splat_angle_epsilon_deg");
    options.k = static_cast<int>(params.Int("splat_k"));
    return options;
  }

  static DepthImageOptions ToDepthImageOptions(const Params& params) {
    DepthImageOptions options;
    options.min_confidence = params.Double("splat_min_confidence");
    options.skin_tolerance = params.Double("skin_tolerance");
    options.skin_views = static_cast<int>(params.Int("skin_views"));
    options.free_space_views = static_cast<int>(params.Int("free_space_views"));
    options.color_tolerance = static_cast<int>(params.Int("color_tolerance"));
    options.merge_tolerance = params.Double("merge_tolerance");
    options.merge_views = static_cast<int>(params.Int("merge_views"));
    return options;
  }

  static RenderOptions ToOptions(const Params& params) {
    RenderOptions options;
    options.k = static_cast<int>(params.Int("k"));
    options.alpha = params.Double("alpha");
    options.beta = params.Double("beta");
    options.gamma = params.Double("gamma");
    options.epipole_consistent = params.Bool("epipole_consistent");
    options.fov_margin = params.Double("fov_margin");
    options.max_penalty = params.Double("max_penalty");
    options.visibility_epsilon = params.Double("visibility_epsilon");
    options.proxy_extend_px = static_cast<int>(params.Int("proxy_extend_px"));
    return options;
  }
};

}  // namespace

void RegisterStage_render(StageRegistry* registry) { registry->Add(std::make_unique<RenderStage>()); }

}  // namespace ibmr
