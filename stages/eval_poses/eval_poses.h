// Pose evaluation against ground-truth cameras, the measure behind seed 000 §8 (lines 4830-4860:
// "structure from motion algorithms are notoriously bad at estimating the true pose" - so measure
// it). The estimate is aligned to the truth by a similarity transform fitted to the camera centres
// (Umeyama 1991, least squares, with scale); then, per camera present in both, the rotation error
// is the angle of R_est_aligned * R_true^T (degrees) and the centre error is the distance of the
// aligned centre to the true one divided by the ring diameter (largest distance between two true
// centres). The focal error compares fx of both models (relative).
#pragma once

#include <string>
#include <vector>

#include "pipeline/core/sparse_model.h"

namespace ibmr {

struct EvalPosesOptions {
  int min_common = 3;  // cameras needed in both models for the alignment; >= 3
  bool Check(std::string* error) const;  // error starts with the YAML key
};

struct CameraPoseError {
  std::string name;
  bool registered = false;
  double rotation_deg = -1;       // -1 when not registered
  double centre_fraction = -1;    // centre error / ring diameter
  double focal_fraction = -1;     // |fx_est - fx_true| / fx_true
};

struct PoseEvaluation {
  int total = 0;        // cameras in the truth
  int registered = 0;   // of those, present in the estimate
  double ring_diameter = 0;  // truth units
  double scale = 1;          // similarity scale (estimate -> truth)
  double median_rotation_deg = 0, mean_rotation_deg = 0, max_rotation_deg = 0;
  double median_centre_fraction = 0, max_centre_fraction = 0;
  double median_focal_fraction = 0;
  std::vector<CameraPoseError> cameras;  // in the truth's name order
  std::vector<std::string> unregistered;
};

// Throws InputError when fewer than min_common cameras are shared (naming the counts).
PoseEvaluation EvaluatePoses(const SparseModel& estimate, const SparseModel& truth, const EvalPosesOptions& options);

}  // namespace ibmr
