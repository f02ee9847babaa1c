// Adapter of the surfels stage (seed 000 section 5, lines 4454-4586; see surfels.h): reads
// dense/fused.ply, the training cameras, their depth maps (free space), hull/hull.ply when present
// and masks/ when silhouette_views > 0, and writes
//   surfels/surfels.ply  binary PLY, one vertex per surfel: float x y z nx ny nz radius, uchar red
//                        green blue, float confidence (radius in scene units: the disc a splatting
//                        renderer draws; confidence in [0, 1], 0 for particles grown into gaps
//                        between low-confidence parents)
//   surfels/mesh.ply     binary PLY triangle mesh on the surfels: vertex normals and colours, faces
//                        counter-clockwise seen from outside
// With ground_truth/mesh.ply (synthetic scenes) the record gets the mesh's accuracy (distance to the
// true mesh at 90%, of points sampled on it) and completeness (true surface within 1% of the
// bounding-box diagonal), the Middlebury measures fuse reports for its points.
#include <spdlog/spdlog.h>

#include <filesystem>
#include <iostream>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/surface_accuracy.h"
#include "stages/surfels/surfels.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

constexpr char kFused[] = "dense/fused.ply";
constexpr char kHull[] = "hull/hull.ply";

class SurfelsStage : public Stage {
 public:
  std::string Name() const override { return "surfels"; }
  std::string Summary() const override {
    return "Oriented particles from the fused points, relaxed and grown, and their mesh (surfels/surfels.ply, surfels/mesh.ply)";
  }
  // 2: mesh faces in a canonical order; 3: surfel radii 0.75 spacing; 4: the advancing front breaks
  // ties by creation order and vertex indices, not addresses (the same mesh from run to run)
  // 6: the data term's confidences relative to the fused points' median (particle_relaxation.cc)
  std::string Version() const override { return "6"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }

  std::vector<ParamSpec> Parameters() const override {
    const SurfelOptions d;
    const ParticleWeights& w = d.weights;
    const auto num = DefaultNumberText;
    return {
        {"spacing_scale", ParamType::kDouble, num(d.spacing_scale), "Particle spacing / median pixel footprint of the points, (0, 100]"},
        {"spacing", ParamType::kDouble, "-1", "Fixed particle spacing in scene units; -1: from the footprints"},
        {"iterations", ParamType::kInt, std::to_string(d.iterations), "Relaxation sweeps per round, [0, 1000]"},
        {"grow_rounds", ParamType::kInt, std::to_string(d.grow_rounds), "Rounds of growth (stretching rule) and relaxation, [0, 20]"},
        {"coplanarity", ParamType::kDouble, num(w.coplanarity), "Weight of the co-planarity potential, >= 0"},
        {"conormality", ParamType::kDouble, num(w.conormality), "Weight of the co-normality potential, >= 0"},
        {"cocircularity", ParamType::kDouble, num(w.cocircularity), "Weight of the co-circularity potential, >= 0"},
        {"repulsion", ParamType::kDouble, num(w.repulsion), "Weight of the short-range repulsion, >= 0"},
        {"data_weight", ParamType::kDouble, num(w.data), "Weight of the data term (pull toward the fused points), >= 0"},
        {"sigma", ParamType::kDouble, num(w.sigma), "Interaction radius of the potentials, spacings, (0, 10]"},
        {"repulsion_radius", ParamType::kDouble, num(w.repulsion_radius), "Repulsion acts closer than this, spacings, (0, 5]"},
        {"data_sigma", ParamType::kDouble, num(w.data_sigma), "Radius of the data term, spacings, (0, 10]"},
        {"tangential", ParamType::kDouble, num(w.tangential), "Share of the tangential data pull, [0, 1]"},
        {"stretch_distance", ParamType::kDouble, num(d.stretch_distance), "Neighbours farther apart get a midpoint particle, spacings, [1, max_gap)"},
        {"max_gap", ParamType::kDouble, num(d.max_gap), "Gaps wider than this stay open, spacings, (1, 20]"},
        {"max_normal_angle_deg", ParamType::kDouble, num(d.max_normal_angle_deg), "Growth only between normals within this, degrees, (0, 180]"},
        {"min_support", ParamType::kInt, std::to_string(d.min_support), "Fused points within support_radius to keep a particle, [0, 1000]"},
        {"support_radius", ParamType::kDouble, num(d.support_radius), "Spacings, (0, 20]"},
        {"min_support_fraction", ParamType::kDouble, num(d.min_support_fraction), "Fused points near a particle / the median particle's, to keep it, [0, 1]"},
        {"min_neighbours", ParamType::kInt, std::to_string(d.min_neighbours), "Particles within 2.5 spacings to keep a particle, [0, 100]"},
        {"free_space_views", ParamType::kInt, std::to_string(d.free_space_views), "Delete particles that this many depth maps see through, [1, 1000]"},
        {"free_space_margin", ParamType::kDouble, num(d.free_space_margin), "See-through margin, spacings (and 0.5% of depth), (0, 1000]"},
        {"silhouette_views", ParamType::kInt, std::to_string(d.silhouette_views), "Delete particles on this many views' background (masks/); 0: off, [0, 1000]"},
        {"silhouette_color_tolerance", ParamType::kInt, std::to_string(d.silhouette_color_tolerance),
         "With silhouette_views: a background landing counts only where the photo differs from the particle's colour "
         "by more than this (grey levels, largest channel); keeps a dark backdrop the masks leave out; 0: every landing counts, [0, 255]"},
        {"free_space_maps", ParamType::kString, "geometric", "Depth maps for the free-space test", {"geometric", "photometric", "none"}},
        {"max_edge", ParamType::kDouble, num(d.max_edge), "Longest triangle edge, spacings, [1, 20]"},
        {"max_hole_edges", ParamType::kInt, std::to_string(d.max_hole_edges), "Close mesh holes bounded by at most this many edges, [0, 1000]"},
        {"min_component_faces", ParamType::kInt, std::to_string(d.min_component_faces), "Drop mesh pieces with fewer faces, [0, 1e6]"},
        {"border_extension", ParamType::kDouble, num(d.border_extension), "Open mesh borders move out by this, spacings (the border discs' outer half), [0, 2]"},
        {"max_particles", ParamType::kInt, std::to_string(d.max_particles), "Refuse to run beyond this many particles, [1000, 5e7]"},
        {"use_hull", ParamType::kBool, "true", "Keep the surface inside hull/hull.ply when it exists"},
        {"eval_samples", ParamType::kInt, "200000", "Samples for accuracy/completeness against ground_truth/mesh.ply, [1000, 1e7]"},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    const int64_t samples = params.Int("eval_samples");
    if (samples < 1000 || samples > 10000000) return ParamError{"eval_samples", "must be in [1000, 10000000], got " + std::to_string(samples)};
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    std::vector<std::string> inputs = {context.workspace.SparseRelative(), kFused};
    const std::string kind = context.params.String("free_space_maps");
    if (kind != "none") {
      const std::vector<std::string> names = context.TrainingImageNamesIfReadable();
      if (names.empty()) inputs.push_back("dense/stereo/depth_maps");
      for (const std::string& name : names) inputs.push_back("dense/stereo/depth_maps/" + name + "." + kind + ".bin");
    }
    if (context.params.Bool("use_hull")) inputs.push_back(kHull);  // optional
    if (context.params.Int("silhouette_views") > 0) {
      inputs.push_back("masks");
      if (context.params.Int("silhouette_color_tolerance") > 0) {
        inputs.push_back(context.workspace.ImagesRelative());  // the colour check's photos (dense/images once undistorted)
      }
    }
    inputs.push_back("ground_truth/mesh.ply");                      // metrics only
    return inputs;
  }

  std::vector<std::string> Outputs(const StageContext&) const override { return {"surfels"}; }

  void Run(StageContext& context) const override {
    const SurfelOptions options = ToOptions(context.params);
    const Workspace& workspace = context.workspace;
    const std::string fused_path = workspace.Path(kFused);
    if (!fs::exists(fused_path)) throw InputError(fused_path + ": no fused points; run fuse first");
    const PointCloud points = ReadPointCloudPly(fused_path);
    if (points.size() == 0) throw InputError(fused_path + ": holds no point; check the fuse record (records/fuse.json)");
    if (points.normals.empty()) spdlog::warn("[surfels] {}: the points have no normals; estimating them from neighbours", fused_path);

    const SparseModel model = context.LoadModel();
    const std::vector<std::string> names = context.TrainingImageNames(model);
    const std::string kind = context.params.String("free_space_maps");
    std::vector<SurfelView> views;
    context.progress->Begin("surfels: reading views", names.size());
    for (const std::string& name : names) {
      const Image& image = *model.FindImage(name);
      SurfelView view;
      view.camera = model.CameraOf(image);
      view.cam_from_world = image.cam_from_world;
      if (kind != "none") {
        const std::string path = workspace.DepthMapPath(name, kind);
        if (fs::exists(path)) {
          view.depth = ReadColmapArray(path);
        } else {
          spdlog::warn("[surfels] {}: missing; view '{}' takes no part in the free-space test", path, name);
        }
      }
      if (options.silhouette_views > 0) {
        const std::string mask_path = workspace.MaskPath(name);
        if (fs::exists(mask_path)) {
          view.mask = ReadImageUnchanged(mask_path);
          if (view.mask.type() != CV_8UC1) {
            throw InputError(mask_path + ": not an 8-bit one-channel mask; re-run silhouettes (or set surfels.silhouette_views: 0)");
          }
          if (options.silhouette_color_tolerance > 0) {
            view.image = ReadImageColor(workspace.ImagesDir() + "/" + name);  // throws naming the file
          }
        }
      }
      views.push_back(std::move(view));
      context.progress->Advance(1, name);
    }
    context.progress->End();

    TriangleMesh hull;
    const bool use_hull = context.params.Bool("use_hull") && fs::exists(workspace.Path(kHull));
    if (use_hull) hull = ReadMeshPly(workspace.Path(kHull));

    SurfelResult result = ReconstructSurfels(points, views, use_hull ? &hull : nullptr, options, context.progress);
    const SurfelStats& s = result.stats;
    if (s.dropped_nonfinite) {
      spdlog::warn("[surfels] {}: {} of {} points have NaN or infinite coordinates or normals; ignored", fused_path,
                   s.dropped_nonfinite, s.input_points);
    }
    // A mesh without faces is no surface: the texture and render stages would fail on it later.
    if (result.mesh.faces.empty()) {
      throw InputError(fused_path + ": the " + std::to_string(s.particles) + " surfel particles made no mesh face (too few, " +
                       "or all on a line; or surfels.max_edge and min_component_faces removed every piece): check the " +
                       "fused points (fuse's record), or raise surfels.max_edge / lower min_component_faces");
    }
    fs::create_directories(workspace.Path("surfels"));
    result.surfels.comments = {"ibmr surfels " + Version() + ": oriented particles from " + std::string(kFused),
                               "spacing " + std::to_string(s.spacing)};
    WritePointCloudPly(workspace.Path("surfels/surfels.ply"), result.surfels);
    result.mesh.comments = {"ibmr surfels_mesh " + Version()};
    WriteMeshPly(workspace.Path("surfels/mesh.ply"), result.mesh);

    nlohmann::json& m = context.metrics;
    m["input_points"] = s.input_points;
    m["dropped_nonfinite"] = s.dropped_nonfinite;
    m["estimated_normals"] = s.estimated_normals;
    m["median_footprint"] = s.median_footprint;
    m["spacing"] = s.spacing;
    m["initial_particles"] = s.initial_particles;
    m["removed_free_space"] = s.removed_free_space;
    m["removed_outside_hull"] = s.removed_outside_hull;
    m["removed_off_silhouette"] = s.removed_off_silhouette;
    m["removed_unsupported"] = s.removed_unsupported;
    m["grown"] = s.grown;
    m["particles"] = s.particles;
    m["mesh_vertices"] = s.vertices;
    m["mesh_faces"] = s.faces;
    m["holes_filled"] = s.holes_filled;
    m["small_component_faces"] = s.small_component_faces;
    m["border_edges_extended"] = s.border_edges_extended;
    m["mean_step_last_sweep"] = s.mean_step_last_sweep;
    m["spacing_spread"] = s.spacing_spread;
    m["used_hull"] = use_hull && s.hull_closed;
    if (use_hull && !s.hull_closed) {
      spdlog::warn("[surfels] {}: not a closed mesh, so inside and outside are undefined; the surface is not bounded "
                   "by it (re-run carve, or set surfels.use_hull: false)",
                   workspace.Path(kHull));
    }
    m["prune_seconds"] = s.prune_seconds;
    m["relax_seconds"] = s.relax_seconds;
    m["triangulate_seconds"] = s.triangulate_seconds;
    spdlog::info("[surfels] {} points -> {} particles (spacing {:.4g}; {} free space, {} outside hull, {} unsupported "
                 "removed; {} grown) -> mesh of {} faces; {:.1f} s pruning, {:.1f} s relaxing, {:.1f} s triangulating",
                 s.input_points, s.particles, s.spacing, s.removed_free_space, s.removed_outside_hull,
                 s.removed_unsupported, s.grown, s.faces, s.prune_seconds, s.relax_seconds, s.triangulate_seconds);
    if (fs::exists(workspace.GroundTruthMeshPath())) Evaluate(context, result.mesh, result.surfels);
  }

 private:
  static void Evaluate(StageContext& context, const TriangleMesh& mesh, const PointCloud& particles) {
    const TriangleMesh truth = ReadMeshPly(context.workspace.GroundTruthMeshPath());
    const PointSetAccuracy a = EvaluateMesh(mesh, truth, static_cast<size_t>(context.params.Int("eval_samples")));
    if (a.points == 0) return;
    context.metrics["mesh_accuracy_90"] = a.accuracy_90;
    context.metrics["mesh_completeness"] = a.completeness;
    context.metrics["eval_threshold"] = a.threshold;
    // The particles themselves: their distance to the truth against their confidence.
    const PointSetAccuracy p = EvaluatePointSet(particles, truth, {}, a.threshold);
    context.metrics["particle_accuracy_90"] = p.accuracy_90;
    context.metrics["confidence_error_spearman"] = p.confidence_error_spearman;
    context.metrics["sparsification_auc_ratio"] = p.sparsification_auc_ratio;
    spdlog::info("[surfels] mesh accuracy (90%) {:.4g}, completeness {:.1f}% within {:.4g}", a.accuracy_90,
                 100 * a.completeness, a.threshold);
  }

  static SurfelOptions ToOptions(const Params& params) {
    SurfelOptions o;
    o.spacing_scale = params.Double("spacing_scale");
    o.spacing = params.Double("spacing");
    o.iterations = static_cast<int>(params.Int("iterations"));
    o.grow_rounds = static_cast<int>(params.Int("grow_rounds"));
    o.weights.coplanarity = params.Double("coplanarity");
    o.weights.conormality = params.Double("conormality");
    o.weights.cocircularity = params.Double("cocircularity");
    o.weights.repulsion = params.Double("repulsion");
    o.weights.data = params.Double("data_weight");
    o.weights.sigma = params.Double("sigma");
    o.weights.repulsion_radius = params.Double("repulsion_radius");
    o.weights.data_sigma = params.Double("data_sigma");
    o.weights.tangential = params.Double("tangential");
    o.stretch_distance = params.Double("stretch_distance");
    o.max_gap = params.Double("max_gap");
    o.max_normal_angle_deg = params.Double("max_normal_angle_deg");
    o.min_support = static_cast<int>(params.Int("min_support"));
    o.support_radius = params.Double("support_radius");
    o.min_support_fraction = params.Double("min_support_fraction");
    o.min_neighbours = static_cast<int>(params.Int("min_neighbours"));
    o.free_space_views = static_cast<int>(params.Int("free_space_views"));
    o.free_space_margin = params.Double("free_space_margin");
    o.silhouette_views = static_cast<int>(params.Int("silhouette_views"));
    o.silhouette_color_tolerance = static_cast<int>(std::clamp<int64_t>(params.Int("silhouette_color_tolerance"), -1, 256));
    o.max_edge = params.Double("max_edge");
    o.max_hole_edges = static_cast<int>(params.Int("max_hole_edges"));
    o.min_component_faces = static_cast<int>(params.Int("min_component_faces"));
    o.border_extension = params.Double("border_extension");
    o.max_particles = static_cast<int>(std::clamp<int64_t>(params.Int("max_particles"), -1, 2000000000));
    return o;
  }
};

// `ibmr mesh-accuracy MESH TRUTH [SAMPLES]`: the measures above for any mesh (a Poisson baseline,
// another tool's output), printed as JSON.
int MeshAccuracyCommand(const std::vector<std::string>& args) {
  if (args.size() < 2 || args.size() > 3 || args[0] == "--help") {
    std::cout << "usage: ibmr mesh-accuracy MESH.ply TRUTH.ply [SAMPLES]   (prints JSON: accuracy_90, completeness "
                 "within 1% of the truth's bounding-box diagonal)\n";
    return !args.empty() && args[0] == "--help" ? 0 : 2;
  }
  try {
    const long long samples = args.size() == 3 ? std::stoll(args[2]) : 200000;
    if (samples < 1000 || samples > 10000000) throw InputError("SAMPLES: must be in [1000, 10000000], got " + args[2]);
    const TriangleMesh mesh = ReadMeshPly(args[0]);
    const PointSetAccuracy a = EvaluateMesh(mesh, ReadMeshPly(args[1]), static_cast<size_t>(samples));
    if (a.points == 0) throw InputError(args[0] + " or " + args[1] + ": a mesh without area; nothing to measure");
    std::cout << nlohmann::json{{"mesh", args[0]},           {"truth", args[1]},
                                {"faces", mesh.faces.size()}, {"accuracy_90", a.accuracy_90},
                                {"accuracy_median", a.accuracy_median}, {"completeness", a.completeness},
                                {"threshold", a.threshold},   {"samples", samples}}
                     .dump(2)
              << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
}

}  // namespace

void RegisterStage_surfels(StageRegistry* registry) {
  registry->Add(std::make_unique<SurfelsStage>());
  registry->AddCommand({"mesh-accuracy", "Accuracy and completeness of a mesh against a true mesh (JSON)", MeshAccuracyCommand});
}

}  // namespace ibmr
