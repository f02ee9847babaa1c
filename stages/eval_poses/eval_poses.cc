// Similarity alignment (Umeyama) and per-camera pose errors; see eval_poses.h.
#include "stages/eval_poses/eval_poses.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "pipeline/core/errors.h"

namespace ibmr {

namespace {

double Median(std::vector<double> values) {
  if (values.empty()) return 0;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

double RingDiameter(const std::vector<Eigen::Vector3d>& centres) {
  double diameter = 0;
  for (size_t i = 0; i < centres.size(); ++i) {
    for (size_t j = i + 1; j < centres.size(); ++j) diameter = std::max(diameter, (centres[i] - centres[j]).norm());
  }
  return diameter;
}

}  // namespace

bool EvalPosesOptions::Check(std::string* error) const {
  if (min_common < 3) {
    if (error) *error = "min_common: must be >= 3, got " + std::to_string(min_common);
    return false;
  }
  return true;
}

PoseEvaluation EvaluatePoses(const SparseModel& estimate, const SparseModel& truth, const EvalPosesOptions& options) {
  PoseEvaluation eval;
  std::vector<const Image*> true_images, est_images;
  std::vector<Eigen::Vector3d> all_true_centres;
  for (int id : truth.ImageIdsByName()) {
    const Image& image = truth.images.at(id);
    all_true_centres.push_back(image.Center());
    CameraPoseError error;
    error.name = image.name;
    const Image* match = estimate.FindImage(image.name);
    error.registered = match != nullptr;
    if (match) {
      true_images.push_back(&image);
      est_images.push_back(match);
    } else {
      eval.unregistered.push_back(image.name);
    }
    eval.cameras.push_back(error);
  }
  eval.total = static_cast<int>(truth.images.size());
  eval.registered = static_cast<int>(true_images.size());
  eval.ring_diameter = RingDiameter(all_true_centres);
  if (eval.registered < options.min_common) {
    throw InputError("eval_poses: " + std::to_string(eval.registered) + " cameras are in both the estimate and the truth (" +
                     std::to_string(eval.total) + " in the truth); at least " + std::to_string(options.min_common) +
                     " are needed for the alignment");
  }
  Eigen::Matrix3Xd source(3, eval.registered), target(3, eval.registered);
  for (int i = 0; i < eval.registered; ++i) {
    source.col(i) = est_images[i]->Center();
    target.col(i) = true_images[i]->Center();
  }
  const Eigen::Matrix4d similarity = Eigen::umeyama(source, target, true);
  const Eigen::Matrix3d scaled_rotation = similarity.topLeftCorner<3, 3>();
  eval.scale = std::cbrt(scaled_rotation.determinant());
  const Eigen::Matrix3d rotation = scaled_rotation / eval.scale;  // truth_from_estimate
  std::vector<double> rotations, centres, focals;
  int k = 0;
  for (CameraPoseError& error : eval.cameras) {
    if (!error.registered) continue;
    const Image& est = *est_images[k];
    const Image& tru = *true_images[k];
    ++k;
    const Eigen::Matrix3d aligned = est.cam_from_world.R() * rotation.transpose();
    const Eigen::AngleAxisd delta(aligned * tru.cam_from_world.R().transpose());
    error.rotation_deg = std::abs(delta.angle()) * 180.0 / M_PI;
    const Eigen::Vector3d centre = scaled_rotation * est.Center() + similarity.topRightCorner<3, 1>();
    error.centre_fraction = (centre - tru.Center()).norm() / std::max(eval.ring_diameter, 1e-12);
    const double f_true = truth.CameraOf(tru).FocalX();
    error.focal_fraction = std::abs(estimate.CameraOf(est).FocalX() - f_true) / f_true;
    rotations.push_back(error.rotation_deg);
    centres.push_back(error.centre_fraction);
    focals.push_back(error.focal_fraction);
  }
  eval.median_rotation_deg = Median(rotations);
  eval.max_rotation_deg = *std::max_element(rotations.begin(), rotations.end());
  double sum = 0;
  for (double r : rotations) sum += r;
  eval.mean_rotation_deg = sum / rotations.size();
  eval.median_centre_fraction = Median(centres);
  eval.max_centre_fraction = *std::max_element(centres.begin(), centres.end());
  eval.median_focal_fraction = Median(focals);
  return eval;
}

}  // namespace ibmr
