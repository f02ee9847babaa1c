// Two-view layered stereo (layered_pair.h): option checks, the steps in order (disparity planes:
// disparity_planes.h; costs per layer: layer_costs.h; Potts assignment with occlusion reasoning:
// layer_labels.h), step 5's output disparity, and the two-view method "layered" with its options.
// Follows seed 000 lines 5625-5811 and 3798-3846, as layered_pair.h details.
#include "stages/layered_stereo/layered_pair.h"

#include <tbb/enumerable_thread_specific.h>

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "stages/layered_stereo/disparity_planes.h"
#include "stages/layered_stereo/layer_costs.h"
#include "stages/layered_stereo/layer_labels.h"
#include "stages/layered_stereo/layered_pair_internal.h"

namespace ibmr {

using layered_internal::AllLayerCosts;
using layered_internal::ApplyOcclusion;
using layered_internal::AssignLabels;
using layered_internal::Census;
using layered_internal::EdgePenalties;
using layered_internal::FindPlanes;
using layered_internal::Holes;
using layered_internal::kOcclusionMargin;
using layered_internal::LayerScratch;
using layered_internal::MakePrior;
using layered_internal::MatchInput;
using layered_internal::Prior;
using layered_internal::RefitPlanes;
using layered_internal::RightZBuffer;
using layered_internal::RoundToInt;

bool LayeredPairOptions::Check(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error != nullptr) *error = message;
    return false;
  };
  auto in = [](double v, double lo, double hi) { return v >= lo && v <= hi; };  // false for NaN
  if (max_layers < 1 || max_layers > 64) return fail("max_layers = " + std::to_string(max_layers) + ": must be in [1, 64]");
  if (!(inlier_tolerance > 0 && inlier_tolerance <= 16))
    return fail("inlier_tolerance = " + std::to_string(inlier_tolerance) + ": must be in (0, 16] pixels");
  if (!(min_layer_fraction > 0 && min_layer_fraction < 1))
    return fail("min_layer_fraction = " + std::to_string(min_layer_fraction) + ": must be in (0, 1)");
  if (ransac_iterations < 1 || ransac_iterations > 100000)
    return fail("ransac_iterations = " + std::to_string(ransac_iterations) + ": must be in [1, 100000]");
  if (sample_radius < 2 || sample_radius > 4096)
    return fail("sample_radius = " + std::to_string(sample_radius) + ": must be in [2, 4096] pixels");
  if (!(loss_scale > 0 && loss_scale <= 16)) return fail("loss_scale = " + std::to_string(loss_scale) + ": must be in (0, 16] pixels");
  if (residual_range < 0 || residual_range > 16)
    return fail("residual_range = " + std::to_string(residual_range) + ": must be in [0, 16] pixels");
  if (!in(residual_penalty, 0, 1e6)) return fail("residual_penalty = " + std::to_string(residual_penalty) + ": must be >= 0");
  if (window_radius < 0 || window_radius > 10)
    return fail("window_radius = " + std::to_string(window_radius) + ": must be in [0, 10] pixels");
  if (!in(initial_weight, 0, 1e6)) return fail("initial_weight = " + std::to_string(initial_weight) + ": must be >= 0");
  if (!(initial_truncation > 0 && initial_truncation <= 1e6))
    return fail("initial_truncation = " + std::to_string(initial_truncation) + ": must be > 0 pixels");
  if (!in(smoothness, 0, 1e6)) return fail("smoothness = " + std::to_string(smoothness) + ": must be >= 0");
  if (!in(edge_threshold, 0, 1e6)) return fail("edge_threshold = " + std::to_string(edge_threshold) + ": must be >= 0");
  if (!in(edge_factor, 0, 1)) return fail("edge_factor = " + std::to_string(edge_factor) + ": must be in [0, 1]");
  if (!in(occlusion_cost, 0, 1e6)) return fail("occlusion_cost = " + std::to_string(occlusion_cost) + ": must be >= 0");
  if (refinement_passes < 0 || refinement_passes > 5)
    return fail("refinement_passes = " + std::to_string(refinement_passes) + ": must be in [0, 5]");
  return true;
}

namespace {

cv::Mat ToGray(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat gray;
  cv::cvtColor(image, gray, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  return gray;
}

void CheckInputs(const cv::Mat& left, const cv::Mat& right, const cv::Mat& initial_disparity, int max_disparity,
                 const LayeredPairOptions& options) {
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument("LayeredStereoPair: " + error);
  if (left.empty() || left.size() != right.size() || left.type() != right.type() || left.depth() != CV_8U) {
    throw std::invalid_argument("LayeredStereoPair: left and right must be 8-bit images of one size and type");
  }
  if (initial_disparity.size() != left.size() || initial_disparity.type() != CV_32F) {
    throw std::invalid_argument("LayeredStereoPair: the initial disparity must be CV_32F of the images' size");
  }
  if (max_disparity < 1) throw std::invalid_argument("LayeredStereoPair: max_disparity must be >= 1");
}

// Step 5's output: per pixel the disparity of its layer (plane + residual); the plane alone where the
// pixel is occluded under it (no match to refine by). Counts each layer's pixels into `support`.
cv::Mat OutputDisparity(const cv::Mat& labels, const std::vector<DisparityPlane>& planes,
                        const std::vector<float>& disparity, const std::vector<uint8_t>& hole, const cv::Mat& zbuffer,
                        int max_disparity, std::vector<size_t>* support) {
  const int w = labels.cols, h = labels.rows;
  const size_t n = static_cast<size_t>(w) * h;
  cv::Mat out(h, w, CV_32F);
  support->assign(planes.size(), 0);
  for (int y = 0; y < h; ++y) {
    const int* label = labels.ptr<int>(y);
    const float* z = zbuffer.ptr<float>(y);
    float* row = out.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const float plane = static_cast<float>(planes[label[x]].Disparity(x, y));
      const int xr = RoundToInt(x - plane);
      const bool occluded = xr < 0 || xr >= w || (hole[i] && z[xr] > plane + kOcclusionMargin);
      const float d = occluded ? plane : disparity[label[x] * n + i];
      // Disparity 0 is an answer, but "<= 0" means none in the output (as plane_sweep's).
      row[x] = std::clamp(d, 1e-3f, static_cast<float>(std::max(1, max_disparity - 1)));
      ++(*support)[label[x]];
    }
  }
  return out;
}

// Drops the layers no pixel chose and renumbers the labels; support = pixels assigned.
void DropUnusedLayers(const std::vector<size_t>& support, std::vector<DisparityPlane>* planes, cv::Mat* labels) {
  std::vector<int> renumber(planes->size(), -1);
  std::vector<DisparityPlane> kept;
  for (size_t l = 0; l < planes->size(); ++l) {
    if (support[l] == 0) continue;
    renumber[l] = static_cast<int>(kept.size());
    kept.push_back((*planes)[l]);
    kept.back().support = support[l];
  }
  for (int y = 0; y < labels->rows; ++y) {
    int* label = labels->ptr<int>(y);
    for (int x = 0; x < labels->cols; ++x) label[x] = renumber[label[x]];
  }
  *planes = std::move(kept);
}

}  // namespace

LayeredPairResult LayeredStereoPair(const cv::Mat& left_image, const cv::Mat& right_image,
                                    const cv::Mat& initial_disparity, int max_disparity,
                                    const LayeredPairOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  CheckInputs(left_image, right_image, initial_disparity, max_disparity, options);
  const int w = left_image.cols, h = left_image.rows;
  LayeredPairResult result;
  result.planes = FindPlanes(initial_disparity, options);  // steps 2 and 3

  MatchInput match;
  match.width = w, match.height = h;
  match.left = Census(ToGray(left_image));
  match.right = Census(ToGray(right_image));
  const std::vector<uint8_t> hole = Holes(initial_disparity);
  const Prior prior = MakePrior(initial_disparity, hole, options.initial_weight);
  const cv::Mat zbuffer = RightZBuffer(initial_disparity, hole);
  std::vector<float> right_penalty, down_penalty;
  EdgePenalties(left_image, options, &right_penalty, &down_penalty);

  std::vector<float> layer_cost, cost, disparity;
  tbb::enumerable_thread_specific<LayerScratch> scratch;
  cv::Mat labels;
  for (int pass = 0; pass <= options.refinement_passes; ++pass) {  // step 4 (and 5's refits)
    AllLayerCosts(match, result.planes, prior, options, &scratch, &layer_cost, &cost, &disparity);
    ApplyOcclusion(hole, zbuffer, result.planes, static_cast<float>(options.occlusion_cost), &cost);
    // The layer-major costs are spent: their memory holds the assignment's sums (no fresh pages).
    AssignLabels(cost, static_cast<int>(result.planes.size()), w, h, right_penalty, down_penalty, &layer_cost,
                 &labels);
    if (pass < options.refinement_passes) RefitPlanes(labels, disparity, hole, options, &result.planes);
  }
  std::vector<size_t> support;
  result.disparity = OutputDisparity(labels, result.planes, disparity, hole, zbuffer, max_disparity, &support);
  DropUnusedLayers(support, &result.planes, &labels);
  result.labels = labels;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

namespace {

int ParseInt(const std::string& key, const std::string& value) {
  size_t used = 0;
  long parsed = 0;
  try {
    parsed = std::stol(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.size() || parsed < std::numeric_limits<int>::min() ||
      parsed > std::numeric_limits<int>::max()) {
    throw std::invalid_argument("layered two-view option " + key + ": expected an integer, got '" + value + "'");
  }
  return static_cast<int>(parsed);
}

double ParseDouble(const std::string& key, const std::string& value) {
  size_t used = 0;
  double parsed = 0;
  try {
    parsed = std::stod(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.size()) {
    throw std::invalid_argument("layered two-view option " + key + ": expected a number, got '" + value + "'");
  }
  return parsed;
}

bool ParseBool(const std::string& key, const std::string& value) {
  if (value == "true") return true;
  if (value == "false") return false;
  throw std::invalid_argument("layered two-view option " + key + ": expected true or false, got '" + value + "'");
}

LayeredPairOptions ParseOptions(const TwoViewOptions& given) {
  LayeredPairOptions options;
  for (const auto& [key, value] : given) {
    if (key == "max_layers") options.max_layers = ParseInt(key, value);
    else if (key == "inlier_tolerance") options.inlier_tolerance = ParseDouble(key, value);
    else if (key == "min_layer_fraction") options.min_layer_fraction = ParseDouble(key, value);
    else if (key == "ransac_iterations") options.ransac_iterations = ParseInt(key, value);
    else if (key == "sample_radius") options.sample_radius = ParseInt(key, value);
    else if (key == "seed") options.seed = static_cast<uint32_t>(ParseInt(key, value));
    else if (key == "loss_scale") options.loss_scale = ParseDouble(key, value);
    else if (key == "residual_range") options.residual_range = ParseInt(key, value);
    else if (key == "residual_penalty") options.residual_penalty = ParseDouble(key, value);
    else if (key == "window_radius") options.window_radius = ParseInt(key, value);
    else if (key == "initial_weight") options.initial_weight = ParseDouble(key, value);
    else if (key == "initial_truncation") options.initial_truncation = ParseDouble(key, value);
    else if (key == "smoothness") options.smoothness = ParseDouble(key, value);
    else if (key == "edge_threshold") options.edge_threshold = ParseDouble(key, value);
    else if (key == "edge_factor") options.edge_factor = ParseDouble(key, value);
    else if (key == "occlusion_cost") options.occlusion_cost = ParseDouble(key, value);
    else if (key == "refinement_passes") options.refinement_passes = ParseInt(key, value);
    else if (key == "subpixel") options.subpixel = ParseBool(key, value);
    else throw std::invalid_argument("layered two-view: unknown option '" + key + "'");
  }
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument("layered two-view option " + error);
  return options;
}

}  // namespace

TwoViewOutput LayeredTwoView(const cv::Mat& left, const cv::Mat& right, int max_disparity,
                             const TwoViewOptions& given) {
  const LayeredPairOptions options = ParseOptions(given);  // before any work: bad options fail fast
  const TwoViewMethod plane_sweep = FindTwoViewMethod("plane_sweep");
  if (!plane_sweep) {
    throw std::runtime_error(
        "layered two-view: the initial disparity needs the \"plane_sweep\" two-view method, which no stage "
        "registered (register the plane_sweep stage first)");
  }
  const auto start = std::chrono::steady_clock::now();
  const TwoViewOutput initial = plane_sweep(left, right, max_disparity, {{"fill", "false"}});
  const double initial_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const LayeredPairResult result = LayeredStereoPair(left, right, initial.disparity, max_disparity, options);
  nlohmann::json planes = nlohmann::json::array();
  for (const DisparityPlane& p : result.planes) planes.push_back({{"a", p.a}, {"b", p.b}, {"c", p.c}, {"pixels", p.support}});
  TwoViewOutput output;
  output.disparity = result.disparity;
  output.facts = {{"layers", result.planes.size()}, {"planes", planes}, {"initial_seconds", initial_seconds},
                  {"layered_seconds", result.seconds}, {"seconds", initial_seconds + result.seconds}};
  return output;
}

}  // namespace ibmr
