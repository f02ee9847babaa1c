// COLMAP command-line driver with retries (see sfm.h; seed 000 lines 3549-3602, 4830-4860).
#include "stages/sfm/sfm.h"

#include <spdlog/spdlog.h>
#include <sqlite3.h>

#include <algorithm>
#include <filesystem>
#include <regex>
#include <set>
#include <sstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/child_process.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

bool Fail(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

std::string Join(const std::vector<double>& values) {
  std::ostringstream out;
  out.precision(12);
  for (size_t i = 0; i < values.size(); ++i) out << (i ? "," : "") << values[i];
  return out.str();
}

// Settings of one attempt; later attempts are stronger.
struct Attempt {
  int index = 1;
  int max_num_features = 8192;
  bool guided_matching = false;
  SfmMatcher matcher = SfmMatcher::kExhaustive;
  int init_min_num_inliers = 100;   // COLMAP defaults
  int abs_pose_min_num_inliers = 30;
  double abs_pose_min_inlier_ratio = 0.25;
  bool new_features = true;         // re-extract (feature count changed)
};

Attempt MakeAttempt(int index, const SfmOptions& options) {
  Attempt a;
  a.index = index;
  a.matcher = options.matcher;
  a.max_num_features = options.max_num_features;
  if (index >= 2) {  // more features, guided exhaustive matching, lower inlier thresholds
    a.max_num_features = options.max_num_features * 2;
    a.guided_matching = true;
    a.matcher = SfmMatcher::kExhaustive;
    a.init_min_num_inliers = 50;
    a.abs_pose_min_num_inliers = 15;
    a.abs_pose_min_inlier_ratio = 0.15;
  }
  if (index >= 3) {  // same features, lowest thresholds
    a.init_min_num_inliers = 30;
    a.abs_pose_min_num_inliers = 10;
    a.abs_pose_min_inlier_ratio = 0.1;
    a.new_features = false;
  }
  if (index >= 4) {
    a.max_num_features = options.max_num_features * 4;
    a.new_features = true;
  }
  return a;
}

class ColmapRunner {
 public:
  ColmapRunner(std::string colmap, std::string log_dir, ProgressReporter* progress, SfmResult* result)
      : colmap_(std::move(colmap)), log_dir_(std::move(log_dir)), progress_(progress), result_(result) {}

  // Runs `colmap <command> args...`; progress advances on lines matching `counter` ("[i/N]").
  // Returns false (and keeps the output's tail in *error) when the step fails.
  bool Run(int attempt, const std::string& command, std::vector<std::string> args, const std::string& phase,
           size_t total, const std::regex& counter, std::string* error) {
    args.insert(args.begin(), {colmap_, command});
    const std::string log_path = log_dir_ + "/sfm_" + std::to_string(attempt) + "_" + command + ".log";
    std::error_code ec;
    fs::remove(log_path, ec);
    progress_->Begin("attempt " + std::to_string(attempt) + ": " + phase, total);
    size_t done = 0;
    std::string current_name;
    const std::regex name_line(R"(^\s*Name:\s*(\S+))"), features_line(R"(^\s*Features:\s*(\d+))");
    const ProcessResult process = RunProcess(args, log_path, [&](const std::string& line) {
      std::smatch m;
      if (std::regex_search(line, m, name_line)) current_name = m[1];
      if (std::regex_search(line, m, features_line) && !current_name.empty()) {
        result_->features_per_image[current_name] = std::stoi(m[1]);
      }
      if (std::regex_search(line, m, counter) && m.size() > 1 && m[1].matched) {
        const size_t value = std::stoul(m[1]);
        if (value > done && value <= total) {
          progress_->Advance(value - done, "");
          done = value;
        }
      }
      if (line.find("No good initial image pair found") != std::string::npos) no_initial_pair_ = true;
    }, {"QT_QPA_PLATFORM=offscreen"});  // COLMAP 3.8 runs headless
    progress_->End();
    result_->steps.push_back({std::to_string(attempt) + "/" + command, process.wall_seconds, process.peak_memory_mb,
                              process.exit_code});
    if (process.exit_code != 0) {
      *error = "colmap " + command + " failed (exit " + std::to_string(process.exit_code) + "; log " + log_path +
               "):\n" + process.last_lines;
      return false;
    }
    return true;
  }

  bool no_initial_pair() const { return no_initial_pair_; }

 private:
  std::string colmap_, log_dir_;
  ProgressReporter* progress_;
  SfmResult* result_;
  bool no_initial_pair_ = false;
};

// Image name -> (image id, camera id) in a COLMAP database.
std::map<std::string, std::pair<int, int>> DatabaseImageIds(const std::string& path) {
  sqlite3* db = nullptr;
  if (sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
    const std::string message = db ? sqlite3_errmsg(db) : "out of memory";
    sqlite3_close(db);
    throw IoError(path + ": cannot open COLMAP's database: " + message);
  }
  std::map<std::string, std::pair<int, int>> ids;
  sqlite3_stmt* query = nullptr;
  if (sqlite3_prepare_v2(db, "SELECT image_id, camera_id, name FROM images", -1, &query, nullptr) == SQLITE_OK) {
    while (sqlite3_step(query) == SQLITE_ROW) {
      const unsigned char* name = sqlite3_column_text(query, 2);
      if (name) ids[reinterpret_cast<const char*>(name)] = {sqlite3_column_int(query, 0), sqlite3_column_int(query, 1)};
    }
  }
  const std::string message = sqlite3_errmsg(db);
  sqlite3_finalize(query);
  sqlite3_close(db);
  if (ids.empty()) throw IoError(path + ": no images in COLMAP's database (" + message + ")");
  return ids;
}

// Converts a binary model folder to TXT and reads it.
bool ReadColmapModel(ColmapRunner* runner, int attempt, const std::string& bin_dir, const std::string& txt_dir,
                     SparseModel* model, std::string* error) {
  fs::create_directories(txt_dir);
  if (!runner->Run(attempt, "model_converter",
                   {"--input_path", bin_dir, "--output_path", txt_dir, "--output_type", "TXT"}, "model_converter", 1,
                   std::regex("^$"), error)) {
    return false;
  }
  *model = ReadSparseModelText(txt_dir);
  return true;
}

std::vector<std::string> FixedIntrinsicsArgs(const KnownIntrinsics& intrinsics) {
  if (intrinsics.model.empty()) return {};
  return {"--Mapper.ba_refine_focal_length", "0", "--Mapper.ba_refine_principal_point", "0",
          "--Mapper.ba_refine_extra_params", "0"};
}

std::vector<std::string> FilterArgs(const SfmOptions& options) {
  std::ostringstream error;
  error << options.filter_max_reproj_error;
  return {"--Mapper.filter_max_reproj_error", error.str(), "--Mapper.ba_global_max_refinements",
          std::to_string(options.global_refinements)};
}

// One full attempt. Returns the model with the most registered images (empty when none).
SparseModel RunAttempt(const Attempt& a, const std::string& image_dir, const std::vector<std::string>& names,
                       const KnownIntrinsics& intrinsics, const std::string& work_dir, const SfmOptions& options,
                       ColmapRunner* runner, int* num_models, std::string* note) {
  const std::string database = work_dir + "/database.db";
  const std::string threads = std::to_string(options.num_threads);
  const size_t n = names.size();
  std::string error;
  if (a.new_features) {
    fs::remove(database);
    std::vector<std::string> args = {"--database_path", database, "--image_path", image_dir, "--image_list_path",
                                     work_dir + "/image_list.txt", "--ImageReader.single_camera",
                                     options.single_camera || !intrinsics.model.empty() ? "1" : "0",
                                     "--SiftExtraction.use_gpu", "0", "--SiftExtraction.num_threads", threads,
                                     "--SiftExtraction.max_image_size", std::to_string(options.max_image_size),
                                     "--SiftExtraction.max_num_features", std::to_string(a.max_num_features)};
    if (!intrinsics.model.empty()) {
      args.insert(args.end(), {"--ImageReader.camera_model", intrinsics.model, "--ImageReader.camera_params",
                               Join(intrinsics.params)});
    } else {
      args.insert(args.end(), {"--ImageReader.camera_model", options.camera_model});
    }
    if (!runner->Run(a.index, "feature_extractor", args, "feature extraction", n, std::regex(R"(\[(\d+)/\d+\])"), &error)) {
      throw InputError("sfm: " + error + "\nCheck the images and sfm.max_image_size / sfm.max_num_features.");
    }
    std::vector<std::string> match = {"--database_path", database, "--SiftMatching.use_gpu", "0",
                                      "--SiftMatching.num_threads", threads, "--SiftMatching.guided_matching",
                                      a.guided_matching ? "1" : "0"};
    const bool exhaustive = a.matcher == SfmMatcher::kExhaustive;
    const size_t blocks = exhaustive ? 1 : n;
    if (!runner->Run(a.index, exhaustive ? "exhaustive_matcher" : "sequential_matcher", match, "matching", blocks,
                     std::regex(exhaustive ? R"(^$)" : R"(\[(\d+)/\d+\])"), &error)) {
      throw InputError("sfm: " + error);
    }
  }
  const std::string sparse_bin = work_dir + "/attempt_" + std::to_string(a.index);
  fs::remove_all(sparse_bin);
  fs::create_directories(sparse_bin);
  std::vector<std::string> mapper = {"--database_path", database, "--image_path", image_dir, "--output_path", sparse_bin,
                                     "--Mapper.num_threads", threads,
                                     // COLMAP drops models under 10 images; small sets need less.
                                     "--Mapper.min_model_size", std::to_string(std::clamp<int>(static_cast<int>(n) / 2, 3, 10)),
                                     "--Mapper.init_min_num_inliers", std::to_string(a.init_min_num_inliers),
                                     "--Mapper.abs_pose_min_num_inliers", std::to_string(a.abs_pose_min_num_inliers),
                                     "--Mapper.abs_pose_min_inlier_ratio", std::to_string(a.abs_pose_min_inlier_ratio)};
  for (const std::string& s : FixedIntrinsicsArgs(intrinsics)) mapper.push_back(s);
  for (const std::string& s : FilterArgs(options)) mapper.push_back(s);
  // "Registering image #12 (5)": the running count of registered images.
  if (!runner->Run(a.index, "mapper", mapper, "mapping (registered views)", n, std::regex(R"(Registering image #\d+ \((\d+)\))"),
                   &error)) {
    *note = runner->no_initial_pair()
                ? "COLMAP's mapper found no initial image pair with enough geometrically verified matches (too few "
                  "features or matches: untextured scene?); see logs/sfm_" + std::to_string(a.index) + "_mapper.log"
                : error;
    return {};
  }
  // Largest model.
  SparseModel best;
  std::string best_dir;
  *num_models = 0;
  for (const auto& entry : fs::directory_iterator(sparse_bin)) {
    if (!entry.is_directory() || !fs::exists(entry.path() / "images.bin")) continue;
    ++*num_models;
    SparseModel model;
    if (!ReadColmapModel(runner, a.index, entry.path().string(), entry.path().string() + "_txt", &model, &error)) continue;
    if (model.images.size() > best.images.size()) {
      best = std::move(model);
      best_dir = entry.path().string();
    }
  }
  if (best.images.empty()) {
    *note = runner->no_initial_pair() ? "COLMAP's mapper found no initial image pair with enough geometrically verified "
                                        "matches (too few features or matches: untextured scene?)"
                                      : "COLMAP's mapper produced no model";
    return {};
  }
  if (options.register_remaining && best.images.size() < n) {
    // Register the remaining views into the largest model with lenient absolute-pose thresholds,
    // triangulate their points and refine everything by bundle adjustment.
    const std::string reg = sparse_bin + "/registered", tri = sparse_bin + "/triangulated", ba = sparse_bin + "/adjusted";
    for (const std::string& d : {reg, tri, ba}) fs::create_directories(d);
    std::vector<std::string> args = {"--database_path", database, "--input_path", best_dir, "--output_path", reg,
                                     "--Mapper.abs_pose_min_num_inliers", "10", "--Mapper.abs_pose_min_inlier_ratio", "0.05",
                                     "--Mapper.abs_pose_max_error", "16"};
    for (const std::string& s : FixedIntrinsicsArgs(intrinsics)) args.push_back(s);
    for (const std::string& s : FilterArgs(options)) args.push_back(s);
    std::vector<std::string> tri_args = {"--database_path", database, "--image_path", image_dir, "--input_path", reg,
                                         "--output_path", tri};
    for (const std::string& s : FixedIntrinsicsArgs(intrinsics)) tri_args.push_back(s);
    for (const std::string& s : FilterArgs(options)) tri_args.push_back(s);
    std::vector<std::string> ba_args = {"--input_path", tri, "--output_path", ba};
    if (!intrinsics.model.empty()) {
      ba_args.insert(ba_args.end(), {"--BundleAdjustment.refine_focal_length", "0",
                                     "--BundleAdjustment.refine_principal_point", "0",
                                     "--BundleAdjustment.refine_extra_params", "0"});
    }
    SparseModel registered;
    if (runner->Run(a.index, "image_registrator", args, "registering remaining views", 1, std::regex("^$"), &error) &&
        runner->Run(a.index, "point_triangulator", tri_args, "triangulating", 1, std::regex("^$"), &error) &&
        runner->Run(a.index, "bundle_adjuster", ba_args, "bundle adjustment", 1, std::regex("^$"), &error) &&
        ReadColmapModel(runner, a.index, ba, ba + "_txt", &registered, &error) &&
        registered.images.size() >= best.images.size()) {
      best = std::move(registered);
    } else if (!error.empty()) {
      spdlog::warn("[sfm] registering the remaining views failed: {}", error);
    }
  }
  return best;
}

}  // namespace

bool SfmOptions::Check(std::string* error) const {
  if (colmap.empty()) return Fail(error, "colmap: must name the COLMAP executable");
  if (max_image_size < 100) return Fail(error, "max_image_size: must be >= 100, got " + std::to_string(max_image_size));
  if (max_num_features < 100) return Fail(error, "max_num_features: must be >= 100, got " + std::to_string(max_num_features));
  if (!(filter_max_reproj_error > 0 && filter_max_reproj_error <= 100)) {
    return Fail(error, "filter_max_reproj_error: must be in (0, 100] pixels, got " + std::to_string(filter_max_reproj_error));
  }
  if (global_refinements < 1 || global_refinements > 100) {
    return Fail(error, "global_refinements: must be in 1..100, got " + std::to_string(global_refinements));
  }
  if (max_attempts < 1 || max_attempts > 5) return Fail(error, "max_attempts: must be in 1..5, got " + std::to_string(max_attempts));
  if (num_threads == 0 || num_threads < -1) return Fail(error, "num_threads: must be -1 (all) or > 0, got " + std::to_string(num_threads));
  static const std::set<std::string> kModels = {"SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV"};
  if (!kModels.count(camera_model)) return Fail(error, "camera_model: unknown COLMAP camera model '" + camera_model + "'");
  return true;
}

SfmResult TriangulateKnownPoses(const std::string& image_dir, const SparseModel& known, const std::string& work_dir,
                                const std::string& log_dir, const SfmOptions& options, ProgressReporter* progress) {
  NullProgress null_progress;
  if (!progress) progress = &null_progress;
  const std::string colmap = FindExecutable(options.colmap);
  if (colmap.empty()) throw InputError("sfm.colmap: the COLMAP executable '" + options.colmap + "' was not found on PATH");
  if (known.images.empty()) throw InputError("sfm.known_poses: the input model has no posed images");
  fs::remove_all(work_dir);
  fs::create_directories(work_dir);
  fs::create_directories(log_dir);
  // One camera for all when the known cameras agree (held at their values), else one per image.
  const std::vector<int> order = known.ImageIdsByName();
  const Camera& first = known.CameraOf(known.images.at(order.front()));
  bool shared = true;
  std::string list;
  for (int id : order) {
    const Camera& camera = known.CameraOf(known.images.at(id));
    shared &= camera.model == first.model && camera.params == first.params && camera.width == first.width &&
              camera.height == first.height;
    list += known.images.at(id).name + "\n";
  }
  WriteFileAtomic(work_dir + "/image_list.txt", list);
  const std::string known_dir = work_dir + "/known", triangulated = work_dir + "/triangulated";
  fs::create_directories(triangulated);

  SfmResult result;
  result.attempts = 1;
  ColmapRunner runner(colmap, log_dir, progress, &result);
  const std::string database = work_dir + "/database.db", threads = std::to_string(options.num_threads);
  std::vector<std::string> extract = {"--database_path", database, "--image_path", image_dir, "--image_list_path",
                                      work_dir + "/image_list.txt", "--ImageReader.single_camera", shared ? "1" : "0",
                                      "--ImageReader.camera_model", CameraModelName(first.model),
                                      "--SiftExtraction.use_gpu", "0", "--SiftExtraction.num_threads", threads,
                                      "--SiftExtraction.max_image_size", std::to_string(options.max_image_size),
                                      "--SiftExtraction.max_num_features", std::to_string(options.max_num_features)};
  if (shared) extract.insert(extract.end(), {"--ImageReader.camera_params", Join(first.params)});
  std::string error;
  const size_t n = order.size();
  if (!runner.Run(1, "feature_extractor", extract, "feature extraction", n, std::regex(R"(\[(\d+)/\d+\])"), &error)) {
    throw InputError("sfm: " + error);
  }
  // The known model under the ids COLMAP's database gave the images (the order extraction finished).
  const std::map<std::string, std::pair<int, int>> ids = DatabaseImageIds(database);
  SparseModel input;
  for (int id : order) {
    Image image = known.images.at(id);
    const auto it = ids.find(image.name);
    if (it == ids.end()) throw InputError("sfm: COLMAP's feature_extractor did not read " + image.name + "; see " + log_dir);
    Camera camera = known.CameraOf(image);
    image.image_id = it->second.first;
    image.camera_id = camera.camera_id = it->second.second;
    image.points2D.clear();
    input.cameras[camera.camera_id] = camera;
    input.images[image.image_id] = image;
  }
  WriteSparseModelText(known_dir, input);
  if (!runner.Run(1, "exhaustive_matcher",
                  {"--database_path", database, "--SiftMatching.use_gpu", "0", "--SiftMatching.num_threads", threads},
                  "matching", 1, std::regex("^$"), &error) ||
      !runner.Run(1, "point_triangulator",
                  {"--database_path", database, "--image_path", image_dir, "--input_path", known_dir, "--output_path",
                   triangulated, "--Mapper.ba_refine_focal_length", "0", "--Mapper.ba_refine_principal_point", "0",
                   "--Mapper.ba_refine_extra_params", "0"},
                  "triangulating", 1, std::regex("^$"), &error) ||
      !ReadColmapModel(&runner, 1, triangulated, triangulated + "_txt", &result.model, &error)) {
    throw InputError("sfm: " + error);
  }
  // The poses must come back as they went in: otherwise COLMAP numbered the images differently.
  for (const auto& [id, image] : result.model.images) {
    const Image* original = known.FindImage(image.name);
    if (original == nullptr ||
        (image.cam_from_world.translation - original->cam_from_world.translation).norm() >
            1e-6 * (1 + original->cam_from_world.translation.norm())) {
      throw InputError("sfm.known_poses: COLMAP returned another pose for " + image.name +
                       " (its database numbers the images otherwise); see " + log_dir);
    }
  }
  for (const auto& [id, image] : known.images) result.registered.push_back(image.name);
  std::sort(result.registered.begin(), result.registered.end());
  result.num_models = 1;
  return result;
}

SfmResult RunColmapSfm(const std::string& image_dir, const std::vector<std::string>& image_names,
                       const KnownIntrinsics& intrinsics, const std::string& work_dir, const std::string& log_dir,
                       const SfmOptions& options, ProgressReporter* progress) {
  NullProgress null_progress;
  if (!progress) progress = &null_progress;
  const std::string colmap = FindExecutable(options.colmap);
  if (colmap.empty()) {
    throw InputError("sfm.colmap: the COLMAP executable '" + options.colmap +
                     "' was not found on PATH; install it (Debian: apt-get install --no-install-recommends colmap) "
                     "or set sfm.colmap to its path");
  }
  if (image_names.empty()) throw InputError("sfm: no images to reconstruct (run import first)");
  fs::create_directories(work_dir);
  fs::create_directories(log_dir);
  std::string list;
  for (const std::string& name : image_names) list += name + "\n";
  WriteFileAtomic(work_dir + "/image_list.txt", list);

  SfmResult result;
  ColmapRunner runner(colmap, log_dir, progress, &result);
  for (int index = 1; index <= options.max_attempts; ++index) {
    const Attempt attempt = MakeAttempt(index, options);
    int num_models = 0;
    std::string note;
    SparseModel model = RunAttempt(attempt, image_dir, image_names, intrinsics, work_dir, options, &runner, &num_models, &note);
    result.attempts = index;
    result.attempt_summaries.push_back({{"attempt", index}, {"max_num_features", attempt.max_num_features},
                                        {"guided_matching", attempt.guided_matching},
                                        {"init_min_num_inliers", attempt.init_min_num_inliers},
                                        {"abs_pose_min_num_inliers", attempt.abs_pose_min_num_inliers},
                                        {"models", num_models}, {"registered", model.images.size()}, {"note", note}});
    spdlog::info("[sfm] attempt {}: {} models, {} of {} views registered{}", index, num_models, model.images.size(),
                 image_names.size(), note.empty() ? "" : " (" + note + ")");
    if (model.images.size() > result.model.images.size()) {
      result.model = std::move(model);
      result.num_models = num_models;
    }
    if (result.model.images.size() == image_names.size()) break;
    if (result.failure.empty() || !note.empty()) result.failure = note;
  }
  std::set<std::string> registered;
  for (const auto& [id, image] : result.model.images) registered.insert(image.name);
  for (const std::string& name : image_names) {
    (registered.count(name) ? result.registered : result.unregistered).push_back(name);
  }
  if (!result.unregistered.empty() && result.failure.empty()) {
    result.failure = "COLMAP could not register these views after " + std::to_string(result.attempts) +
                     " attempts (too few verified 2D-3D matches)";
  }
  if (result.unregistered.empty()) result.failure.clear();
  return result;
}

}  // namespace ibmr
