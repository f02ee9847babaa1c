// Similarity alignment (Umeyama) and per-camera pose errors; see eval_poses.h.
#include "stages/eval_poses/eval_poses.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

#include "pipeline/core/median.h"
#include "pipeline/core/errors.h"

namespace ibmr {

namespace {

double RingDiameter(const std::vector<Eigen::Vector3d>& centres) {
  double diameter = 0;
  for (size_t i = 0; i < centres.size(); ++i) {
    for (size_t j = i + 1; j < centres.size(); ++j) diameter = std::max(diameter, (centres[i] - centres[j]).norm());
  }
  return diameter;
}

// x_true = scale * rotation * x_est + translation.
struct Similarity {
  double scale = 1;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
};

Similarity CentreAlignment(const Eigen::Matrix3Xd& source, const Eigen::Matrix3Xd& target) {
  const Eigen::Matrix4d m = Eigen::umeyama(source, target, true);
  Similarity s;
  s.scale = std::cbrt(m.topLeftCorner<3, 3>().determinant());
  s.rotation = m.topLeftCorner<3, 3>() / s.scale;
  s.translation = m.topRightCorner<3, 1>();
  return s;
}

// The rotation maximising trace(R^T m) (orthogonal Procrustes, determinant +1).
Eigen::Matrix3d Procrustes(const Eigen::Matrix3d& m) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

// Alternating minimisation of the joint cost in eval_poses.h, from the centre-only fit. The cost
// falls at every step (each is the exact minimiser over one block), so it converges; 50 rounds
// are far more than the few it takes.
Similarity JointAlignment(const Eigen::Matrix3Xd& source, const Eigen::Matrix3Xd& target,
                          const std::vector<const Image*>& est, const std::vector<const Image*>& truth,
                          double diameter, const Similarity& start) {
  const Eigen::Vector3d source_mean = source.rowwise().mean(), target_mean = target.rowwise().mean();
  const Eigen::Matrix3Xd x = source.colwise() - source_mean, y = target.colwise() - target_mean;
  const Eigen::Matrix3d centre_cov = y * x.transpose();  // sum of y_i x_i^T
  const double source_var = x.squaredNorm();
  // R_est_i R^T ~ R_true_i  <=>  R ~ R_true_i^T R_est_i.
  Eigen::Matrix3d orientation_cov = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < est.size(); ++i) orientation_cov += truth[i]->cam_from_world.R().transpose() * est[i]->cam_from_world.R();
  const double weight = 1.0 / std::max(diameter * diameter, 1e-24);
  Similarity s = start;
  for (int round = 0; round < 50; ++round) {
    s.rotation = Procrustes(orientation_cov + weight * s.scale * centre_cov);
    if (source_var > 0) s.scale = std::max((s.rotation.transpose() * centre_cov).trace() / source_var, 1e-12);
  }
  s.translation = target_mean - s.scale * s.rotation * source_mean;
  return s;
}

double RotationErrorDeg(const Image& est, const Image& truth, const Similarity& s) {
  const Eigen::AngleAxisd delta(est.cam_from_world.R() * s.rotation.transpose() * truth.cam_from_world.R().transpose());
  return std::abs(delta.angle()) * 180.0 / M_PI;
}

double CentreError(const Image& est, const Image& truth, const Similarity& s) {
  return (s.scale * s.rotation * est.Center() + s.translation - truth.Center()).norm();
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
  bool identical = true;
  for (int i = 0; i < eval.registered; ++i) {
    source.col(i) = est_images[i]->Center();
    target.col(i) = true_images[i]->Center();
    // Equal up to the text round trip's last digits (a copy of the truth, not an estimate).
    identical = identical && (est_images[i]->cam_from_world.R() - true_images[i]->cam_from_world.R()).norm() < 1e-9 &&
                (est_images[i]->Center() - true_images[i]->Center()).norm() <= 1e-9 * std::max(1.0, source.col(i).norm());
  }
  eval.identical_to_truth = identical;
  const Similarity centre_only = CentreAlignment(source, target);
  const Similarity joint = JointAlignment(source, target, est_images, true_images, eval.ring_diameter, centre_only);
  eval.scale = joint.scale;
  std::vector<double> focals;
  int k = 0;
  for (CameraPoseError& error : eval.cameras) {
    if (!error.registered) continue;
    const Image& est = *est_images[k];
    const Image& tru = *true_images[k];
    ++k;
    error.rotation_deg = RotationErrorDeg(est, tru, joint);
    error.centre_fraction = CentreError(est, tru, joint) / std::max(eval.ring_diameter, 1e-12);
    const double f_true = truth.CameraOf(tru).FocalX();
    error.focal_fraction = std::abs(estimate.CameraOf(est).FocalX() - f_true) / f_true;
    focals.push_back(error.focal_fraction);
  }
  const auto summarise = [&](const Similarity& alignment) {
    std::vector<double> rotations, centres;
    for (size_t i = 0; i < est_images.size(); ++i) {
      rotations.push_back(RotationErrorDeg(*est_images[i], *true_images[i], alignment));
      centres.push_back(CentreError(*est_images[i], *true_images[i], alignment) / std::max(eval.ring_diameter, 1e-12));
    }
    PoseErrorSummary summary;
    summary.median_rotation_deg = Median(rotations);
    summary.max_rotation_deg = *std::max_element(rotations.begin(), rotations.end());
    double sum = 0;
    for (double r : rotations) sum += r;
    summary.mean_rotation_deg = sum / rotations.size();
    summary.median_centre_fraction = Median(centres);
    summary.max_centre_fraction = *std::max_element(centres.begin(), centres.end());
    return summary;
  };
  const PoseErrorSummary main = summarise(joint);
  eval.median_rotation_deg = main.median_rotation_deg;
  eval.mean_rotation_deg = main.mean_rotation_deg;
  eval.max_rotation_deg = main.max_rotation_deg;
  eval.median_centre_fraction = main.median_centre_fraction;
  eval.max_centre_fraction = main.max_centre_fraction;
  eval.centre_only = summarise(centre_only);
  eval.median_focal_fraction = Median(focals);
  return eval;
}

}  // namespace ibmr
