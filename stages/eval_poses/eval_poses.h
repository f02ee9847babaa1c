// Pose evaluation against ground-truth cameras, the measure behind seed 000 §8 (lines 4830-4860:
// "structure from motion algorithms are notoriously bad at estimating the true pose" - so measure
// it). The estimate is aligned to the truth by a similarity transform x_true = s R x_est + t fitted
// to the camera centres and orientations together: it minimises
//   sum_i || R_est_i R^T - R_true_i ||_F^2  +  sum_i || s R c_est_i + t - c_true_i ||^2 / D^2
// (D the ring diameter, the largest distance between two true centres), so that a degree of
// orientation error (2 theta^2 in the first sum) weighs like 2.5% of D of centre error. Started from Umeyama's
// centre-only fit (1991), it alternates the closed forms: t from the centroids, R by orthogonal
// Procrustes on the summed orientation and centre cross-covariances, s by least squares. Without
// the orientation term a ring's rotation gauge is fixed by the centres alone, and every camera's
// orientation error then carries the error of that gauge; the centre-only figures are kept too.
// Per camera present in both: the rotation error is the angle of R_est_aligned R_true^T (degrees),
// the centre error the distance of the aligned centre to the true one over D. The focal error
// compares fx of both models (relative). An estimate identical to the truth (sfm fell back to the
// known cameras) is flagged: its errors are zero by construction and measure nothing.
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

// Errors under one alignment.
struct PoseErrorSummary {
  double median_rotation_deg = 0, mean_rotation_deg = 0, max_rotation_deg = 0;
  double median_centre_fraction = 0, max_centre_fraction = 0;
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
  PoseErrorSummary centre_only;  // the same errors after Umeyama's centre-only alignment
  bool identical_to_truth = false;  // every shared pose equals the truth's exactly (no evaluation)
};

// Throws InputError when fewer than min_common cameras are shared (naming the counts).
PoseEvaluation EvaluatePoses(const SparseModel& estimate, const SparseModel& truth, const EvalPosesOptions& options);

}  // namespace ibmr
