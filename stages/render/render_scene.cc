// The training views, sparse points and desired views every render model shares (render_scene.h).
#include "stages/render/render_scene.h"

#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <filesystem>
#include <map>

#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/undistorted_cameras.h"

namespace fs = std::filesystem;

namespace ibmr {

int RenderScene::SelfSource(const std::string& name) const {
  if (!exclude_self) return -1;
  const auto found = std::find(training.begin(), training.end(), name);
  return found == training.end() ? -1 : static_cast<int>(found - training.begin());
}

const std::vector<SourceView>* RenderScene::SourcesWithout(const std::vector<SourceView>& all,
                                                           const std::string& name,
                                                           std::vector<SourceView>* own) const {
  const bool has_self = std::any_of(all.begin(), all.end(), [&](const SourceView& s) { return s.name == name; });
  if (!exclude_self || !has_self) return &all;
  for (const SourceView& s : all) {
    if (s.name != name) own->push_back(s);
  }
  return own;
}

namespace {

Camera PinholeOf(const Camera& camera, const std::string& image_name, const Workspace& workspace) {
  RequireUndistorted(camera, image_name, workspace.SparseDir() + "/cameras.txt", "render");
  return camera;
}

}  // namespace

RenderOptions ToRenderOptions(const Params& params) {
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

// The training views' photos (a held-out photo's pixels are never read), the sparse points they
// see and the point nearest to their optical axes.
void LoadRenderScene(const StageContext& context, const SparseModel& model, RenderScene* scene) {
  scene->context = &context;
  scene->model = &model;
  scene->options = ToRenderOptions(context.params);
  scene->exclude_self = context.params.Bool("exclude_self");
  scene->factor = static_cast<int>(context.params.Int("supersample"));
  for (const std::string& name : context.TrainingImageNames(model)) {
    if (!context.IsHeldOut(name)) scene->training.push_back(name);
  }
  if (scene->training.empty()) throw InputError("render: every image is held out; nothing to render from (check holdout)");
  std::vector<SourceView>& sources = scene->sources;
  sources.resize(scene->training.size());
  tbb::parallel_for(size_t{0}, sources.size(), [&](size_t i) {
    const Image& image = *model.FindImage(scene->training[i]);
    sources[i].name = image.name;
    sources[i].camera = PinholeOf(model.CameraOf(image), image.name, context.workspace);
    sources[i].cam_from_world = image.cam_from_world;
    const std::string path = context.workspace.ImagesDir() + "/" + image.name;
    sources[i].image = ReadImageColor(path);
    if (sources[i].image.cols != sources[i].camera.width || sources[i].image.rows != sources[i].camera.height) {
      throw InputError(path + ": image is " + std::to_string(sources[i].image.cols) + "x" +
                       std::to_string(sources[i].image.rows) + " but its camera says " +
                       std::to_string(sources[i].camera.width) + "x" + std::to_string(sources[i].camera.height));
    }
  });
  std::set<int> training_ids;
  std::vector<Eigen::Vector3d> centers, directions;
  for (const std::string& name : scene->training) {
    const Image* image = model.FindImage(name);
    training_ids.insert(image->image_id);
    centers.push_back(image->Center());
    directions.push_back(image->ViewingDirection());
  }
  for (const auto& [id, point] : model.points) {
    // A non-finite point would make the plane's depth and the layers' scene centre NaN (a black
    // render reported as rendered); it says nothing about where the scene is.
    if (!point.xyz.allFinite()) continue;
    bool seen = point.track.empty();
    for (const TrackElement& element : point.track) seen = seen || training_ids.count(element.image_id) > 0;
    if (seen) scene->sparse_points.push_back(point.xyz);
  }
  // Without sparse points (an LLFF import: poses and per-view bounds only), the capture's bounds
  // (sparse/depth_bounds.json) stand for them: a point on each training view's optical axis at
  // the mean inverse depth of its near and far bound, so the plane lies where the scene is.
  const std::string bounds_path = context.workspace.Path("sparse/depth_bounds.json");
  if (scene->sparse_points.empty()) {
    const nlohmann::json bounds = ReadJsonOr(bounds_path, nlohmann::json::object());
    for (size_t i = 0; i < scene->training.size(); ++i) {
      const nlohmann::json entry = bounds.value(scene->training[i], nlohmann::json::object());
      const double near = entry.value("near", 0.0), far = entry.value("far", 0.0);
      if (!(near > 0 && far > near)) continue;
      scene->sparse_points.push_back(centers[i] + directions[i] * (2.0 / (1.0 / near + 1.0 / far)));
    }
  }
  scene->have_axes_point = PointNearestToAxes(centers, directions, &scene->axes_point);
}

// The photographed views (render.views, else the held-out ones) and the novel camera, less those
// outside this run's shard; two views with one stem are refused.
std::vector<DesiredView> DesiredViews(const StageContext& context, const SparseModel& model, const RenderScene& scene,
                                      const std::vector<std::string>& photo_views, const std::set<std::string>& shard) {
  std::vector<DesiredView> desired;
  for (const std::string& name : photo_views) {
    const Image* image = model.FindImage(name);
    if (!image) throw InputError("render.views: no image named \"" + name + "\" in " + context.workspace.SparseDir());
    desired.push_back({name, fs::path(name).stem().string(), PinholeOf(model.CameraOf(*image), name, context.workspace),
                       image->cam_from_world});
  }
  const std::vector<double> look = context.params.DoubleList("novel_look_at");
  if (!look.empty()) {
    const Eigen::Vector3d eye(look[0], look[1], look[2]), target(look[3], look[4], look[5]);
    const Eigen::Vector3d up = look.size() == 9 ? Eigen::Vector3d(look[6], look[7], look[8]) : Eigen::Vector3d(0, 0, 1);
    desired.push_back({"novel", "novel", scene.sources[0].camera, LookAt(eye, target, up)});
  }
  if (desired.empty()) {
    spdlog::warn("[render] no view to render: the config holds no view out (holdout) and lists no render.views");
  }
  // Every file of a view is named by its image's stem (renders/<model>/<stem>.png, the checkpoint
  // keys): two views with one stem (view_000.png and view_000.jpg, left/0001.jpg and
  // right/0001.jpg) would overwrite each other's renders and be scored against the wrong photo.
  std::map<std::string, std::string> view_of_stem;
  for (const DesiredView& view : desired) {
    const auto [other, fresh] = view_of_stem.emplace(view.stem, view.name);
    if (!fresh) {
      throw InputError("render: views \"" + other->second + "\" and \"" + view.name +
                       "\" would both be written as renders/<proxy>/" + view.stem +
                       ".png (same file stem); rename one of the images (in " + context.workspace.ImagesDir() + " and " +
                       context.workspace.SparseDir() + "/images.txt), or render only one of them (render.views, holdout)");
    }
  }
  if (shard.empty()) return desired;
  std::string unknown;
  for (const std::string& name : shard) {
    if (std::none_of(desired.begin(), desired.end(), [&](const DesiredView& d) { return d.name == name; })) {
      unknown += (unknown.empty() ? "" : ", ") + name;
    }
  }
  if (!unknown.empty()) throw InputError("--views: not among render's views (held out or render.views): " + unknown);
  desired.erase(std::remove_if(desired.begin(), desired.end(), [&](const DesiredView& d) { return !shard.count(d.name); }),
                desired.end());
  return desired;
}

}  // namespace ibmr
