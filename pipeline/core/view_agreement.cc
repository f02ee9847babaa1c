// Robust z-scores of per-view figures and the flag of the views that stand out (issue 67;
// Iglewicz & Hoaglin 1993). See view_agreement.h.
#include "pipeline/core/view_agreement.h"

#include <algorithm>
#include <limits>
#include <cmath>
#include <cstdio>

#include "pipeline/core/json_file.h"
#include "pipeline/core/median.h"

namespace ibmr {

namespace {

// The MAD of a Gaussian sample times this estimates its standard deviation (1 / Phi^-1(3/4)).
constexpr double kMadToSigma = 1.4826;

std::string Format(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

}  // namespace

bool ViewFlagOptions::Check(std::string* error) const {
  if (!(z_threshold > 0)) {
    *error = "view_flag_z: must be > 0, got " + std::to_string(z_threshold);
    return false;
  }
  if (!(min_scale >= 0)) {
    *error = "view_flag_min_scale: must be >= 0, got " + std::to_string(min_scale);
    return false;
  }
  if (min_views < 3) {
    *error = "view_flag_min_views: must be >= 3, got " + std::to_string(min_views);
    return false;
  }
  return true;
}

RobustScores RobustZScores(const std::vector<double>& values, double min_scale) {
  RobustScores scores;
  if (values.empty()) return scores;
  scores.median = Median(values);
  std::vector<double> deviations;
  deviations.reserve(values.size());
  for (double v : values) deviations.push_back(std::abs(v - scores.median));
  scores.mad = Median(deviations);
  scores.scale = std::max(kMadToSigma * scores.mad, min_scale);
  for (double v : values) scores.z.push_back(scores.scale > 0 ? (v - scores.median) / scores.scale : 0.0);
  return scores;
}

ViewFlagResult FlagViews(std::vector<ViewAgreement> views, bool higher_is_better, const ViewFlagOptions& options) {
  ViewFlagResult result;
  result.views = std::move(views);
  std::vector<double> figures;
  for (const ViewAgreement& v : result.views) {
    if (v.has_figure) figures.push_back(v.figure);
  }
  result.scored = figures.size();
  result.scores = RobustZScores(figures, options.min_scale);
  const bool enough = static_cast<int>(figures.size()) >= options.min_views;
  result.capture_poor = higher_is_better && enough && options.min_median > 0 && result.scores.median < options.min_median;
  size_t k = 0;
  for (ViewAgreement& v : result.views) {
    v.flagged = false;
    if (!v.has_figure) continue;
    v.z = result.scores.z[k++];
    const double bad_side = higher_is_better ? -v.z : v.z;
    if (enough && bad_side > options.z_threshold) {
      v.flagged = true;
      result.flagged.push_back(v.name);
    }
  }
  return result;
}

std::string ViewFlagMessage(const ViewFlagResult& result, const std::string& figure_name, const ViewFlagOptions& options) {
  if (result.scored == 0) {
    return "no view could be checked against the others: " + std::to_string(result.views.size()) +
           " views, none with depth samples a neighbour sees (no neighbours within the view angle, or empty depth maps); "
           "check the earlier stages' outputs";
  }
  if (static_cast<int>(result.scored) < options.min_views) {
    return "too few views to tell whether one stands out: " + std::to_string(result.scored) + " with a " + figure_name +
           ", at least " + std::to_string(options.min_views) + " needed";
  }
  const std::string centre = figure_name + " median " + Format("%.3f", result.scores.median) + ", robust scale " +
                             Format("%.3f", result.scores.scale);
  if (result.flagged.empty()) {
    return "no view stands out (" + centre + ", z threshold " + Format("%.1f", options.z_threshold) + ")";
  }
  std::string names;
  for (const ViewAgreement& v : result.views) {
    if (!v.flagged) continue;
    if (!names.empty()) names += ", ";
    names += v.name + " (" + Format("%.3f", v.figure) + ", z " + Format("%.1f", v.z) + ")";
  }
  return std::to_string(result.flagged.size()) + " view(s) disagree with the others (a wrong camera pose, or a photo the matcher "
         "fails on): " + names + "; " + centre + ". Check these photos' cameras (the lowest first: its error can damage "
         "others through the hull), or leave them out";
}

std::string CaptureAgreementMessage(const ViewFlagResult& result, const std::string& figure_name, const ViewFlagOptions& options) {
  if (!result.capture_poor) return "";
  return "the views agree poorly as a whole: " + figure_name + " median " + Format("%.3f", result.scores.median) + " < " +
         Format("%.2f", options.min_median) + ": every camera may be off alike (no single view "
         "stands out), or the photos defeat the matcher; check the poses (sfm, calibration)";
}

nlohmann::json ViewAgreementJson(const ViewFlagResult& result, const std::string& figure_description, bool higher_is_better,
                                 const ViewFlagOptions& options) {
  nlohmann::json views = nlohmann::json::array();
  for (const ViewAgreement& v : result.views) {
    nlohmann::json entry = {{"name", v.name}};
    entry["figure"] = v.has_figure ? nlohmann::json(v.figure) : nlohmann::json();
    entry["z"] = v.has_figure ? nlohmann::json(v.z) : nlohmann::json();
    entry["flagged"] = v.flagged;
    for (const auto& [key, value] : v.extra.items()) entry[key] = value;
    views.push_back(std::move(entry));
  }
  return {{"figure", figure_description},
          {"higher_is_better", higher_is_better},
          {"median", result.scores.median},
          {"mad", result.scores.mad},
          {"scale", result.scores.scale},
          {"z_threshold", options.z_threshold},
          {"min_scale", options.min_scale},
          {"min_views", options.min_views},
          {"min_median", options.min_median},
          {"capture_poor", result.capture_poor},
          {"scored", result.scored},
          {"views", std::move(views)},
          {"flagged", result.flagged}};
}

ViewFlagScore ScoreViewFlags(const ViewFlagResult& result, const std::map<std::string, double>& displacement_px,
                             double wrong_px) {
  ViewFlagScore score;
  for (const ViewAgreement& view : result.views) {
    const auto it = displacement_px.find(view.name);
    if (it == displacement_px.end()) continue;  // a view the truth does not know is not scored
    const bool wrong = it->second >= wrong_px;
    const bool called = view.flagged || result.capture_poor;
    ++score.views;
    score.wrong += wrong;
    score.called_out += called;
    score.true_calls += called && wrong;
    score.false_calls += called && !wrong;
  }
  const double nan = std::numeric_limits<double>::quiet_NaN();
  score.precision = score.called_out > 0 ? static_cast<double>(score.true_calls) / score.called_out : nan;
  score.recall = score.wrong > 0 ? static_cast<double>(score.true_calls) / score.wrong : nan;
  return score;
}

std::vector<std::string> ReadFlaggedViews(const std::string& path) {
  const nlohmann::json file = ReadJsonOr(path, nlohmann::json());
  std::vector<std::string> names;
  if (!file.is_object() || !file.contains("flagged") || !file["flagged"].is_array()) return names;
  for (const auto& name : file["flagged"]) {
    if (name.is_string()) names.push_back(name.get<std::string>());
  }
  return names;
}

}  // namespace ibmr
