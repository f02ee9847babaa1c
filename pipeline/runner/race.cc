// The race (see race.h).
#include "pipeline/runner/race.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/capture_info.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/heldout_scores.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/runner/record.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

// `from` resized to `size` into `to`, unless `to` is newer than `from` and `kept_size` (its size
// in the race's model before) is `size` already.
void ScaleImage(const std::string& from, const std::string& to, cv::Size size, cv::Size kept_size) {
  std::error_code ec;
  if (kept_size == size && fs::exists(to, ec) && fs::last_write_time(to, ec) >= fs::last_write_time(from, ec)) return;
  const cv::Mat image = ReadImageUnchanged(from);
  if (image.empty()) throw IoError(from + ": cannot read the photo for the race");
  cv::Mat scaled;
  cv::resize(image, scaled, size, 0, 0, cv::INTER_AREA);
  fs::create_directories(fs::path(to).parent_path());
  WriteImage(to, scaled);
}

}  // namespace

std::vector<std::string> ValidationViews(const std::vector<std::string>& training, int every) {
  std::vector<std::string> sorted = training;
  std::sort(sorted.begin(), sorted.end());
  std::vector<std::string> validation;
  for (size_t i = static_cast<size_t>(every / 2); i < sorted.size(); i += static_cast<size_t>(every)) {
    validation.push_back(sorted[i]);
  }
  return validation;
}

void PrepareRaceCapture(const Workspace& model, const std::set<std::string>& heldout, double scale,
                        const std::string& race_workspace) {
  SparseModel sparse = ReadSparseModelText(model.SparseDir());
  RemoveImages(heldout, &sparse);  // the held-out views leave the model, their observations the tracks
  // Cameras and observations scaled: pixel coordinates scale with the image (corner at 0).
  std::map<int, std::pair<double, double>> factors;
  for (auto& [id, camera] : sparse.cameras) {
    const Camera scaled = camera.Scaled(scale);
    factors[id] = {static_cast<double>(scaled.width) / camera.width, static_cast<double>(scaled.height) / camera.height};
    camera = scaled;
  }
  const Workspace race(race_workspace);
  const bool has_alpha = CaptureHasAlpha(model);
  // The photos' sizes in an earlier race (none: every photo is written).
  std::map<std::string, cv::Size> kept_sizes;
  if (fs::exists(race.Path("sparse/images.txt"))) {
    try {
      const SparseModel kept = ReadSparseModelText(race.Path("sparse"));
      for (const auto& [id, image] : kept.images) {
        const Camera& camera = kept.CameraOf(image);
        kept_sizes[image.name] = cv::Size(camera.width, camera.height);
      }
    } catch (const std::exception&) {  // unreadable: written anew
    }
  }
  for (auto& [id, image] : sparse.images) {
    const auto [fx, fy] = factors.at(image.camera_id);
    for (Point2D& point : image.points2D) point.xy = Eigen::Vector2d(point.xy.x() * fx, point.xy.y() * fy);
    const Camera& camera = sparse.cameras.at(image.camera_id);
    const cv::Size size(camera.width, camera.height);
    const auto kept = kept_sizes.find(image.name);
    const cv::Size kept_size = kept == kept_sizes.end() ? cv::Size() : kept->second;
    ScaleImage(model.ImagesDir() + "/" + image.name, race.Path("images/" + image.name), size, kept_size);
    const std::string alpha = model.Path(std::string(kAlphaFolder) + "/" + image.name + ".png");
    if (has_alpha && fs::exists(alpha)) {
      ScaleImage(alpha, race.Path(std::string(kAlphaFolder) + "/" + image.name + ".png"), size, kept_size);
    }
  }
  // Photos of an earlier race whose views are not in this one (the holdout changed) go.
  std::set<std::string> kept;
  for (const auto& [id, image] : sparse.images) {
    kept.insert(race.Path("images/" + image.name));
    kept.insert(race.Path(std::string(kAlphaFolder) + "/" + image.name + ".png"));
  }
  for (const std::string folder : {std::string("images"), std::string(kAlphaFolder)}) {
    std::error_code ec;
    std::vector<fs::path> stale;
    for (auto it = fs::recursive_directory_iterator(race.Path(folder), ec); !ec && it != fs::recursive_directory_iterator();
         it.increment(ec)) {
      if (it->is_regular_file() && !kept.count(it->path().lexically_normal().string())) stale.push_back(it->path());
    }
    for (const fs::path& path : stale) fs::remove(path, ec);
  }
  fs::create_directories(race.Path("sparse"));
  WriteSparseModelText(race.Path("sparse"), sparse);
  // What else the model folder holds (LLFF's depth_bounds.json), and the capture's own files.
  for (const auto& entry : fs::directory_iterator(model.SparseDir())) {
    const std::string name = entry.path().filename().string();
    if (name == "cameras.txt" || name == "images.txt" || name == "points3D.txt" || !entry.is_regular_file()) continue;
    fs::copy_file(entry.path(), race.Path("sparse/" + name), fs::copy_options::overwrite_existing);
  }
  for (const char* file : {kBackgroundFile, kSplitsFile}) {
    if (fs::exists(model.Path(file))) fs::copy_file(model.Path(file), race.Path(file), fs::copy_options::overwrite_existing);
  }
}

RaceOutcome RunRace(const Config& config, const StageRegistry& registry, size_t model_stage, const Workspace& model,
                    const std::set<std::string>& heldout, const std::string& kind, const RunOptions& options) {
  RaceOutcome outcome;
  outcome.workspace = Workspace(config.workspace).Path("race");
  const RacePlan& plan = config.plan.race;
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::string> training;
  try {
    const SparseModel sparse = ReadSparseModelText(model.SparseDir());
    for (const auto& [id, image] : sparse.images) {
      if (!heldout.count(image.name)) training.push_back(image.name);
    }
    outcome.validation = ValidationViews(training, plan.validation_every);
    if (outcome.validation.empty() || training.size() - outcome.validation.size() < 2) {
      outcome.problem = std::to_string(training.size()) + " training views are too few to hold " +
                        std::to_string(std::max<size_t>(1, outcome.validation.size())) +
                        " out for validation and reconstruct from the rest";
      return outcome;
    }
    spdlog::info("race: the stages after {} on the {} training views scaled by {} in {}, {} of them held out and "
                 "scored ({} every {})",
                 config.stages[model_stage].name, training.size(), plan.scale, outcome.workspace,
                 outcome.validation.size(), plan.metric, plan.validation_every);
    PrepareRaceCapture(model, heldout, plan.scale, outcome.workspace);
  } catch (const std::exception& e) {
    outcome.problem = e.what();
    return outcome;
  }

  Config race = config;
  race.workspace = outcome.workspace;
  race.stages.assign(config.stages.begin() + static_cast<long>(model_stage) + 1, config.stages.end());
  race.holdout = HoldoutPolicy();
  race.holdout.images = outcome.validation;
  race.plan.race.enabled = false;
  if (!kind.empty()) race.plan.kind = kind;
  RunOptions race_options;
  race_options.jobs = options.jobs;
  race_options.memory_limit_mb = options.memory_limit_mb;
  race_options.interactive = options.interactive;
  Runner runner(race, registry);
  const int code = runner.Run(race_options);
  outcome.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (code != 0) {
    outcome.problem = "a stage failed in the race (its log above; records in " + outcome.workspace + "/records)";
    return outcome;
  }
  for (const StageConfig& stage : race.stages) {
    if (const auto record = ReadRecord(outcome.workspace + "/records/" + stage.name + ".json"); record && record->status == "ok") {
      outcome.stage_seconds[stage.name] = record->wall_seconds;
    }
  }
  const nlohmann::json scores = ReadJsonOr(outcome.workspace + "/scores/heldout.json", nlohmann::json());
  if (!scores.is_object() || !scores.contains("proxies") || !scores["proxies"].is_object()) {
    outcome.problem = "the race scored no model (the config has no render and score stages)";
    return outcome;
  }
  for (auto it = scores["proxies"].begin(); it != scores["proxies"].end(); ++it) {
    const nlohmann::json means = HeldoutMeans(it.value());
    if (means.contains(plan.metric) && means[plan.metric].is_number()) outcome.scores[it.key()] = means[plan.metric].get<double>();
  }
  if (outcome.scores.empty()) {
    outcome.problem = "no model of the race has a mean " + plan.metric;
    return outcome;
  }
  for (const auto& [name, score] : outcome.scores) {
    if (outcome.best.empty() || score > outcome.best_score) {
      outcome.best = name;
      outcome.best_score = score;
    }
  }
  for (const auto& [name, score] : outcome.scores) {
    if (score >= outcome.best_score - plan.margin_db) outcome.winners.insert(name);
  }
  outcome.ok = true;
  return outcome;
}

}  // namespace ibmr
