// A failing view says so (issue 67): per view a figure of how well it agrees with the capture's
// other views, and a flag on the views that stand out from the rest on the bad side. An error in
// one camera's pose makes nearly every pixel of that view wrong by an amount the pose error sets,
// so there is nothing local for a per-pixel confidence to rank; the whole view's figure is what
// moves. Which figure is the producing stage's business (multi_depth: the median over its
// neighbours of the fraction of its depth samples each neighbour confirms); this file holds the
// robust statistics, the flag and the file they are written to.
//
// The flag is a robust z-score (Iglewicz & Hoaglin, "How to Detect and Handle Outliers", ASQC
// 1993, the "modified z-score"): z_i = (x_i - median) / s with s = 1.4826 * MAD, the median
// absolute deviation scaled to a Gaussian's sigma, so that one bad view among many neither moves
// the centre nor widens the spread it is measured against (a mean and standard deviation would be
// pulled towards it and could hide it). A view is flagged when its z is beyond `z_threshold` on
// the bad side only: a view that agrees better than the rest is not a problem. Two guards:
//   * min_scale: s is at least this (in the figure's units). A clean capture's views can agree so
//     uniformly (MAD of a few thousandths) that a harmless dip would reach any threshold; the floor
//     says how far below the median a view must fall before it can be called out at all.
//   * min_views: with fewer views the median and MAD say little: nothing is flagged.
// When all views are equally bad (noise on every camera) the MAD grows with them and no view
// stands out: the flag is about one view against its capture, not about the capture's quality.
//
// File (dense/stereo/view_agreement.json, written by multi_depth):
//   {"figure": "<what the number is>", "higher_is_better": true, "median": m, "mad": d, "scale": s,
//    "z_threshold": t, "min_scale": f, "min_views": n, "min_median": g, "scored": k,
//    "capture_poor": false, "views": [{"name": "...", "figure": x | null, "z": z | null,
//    "flagged": false, ...extra per-view fields}, ...], "flagged": ["<name>", ...]}
#pragma once

#include <nlohmann/json.hpp>
#include <map>
#include <string>
#include <vector>

namespace ibmr {

struct ViewFlagOptions {
  // |z| beyond which a view stands out, on the bad side; > 0. 3.5 is Iglewicz & Hoaglin's cut for
  // the modified z-score: a Gaussian sample falls below -3.5 with probability 0.00023, so a clean
  // ring of 40 views has under a 1% chance of one false flag, before min_scale lowers it further.
  double z_threshold = 3.5;
  // Least robust scale s, in the figure's units; >= 0. For multi_depth's confirmed fraction (in
  // [0, 1]): 0.08, so a view is flagged only when 3.5 * 0.08 = 0.28 or more below the median.
  // Measured on six clean captures (templeRing, the synthetic ring with seeds 1-5): their MADs
  // give s = 0.04-0.076, and the lowest view that works sits at most 0.135 below the median (a
  // 2x margin); a view turned by 0.5 degrees or more falls 0.4-0.6 below it. (templeR0040, whose
  // neighbours are all turned 180 degrees in the image plane, sat 0.72 below and was flagged
  // until plane_sweep read half-turned neighbours' census codes in its order: now 0.21.) With 0.05 the
  // views whose depth a 5-degree error damages second-hand (through the hull it carves wrongly,
  // 0.19-0.28 below) were flagged too.
  double min_scale = 0.08;
  // Capture-wide: the median figure below which the run warns that the views agree poorly as a
  // whole (every camera off alike, which no z-score can single out), in the figure's units, for a
  // higher-is-better figure; <= 0: off. Confirmed fraction: 0.4 (clean captures 0.66-0.87; the
  // synthetic ring with camera_noise 0.25: 0.21-0.34).
  double min_median = 0.4;
  int min_views = 5;  // fewer views with a figure: nothing is flagged; >= 3

  // False with `error` starting with the key when a value is out of range.
  bool Check(std::string* error) const;
};

// Median and robust scale of `values`, and each value's z-score.
struct RobustScores {
  double median = 0;
  double mad = 0;    // median absolute deviation from the median
  double scale = 0;  // max(1.4826 * mad, min_scale)
  std::vector<double> z;  // (value - median) / scale, in input order; 0 when scale is 0
};

// Pure. Empty input: all zero, no z.
RobustScores RobustZScores(const std::vector<double>& values, double min_scale);

// One view's figure and verdict. `has_figure` false: the view could not be scored (no neighbour
// saw its samples) and is never flagged.
struct ViewAgreement {
  std::string name;
  bool has_figure = false;
  double figure = 0;
  double z = 0;
  bool flagged = false;
  nlohmann::json extra = nlohmann::json::object();  // the producer's per-view details
};

struct ViewFlagResult {
  std::vector<ViewAgreement> views;  // as given
  RobustScores scores;               // over the views with a figure
  std::vector<std::string> flagged;  // names, in the views' order
  size_t scored = 0;                 // views with a figure
  bool capture_poor = false;         // higher is better and the median is below min_median
};

// Scores the views' figures and flags those beyond the threshold on the bad side (below the
// median when `higher_is_better`, above it otherwise). Pure.
ViewFlagResult FlagViews(std::vector<ViewAgreement> views, bool higher_is_better, const ViewFlagOptions& options);

// The run log's line about the result: the flagged views with their figure and z, or that none
// stands out, or why nothing could be scored (no view with a figure, too few views).
// `figure_name` says what the figure is ("confirmed fraction").
std::string ViewFlagMessage(const ViewFlagResult& result, const std::string& figure_name, const ViewFlagOptions& options);

// The run log's line when the capture as a whole agrees poorly (capture_poor), else empty.
std::string CaptureAgreementMessage(const ViewFlagResult& result, const std::string& figure_name, const ViewFlagOptions& options);

// The file's content (layout above).
nlohmann::json ViewAgreementJson(const ViewFlagResult& result, const std::string& figure_description, bool higher_is_better,
                                 const ViewFlagOptions& options);

// How the flags match views known to be wrong (synthetic captures, whose true cameras are known;
// the stability matrix's pose-error cells). A view is wrong when its written camera puts its
// points `wrong_px` pixels or more away from where the photo shows them on average
// (synth's ground_truth/pose_error.json). A view is called out when it is flagged, or when the
// capture as a whole is (capture_poor: the run's warning then names every view, the answer when
// every camera is off alike). precision = wrong views called out / views called out, recall =
// wrong views called out / wrong views; NaN where the denominator is 0 (nothing called out, no
// wrong view). Pure.
struct ViewFlagScore {
  int wrong = 0, called_out = 0, true_calls = 0, false_calls = 0, views = 0;
  double precision = 0, recall = 0;
};
ViewFlagScore ScoreViewFlags(const ViewFlagResult& result, const std::map<std::string, double>& displacement_px,
                             double wrong_px);

// The flagged view names of a file in that layout; empty when it is absent or unreadable (the
// report shows flags where a run wrote them, and nothing otherwise).
std::vector<std::string> ReadFlaggedViews(const std::string& path);

}  // namespace ibmr
