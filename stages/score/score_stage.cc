// Adapter of the score stage (held-out-view cross-validation, seed 000 lines 5906-5920; see
// score.h): compares every render listed in renders/renders.json (written by the render stage)
// with the real photo of that view, and writes scores/heldout.json (per proxy: per view and mean,
// with and without views near a training camera; skipped proxies with the reason) and side-by-side
// images scores/<proxy>/<image stem>.png (real | rendered | error).
// Masks, first found: ground_truth/masks/<image>.png (synth), heldout/masks/<image>.png
// (silhouettes stage), masks/<image>.png.
#include <spdlog/spdlog.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/task_arena.h>
#include <Eigen/Eigenvalues>
#include <Eigen/Cholesky>

#include <algorithm>
#include <filesystem>
#include <limits>
#include <map>
#include <set>

#include "pipeline/core/optical_axes.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/view_cache.h"
#include "stages/score/score.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

const char* const kMaskFolders[] = {"ground_truth/masks", "heldout/masks", "masks"};

// A held-out photo with its share of the SSIM statistics, prepared once for every model's render
// of its view: before, each render re-read its photo and blurred it again (on templeRing 14
// models x 6 views read and blurred each photo 14-28 times, twice where a filled render is
// scored too).
struct ScoredPhoto {
  cv::Mat image;            // CV_8UC3
  SsimReference reference;  // PrepareSsimReference(image)
};
using PhotoCache = ViewCache<ScoredPhoto>;

nlohmann::json ToJson(const MaskedScore& s) {
  return {{"psnr", s.psnr}, {"ssim", s.ssim}, {"coverage", s.coverage}, {"pixels", s.pixels}};
}

// Mean of the per-view entries' metrics over the views selected by `use`: each metric over the
// views that have it (a view with no covered pixel has no psnr or ssim; "views" counts them all).
nlohmann::json Mean(const nlohmann::json& views, const std::function<bool(const nlohmann::json&)>& use) {
  const char* const keys[] = {"psnr",          "ssim",          "coverage",        "mask_psnr",
                              "mask_ssim",     "mask_coverage", "photo_psnr",      "photo_ssim",
                              "photo_coverage", "filled_psnr",  "filled_coverage", "filled_photo_psnr"};
  std::map<std::string, std::pair<double, int>> sums;
  int count = 0;
  for (const auto& [name, view] : views.items()) {
    if (!use(view)) continue;
    ++count;
    for (const char* key : keys) {
      if (view.contains(key) && view[key].is_number()) {
        sums[key].first += view[key].get<double>();
        ++sums[key].second;
      }
    }
  }
  nlohmann::json mean = {{"views", count}};
  for (const auto& [key, sum] : sums) mean[key] = sum.first / sum.second;
  return mean;
}

class ScoreStage : public Stage {
 public:
  std::string Name() const override { return "score"; }
  std::string Summary() const override {
    return "Held-out-view cross-validation: PSNR, SSIM, coverage, masked error, angle to the nearest training view";
  }
  // 2: photo_* scores; 3: filled_* scores; 4: SSIM blurred in float (scores move by up to 2e-6)
  std::string Version() const override { return "4"; }
  HoldoutRole Role() const override { return HoldoutRole::kScoring; }

  std::vector<ParamSpec> Parameters() const override {
    return {
        {"gain_correction", ParamType::kBool, "false", "per-image, per-channel least-squares gain on each render", {}},
        {"near_angle_deg", ParamType::kDouble, "1",
         "held-out views closer than this (degrees) to a training camera are reported apart, in [0, 180)", {}},
        {"error_gain", ParamType::kInt, "4", "error panel of the side-by-side images: |real - render| times this, in [1, 64]",
         {}},
        {"photo_threshold", ParamType::kInt, "20",
         "photo_* scores count the real photo's pixels whose largest channel is above this (holes black), in [-1, 255]", {}},
    };
  }

  std::optional<ParamError> CheckParams(const Params& params) const override {
    std::string error;
    if (!ToOptions(params).Check(&error)) return ParamError::FromCheck(error);
    return std::nullopt;
  }

  std::vector<std::string> Inputs(const StageContext& context) const override {
    return {"renders", context.workspace.ImagesRelative(), context.workspace.SparseRelative(), "ground_truth/masks", "heldout/masks", "masks"};
  }
  // The scores and an error-image folder per rendered model (select writes beside them).
  std::vector<std::string> Outputs(const StageContext& context) const override {
    std::vector<std::string> outputs = {"scores/heldout.json"};
    const nlohmann::json renders = ReadJsonOr(context.workspace.Path("renders/renders.json"), nlohmann::json::object());
    for (const nlohmann::json& proxy : renders.value("proxies", nlohmann::json::array())) {
      if (proxy.value("status", "") == "rendered") outputs.push_back("scores/" + proxy.value("name", ""));
    }
    return outputs;
  }

  // One render's scoring at its peak, at most 120 bytes a pixel: the render, coverage, mask and
  // side-by-side images (about 20), the SSIM's working images (SsimBuffers, six to ten floats, and
  // its maps of doubles, two at once for the photo score: 40-56) which stay with the thread for
  // its next render, the PNG encoder's filtered rows and output while the side-by-side image is
  // written (about 18), and its share of the photos the stage's cache keeps (one photo with its
  // SSIM reference per item in flight and one more: 27 each).
  // Measured with double working images and no cache, on the Sceaux castle's 1600x1202 renders
  // (estimate 220 MB): 216 MB above the stage's start with one render in flight, 412 MB with two.
  double ViewMemoryMb(const StageContext& context) const override {
    return LargestTrainingImage(context).Pixels() * 120.0 / 1048576.0;
  }

  void Run(StageContext& context) const override {
    const ScoreOptions options = ToOptions(context.params);
    const Workspace& ws = context.workspace;
    const nlohmann::json renders = ReadStageJson(ws.Path("renders/renders.json"), "render", "score");
    const SparseModel model = ReadSparseModelText(ws.SparseDir());

    // Geometry for the nearest-training-camera angle.
    std::vector<Eigen::Vector3d> training_centers;
    std::vector<std::string> training_names;
    std::vector<Eigen::Vector3d> centers, directions;
    Eigen::Vector3d mean_center = Eigen::Vector3d::Zero(), mean_direction = Eigen::Vector3d::Zero();
    for (const auto& [id, image] : model.images) {
      const Eigen::Vector3d v = image.ViewingDirection().normalized();
      centers.push_back(image.Center());
      directions.push_back(v);
      mean_center += image.Center() / model.images.size();
      mean_direction += v;
      if (!context.IsHeldOut(image.name)) {
        training_centers.push_back(image.Center());
        training_names.push_back(image.name);
      }
    }
    Eigen::Vector3d scene_center;
    std::string center_kind = "nearest_to_axes";
    if (!PointNearestToAxes(centers, directions, &scene_center)) {
      // Finite points only: one NaN or infinite coordinate would make the centre (and every
      // nearest-camera angle) NaN, written as null.
      std::vector<Eigen::Vector3d> points;
      for (const auto& [id, point] : model.points) points.push_back(point.xyz);
      const bool have_points = MeanOfFinitePoints(points, &scene_center);
      if (!have_points) scene_center = mean_center + mean_direction.normalized();
      center_kind = have_points ? "mean_sparse_point" : "ahead_of_cameras";
    }

    nlohmann::json out = {{"primary", renders.value("primary", "")},
                          {"near_angle_deg", options.near_angle_deg},
                          {"gain_correction", options.gain_correction},
                          {"scene_center", {scene_center.x(), scene_center.y(), scene_center.z()}},
                          {"scene_center_from", center_kind},
                          {"heldout", context.heldout_images},
                          {"proxies", nlohmann::json::object()}};
    fs::create_directories(ws.Path("scores"));
    // Every rendered view of every proxy is an item of the per-view loop, named <proxy>/<image>
    // (proxy names are unique: render never writes one twice). Items are scored in parallel (each
    // reads its own files and writes its own side-by-side image), as many at once as the memory
    // budget holds (ViewMemoryMb), marked done as they finish (a stopped run resumes there), then
    // gathered in the order renders.json gives.
    const nlohmann::json proxies = renders.value("proxies", nlohmann::json::array());
    struct Item {
      std::string proxy, image;
      nlohmann::json info;
    };
    std::vector<Item> items;
    std::vector<std::string> item_names;
    std::vector<size_t> first_item;  // per proxy of renders.json, its first item (the next proxy's ends it)
    std::map<std::string, size_t> item_of;
    std::set<std::string> proxy_names;
    for (const nlohmann::json& proxy : proxies) {
      first_item.push_back(items.size());
      if (proxy.value("status", "") != "rendered") continue;
      const std::string name = proxy.value("name", "");
      if (name.empty() || name.find('/') != std::string::npos || name == "." || name == ".." || !proxy_names.insert(name).second) {
        throw InputError(ws.Path("renders/renders.json") + ": a rendered proxy named '" + name +
                         "' (empty, a path, or listed twice: its scores would mix); re-run the render stage");
      }
      fs::create_directories(ws.Path("scores/" + name));
      const nlohmann::json views = proxy.value("views", nlohmann::json::object());  // named: items() refers to it
      for (const auto& [image_name, info] : views.items()) {
        const std::string item_name = name + "/" + image_name;
        item_of[item_name] = items.size();
        items.push_back({name, image_name, info});
        item_names.push_back(item_name);
      }
    }
    first_item.push_back(items.size());
    tbb::enumerable_thread_specific<SsimBuffers> buffers;  // one set per thread scoring; freed when the stage is done
    // Each held-out photo is read and blurred once for the renders of all models (ScoredPhoto), so
    // the items run view by view: the threads then share the few photos they work on. The cache
    // keeps one photo per item in flight (the memory budget's, as ViewMemoryMb counts it) and one more.
    std::vector<std::string> view_major = item_names;
    std::stable_sort(view_major.begin(), view_major.end(), [&](const std::string& a, const std::string& b) {
      return items[item_of.at(a)].image < items[item_of.at(b)].image;
    });
    const int threads = tbb::this_task_arena::max_concurrency();
    const int in_flight = context.max_views_in_flight > 0 ? std::min(context.max_views_in_flight, threads) : threads;
    PhotoCache photos(static_cast<size_t>(in_flight) + 1, [](const std::string& path) {
      ScoredPhoto photo;
      photo.image = ReadImageColor(path);
      photo.reference = PrepareSsimReference(photo.image);
      return photo;
    });
    const PerViewSummary summary = ForEachView(context, "score", view_major, [&](const std::string& item_name) {
      const Item& item = items[item_of.at(item_name)];
      nlohmann::json result;
      // Isolated: while this view's OpenCV calls wait for parallel work, this thread takes no other
      // view (which would use the same buffers).
      tbb::this_task_arena::isolate([&] {
        result = ScoreView(context, options, item.proxy, item.image, item.info, model, training_centers, training_names,
                           scene_center, &photos, &buffers.local());
      });
      return result;
    });
    const size_t scored = items.size();
    for (size_t p = 0; p < proxies.size(); ++p) {
      const nlohmann::json& proxy = proxies[p];
      const std::string name = proxy.value("name", "");
      if (proxy.value("status", "") != "rendered") {
        if (proxy.value("left_out_by_plan", false)) {  // the run's plan, said by the runner already
          spdlog::info("[score] proxy {} was not rendered ({}); no scores for it", name, proxy.value("reason", "?"));
        } else {
          spdlog::warn("[score] proxy {} was not rendered ({}); no scores for it", name, proxy.value("reason", "?"));
        }
        out["proxies"][name] = {{"status", "skipped"}, {"reason", proxy.value("reason", "not rendered")}};
        continue;
      }
      nlohmann::json views = nlohmann::json::object();
      for (size_t i = first_item[p]; i < first_item[p + 1]; ++i) views[items[i].image] = summary.pieces.at(item_names[i]);
      const double near = options.near_angle_deg;
      const auto is_near = [near](const nlohmann::json& v) {
        return v.contains("nearest_training_angle_deg") && v["nearest_training_angle_deg"].get<double>() < near;
      };
      nlohmann::json pj = {{"status", "scored"},
                           {"path", proxy.value("path", "")},
                           {"views", views},
                           {"mean", Mean(views, [](const nlohmann::json&) { return true; })},
                           {"mean_excluding_near", Mean(views, [&](const nlohmann::json& v) { return !is_near(v); })},
                           {"mean_near", Mean(views, is_near)}};
      context.metrics[name] = pj["mean"];
      if (pj["mean"].contains("filled_psnr")) {
        spdlog::info("[score] {}: holes filled (render.background): PSNR {:.2f} dB over {:.3f} of the image", name,
                     pj["mean"].value("filled_psnr", 0.0), pj["mean"].value("filled_coverage", 0.0));
      }
      spdlog::info("[score] {}: mean PSNR {:.2f} dB, SSIM {:.3f}, coverage {:.3f}; lit photo pixels (holes black) "
                   "{:.2f} dB, covered {:.3f}; over {} views",
                   name, pj["mean"].value("psnr", 0.0), pj["mean"].value("ssim", 0.0), pj["mean"].value("coverage", 0.0),
                   pj["mean"].value("photo_psnr", 0.0), pj["mean"].value("photo_coverage", 0.0), views.size());
      out["proxies"][name] = pj;
    }
    if (scored == 0) spdlog::warn("[score] no render to score (is any view held out? see holdout in the config)");
    WriteFileAtomic(ws.Path("scores/heldout.json"), out.dump(2) + "\n");
    context.metrics["views_scored"] = scored;
  }

 private:
  static ScoreOptions ToOptions(const Params& params) {
    ScoreOptions options;
    options.gain_correction = params.Bool("gain_correction");
    options.near_angle_deg = params.Double("near_angle_deg");
    options.error_gain = static_cast<int>(params.Int("error_gain"));
    options.photo_threshold = static_cast<int>(params.Int("photo_threshold"));
    return options;
  }

  // <name>.png -> <name>.coverage.png beside it (render's naming of a render's coverage).
  static std::string CoveragePathOf(const std::string& render_path) {
    const fs::path path(render_path);
    return (path.parent_path() / (path.stem().string() + ".coverage" + path.extension().string())).string();
  }

  static nlohmann::json ScoreView(const StageContext& context, const ScoreOptions& options, const std::string& proxy,
                                  const std::string& image_name, const nlohmann::json& info, const SparseModel& model,
                                  const std::vector<Eigen::Vector3d>& training_centers,
                                  const std::vector<std::string>& training_names, const Eigen::Vector3d& scene_center,
                                  PhotoCache* photos, SsimBuffers* buffers) {
    const Workspace& ws = context.workspace;
    // The render as renders.json lists it (its file name is render's, not rebuilt here from the
    // image name); older renders.json files without the entry used renders/<proxy>/<stem>.png.
    const std::string stem = fs::path(image_name).stem().string();
    const std::string render_relative = info.value("render", "renders/" + proxy + "/" + stem + ".png");
    const std::string render_path = ws.Path(render_relative);
    const std::string coverage_path = CoveragePathOf(render_path);
    const std::string real_path = ws.ImagesDir() + "/" + image_name;
    nlohmann::json v = {{"render", render_relative}};
    if (!fs::exists(real_path)) {
      spdlog::warn("[score] {}: no real photo {}; view not scored", image_name, real_path);
      v["error"] = real_path + " does not exist";
      return v;
    }
    for (const std::string& path : {render_path, coverage_path}) {
      if (!fs::exists(path)) {
        throw InputError(path + ": missing, though renders/renders.json lists the view " + image_name + " of proxy " +
                         proxy + "; re-run the render stage");
      }
    }
    const std::shared_ptr<const ScoredPhoto> photo = photos->Get(real_path);
    const cv::Mat& real = photo->image;
    const cv::Mat rendered = ReadImageColor(render_path);
    const cv::Mat coverage = ReadImageUnchanged(coverage_path);
    if (rendered.size() != real.size() || coverage.size() != real.size() || coverage.type() != CV_8UC1) {
      throw InputError(render_path + ": size differs from the photo " + real_path + " (or its coverage mask " +
                       coverage_path + " is not 8-bit grey); re-run the render stage");
    }
    cv::Mat mask;
    for (const char* folder : kMaskFolders) {
      const std::string path = ws.Path(std::string(folder) + "/" + image_name + ".png");
      if (!fs::exists(path)) continue;
      mask = ReadImageUnchanged(path);
      if (mask.channels() != 1 || mask.size() != real.size()) {
        spdlog::warn("[score] {}: mask is not {}x{} 8-bit grey; ignored", path, real.cols, real.rows);
        mask = cv::Mat();
        continue;
      }
      if (mask.depth() != CV_8U) mask.convertTo(mask, CV_8U);
      v["mask"] = std::string(folder) + "/" + image_name + ".png";
      break;
    }
    const ImageScore score = ScoreImage(real, rendered, coverage, mask, options, buffers, &photo->reference);
    // A render that covers no pixel has no PSNR or SSIM (ScoreImage's 0 is not a score): they are
    // left out, so the means run over the views that have them, as for photo_*; coverage says 0.
    if (score.all.pixels > 0) {
      v["psnr"] = score.all.psnr;
      v["ssim"] = score.all.ssim;
    }
    v["coverage"] = score.all.coverage;
    v["covered_pixels"] = score.all.pixels;
    if (score.has_mask) {
      if (score.mask.pixels > 0) {
        v["mask_psnr"] = score.mask.psnr;
        v["mask_ssim"] = score.mask.ssim;
      }
      v["mask_coverage"] = score.mask.coverage;
    }
    if (score.photo.pixels > 0) {  // a photo without lit pixels has no photo score (not 0 dB in the mean)
      v["photo_psnr"] = score.photo.psnr;
      v["photo_ssim"] = score.photo.ssim;
      v["photo_coverage"] = score.photo.coverage;
    }
    if (options.gain_correction) v["gains_bgr"] = {score.gains[0], score.gains[1], score.gains[2]};
    // The render with its holes filled by the background (render.background): the same metrics,
    // so a model is judged both alone (holes black) and as it would be shown. Only when the view's
    // entry says render made it: a .filled.png left by an earlier run with another background is
    // stale.
    if (info.contains("filled") && info["filled"].is_string()) {
      const std::string filled_path = ws.Path(info["filled"].get<std::string>());
      const std::string filled_coverage_path = CoveragePathOf(filled_path);
      for (const std::string& path : {filled_path, filled_coverage_path}) {
        if (!fs::exists(path)) {
          throw InputError(path + ": missing, though renders/renders.json lists a filled render of the view " +
                           image_name + " of proxy " + proxy + "; re-run the render stage");
        }
      }
      const cv::Mat filled = ReadImageColor(filled_path);
      const cv::Mat filled_coverage = ReadImageUnchanged(filled_coverage_path);
      if (filled.size() != real.size() || filled_coverage.size() != real.size() || filled_coverage.type() != CV_8UC1) {
        throw InputError(filled_path + ": size differs from the photo " + real_path + "; re-run the render stage");
      }
      const ImageScore filled_score = ScoreImage(real, filled, filled_coverage, mask, options, buffers, &photo->reference);
      if (filled_score.all.pixels > 0) {
        v["filled_psnr"] = filled_score.all.psnr;
        v["filled_ssim"] = filled_score.all.ssim;
      }
      v["filled_coverage"] = filled_score.all.coverage;
      if (filled_score.photo.pixels > 0) v["filled_photo_psnr"] = filled_score.photo.psnr;
    }
    if (const Image* image = model.FindImage(image_name)) {
      std::vector<Eigen::Vector3d> others;
      std::vector<std::string> other_names;
      for (size_t i = 0; i < training_centers.size(); ++i) {
        if (training_names[i] == image_name) continue;  // a training view rendered leave-one-out
        others.push_back(training_centers[i]);
        other_names.push_back(training_names[i]);
      }
      int nearest = -1;
      const double angle = NearestCameraAngleDeg(image->Center(), others, scene_center, &nearest);
      if (nearest >= 0) {
        v["nearest_training_angle_deg"] = angle;
        v["nearest_training_view"] = other_names[nearest];
        v["near_training_view"] = angle < options.near_angle_deg;
      }
    }
    v["sources"] = info.value("sources", 0);
    // Named after the render's file, which render keeps unique per proxy.
    WriteImage(ws.Path("scores/" + proxy + "/" + fs::path(render_path).filename().string()),
               SideBySide(real, rendered, coverage, options.error_gain));
    return v;
  }
};

}  // namespace

void RegisterStage_score(StageRegistry* registry) { registry->Add(std::make_unique<ScoreStage>()); }

}  // namespace ibmr
