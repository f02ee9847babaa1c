// The shape of a capture, read from its poses once they are known (import's or sfm's model): is it
// forward-facing (one scene photographed from a small patch of viewpoints, as LLFF captures are),
// an object (cameras around one point, their axes converging on it: a ring, a dome, a turntable) or
// general (a walk along or around a building, anything else)? Which models can serve a capture
// follows from it: a volume of fronto-parallel planes samples a forward-facing capture only (issue
// 53's finding), silhouettes and carving need one object against its background. The runner
// writes the analysis to capture.json and skips the stages whose model cannot serve the kind
// (Stage::Serves).
//
// The figures that decide, all from the model's cameras and sparse points:
//   axis_spread_deg     angle of the optical axes from their mean direction, 90th percentile of views
//   baseline_over_near  diameter of the camera centres over the near depth (the 5th percentile of
//                       the sparse points' depths in the views that see them); null without points
//   convergence         the point nearest to all axes (least squares): the median distance of the
//                       axes from it over the cameras' median distance to it (residual), the
//                       fraction of cameras that look towards it (in_front), and how far round it
//                       the cameras stand (surround_deg: 360 minus the largest gap between their
//                       azimuths about the axis of the ring they make)
// Rules, in order (thresholds in CaptureShapeOptions):
//   forward_facing  axis spread <= 35 deg and baseline over near <= 0.5 (or no points to say)
//   object          in_front >= 0.9, residual <= 0.35 and surround >= 150 deg
//   general         otherwise
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "pipeline/core/sparse_model.h"

namespace ibmr {

inline constexpr const char* kCaptureFile = "capture.json";

struct CaptureShapeOptions {
  double forward_max_spread_deg = 35;
  double forward_max_baseline_over_near = 0.5;
  double object_min_in_front = 0.9;
  double object_max_residual = 0.35;
  double object_min_surround_deg = 150;
};

struct CaptureShape {
  std::string kind;  // "forward_facing", "object" or "general"; "" with fewer than 2 posed views
  std::string reason;  // one line: the figures that decided it
  int views = 0;
  double axis_spread_deg = 0;      // 90th percentile
  double axis_spread_max_deg = 0;
  std::optional<double> baseline_over_near;
  std::optional<double> near_depth, far_depth;  // 5th and 95th percentiles of the points' depths
  bool converges = false;          // a point nearest to the axes exists (axes not all parallel)
  double convergence_residual = 0;
  double in_front = 0;
  double surround_deg = 0;
  bool silhouettes = false;        // the capture brings alpha (import's alpha/ folder)
  std::string set_by;              // "": the analysis; else what set `kind` instead ("plan.kind (...)")

  nlohmann::json ToJson() const;
  static CaptureShape FromJson(const nlohmann::json& json);
  // "object (axis spread 64 deg, ...)": the kind and its deciding figures.
  std::string Describe() const;
};

// The analysis of `model` (every posed view, held out or not: the shape of the capture).
CaptureShape AnalyseCapture(const SparseModel& model, bool has_alpha, const CaptureShapeOptions& options = {});

// The model folder to analyse at `path`: `path` itself when it holds images.txt, else a
// workspace's latest model (dense/sparse, sfm/sparse, sparse, the first with images.txt). Throws
// InputError naming the folders tried.
std::string FindModelFolder(const std::string& path);

// Kinds, for messages and checks.
inline constexpr const char* kCaptureKinds[] = {"forward_facing", "object", "general"};
bool IsCaptureKind(const std::string& kind);

}  // namespace ibmr
