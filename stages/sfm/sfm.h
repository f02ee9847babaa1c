// Structure from motion through the COLMAP 3.8 command line (CPU only), after seed 000 lines
// 3549-3602 (structure from motion: points in correspondence across images give 3D points and
// camera motion together; calibration matters for a Euclidean result; robust feature tracking is
// needed) and 4830-4860 (§8: pose by structure from motion, RANSAC against outliers; poses are
// poorly determined without wide baselines, hence known intrinsics are held fixed when available).
//
// Steps: feature_extractor -> exhaustive_matcher | sequential_matcher -> mapper -> the largest
// model -> image_registrator (lenient absolute-pose thresholds) + bundle_adjuster for views the
// mapper left out -> model_converter to TXT. When views stay unregistered the whole chain is
// retried with stronger settings (more features, guided exhaustive matching, lower mapper inlier
// thresholds); the best attempt (most registered views) is kept.
//
// This is a driver of an external program, so unlike other stages' pure functions it takes a
// working folder; it reads the images and (optionally) the known intrinsics only, never poses.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "pipeline/core/progress.h"
#include "pipeline/core/sparse_model.h"

namespace ibmr {

enum class SfmMatcher { kExhaustive, kSequential };

struct SfmOptions {
  std::string colmap = "colmap";            // COLMAP executable (name on PATH or path)
  std::string camera_model = "SIMPLE_RADIAL";  // COLMAP model when intrinsics are estimated
  SfmMatcher matcher = SfmMatcher::kExhaustive;
  int max_image_size = 3200;     // pixels; longest side for feature extraction; >= 100
  int max_num_features = 8192;   // SIFT features per image (first attempt; doubled on retries); >= 100
  int max_attempts = 3;          // 1 = no retry; 1..5
  bool register_remaining = true;  // image_registrator pass for views the mapper left out
  // Observations whose reprojection error exceeds this (pixels) are dropped between the mapper's
  // bundle adjustments (COLMAP's Mapper.filter_max_reproj_error, 4 by default). With known
  // intrinsics 1 px pays: on templeSparseRing the median rotation error falls from ~0.3 deg to
  // ~0.12 deg, since the true cameras reproject their own triangulated points at 0.3 px (mean).
  double filter_max_reproj_error = 4.0;  // (0, 100]
  int global_refinements = 5;    // Mapper.ba_global_max_refinements (filter + adjust rounds); 1..100
  int num_threads = -1;          // -1: all cores
  // One camera shared by all photos (COLMAP's ImageReader.single_camera); false when the photos
  // differ in size (COLMAP would skip those of another size) or come from several cameras.
  bool single_camera = true;
  bool Check(std::string* error) const;  // error starts with the YAML key
};

// Known intrinsics held fixed (one camera shared by all images): a COLMAP model name and params.
struct KnownIntrinsics {
  std::string model;            // e.g. "PINHOLE", "OPENCV", "FULL_OPENCV"; empty: estimate
  std::vector<double> params;   // COLMAP order and pixel convention
};

struct SfmStep {
  std::string attempt_step;  // "1/feature_extractor"
  double wall_seconds = 0;
  double peak_memory_mb = 0;
  int exit_code = 0;
};

struct SfmResult {
  SparseModel model;                 // the best model (empty when none)
  std::vector<std::string> registered, unregistered;  // image names
  int num_models = 0;                // models the mapper produced in the best attempt
  int attempts = 0;
  std::string failure;               // why images stay unregistered / no model (empty: all registered)
  std::vector<SfmStep> steps;
  nlohmann::json attempt_summaries = nlohmann::json::array();
  std::map<std::string, int> features_per_image;  // from feature_extractor's output
};

// Runs COLMAP on `image_names` of `image_dir`, working in `work_dir` (database, models) and
// appending COLMAP's output to `log_dir`/sfm_<attempt>_<step>.log. Throws InputError when COLMAP
// is missing or a step fails, with what to install or change.
SfmResult RunColmapSfm(const std::string& image_dir, const std::vector<std::string>& image_names,
                       const KnownIntrinsics& intrinsics, const std::string& work_dir, const std::string& log_dir,
                       const SfmOptions& options, ProgressReporter* progress);

// Known poses (imported cameras): keeps `known`'s cameras and poses and triangulates points from
// COLMAP features and exhaustive matches (feature_extractor -> exhaustive_matcher ->
// point_triangulator, poses and intrinsics held fixed), so that COLMAP's dense tools find the
// views that overlap. Image ids follow the sorted names, as COLMAP numbers the image list it reads.
// Throws InputError when COLMAP fails or numbers the images otherwise.
SfmResult TriangulateKnownPoses(const std::string& image_dir, const SparseModel& known, const std::string& work_dir,
                                const std::string& log_dir, const SfmOptions& options, ProgressReporter* progress);

}  // namespace ibmr
