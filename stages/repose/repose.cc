// Pose refinement of one view against the other views' depth maps: SIFT matches lifted to 3D,
// RANSAC EPnP, Levenberg-Marquardt (issue 67; see repose.h).
#include "stages/repose/repose.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/features2d.hpp>

namespace ibmr {

namespace {

constexpr double kPi = 3.14159265358979323846;

struct Features {
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
};

Features Detect(const cv::Mat& gray, int max_features) {
  Features f;
  cv::Ptr<cv::SIFT> sift = cv::SIFT::create(max_features);
  sift->detectAndCompute(gray, cv::noArray(), f.keypoints, f.descriptors);
  return f;
}

// The reference's depth at image coordinates `p` (pixel centres at +0.5, COLMAP's convention),
// nearest pixel of its depth map; 0 outside or unknown.
float DepthAtImage(const ReposeView& reference, const Eigen::Vector2d& p) {
  const DepthMap& depth = reference.depth;
  const int x = static_cast<int>(p.x() * depth.width / reference.camera.width);
  const int y = static_cast<int>(p.y() * depth.height / reference.camera.height);
  if (x < 0 || y < 0 || x >= depth.width || y >= depth.height) return 0.f;
  const float z = depth.At(x, y);
  return IsValidDepth(z) ? z : 0.f;
}

// 2D-3D matches: the view's keypoints (normalised coordinates x/z, y/z) and world points.
struct Correspondences {
  std::vector<cv::Point2d> normalized;
  std::vector<cv::Point3d> world;
};

void AddMatches(const Features& view_features, const ReposeView& view, const ReposeView& reference,
                const ReposeOptions& options, Correspondences* out) {
  const Features ref = Detect(reference.gray, options.max_features);
  if (ref.descriptors.empty() || view_features.descriptors.empty()) return;
  cv::BFMatcher matcher(cv::NORM_L2);
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(view_features.descriptors, ref.descriptors, knn, 2);
  const Rigid3d world_from_ref = reference.cam_from_world.Inverse();
  for (const auto& m : knn) {
    if (m.size() < 2 || m[0].distance > options.ratio * m[1].distance) continue;
    const cv::Point2f& r = ref.keypoints[m[0].trainIdx].pt;
    const Eigen::Vector2d ref_pixel(r.x + 0.5, r.y + 0.5);
    const float z = DepthAtImage(reference, ref_pixel);
    if (z <= 0.f) continue;
    const Eigen::Vector3d point = world_from_ref.rotation * (reference.camera.CamFromImg(ref_pixel) * z) + world_from_ref.translation;
    const cv::Point2f& v = view_features.keypoints[m[0].queryIdx].pt;
    const Eigen::Vector3d ray = view.camera.CamFromImg(Eigen::Vector2d(v.x + 0.5, v.y + 0.5));
    out->normalized.emplace_back(ray.x() / ray.z(), ray.y() / ray.z());
    out->world.emplace_back(point.x(), point.y(), point.z());
  }
}

// RMS reprojection error (pixels, through the focal length) of the `inliers` under a pose.
double RmsPixels(const Correspondences& c, const std::vector<int>& inliers, const Rigid3d& cam_from_world, double focal) {
  if (inliers.empty()) return 0.0;
  double sum = 0;
  for (int i : inliers) {
    const Eigen::Vector3d x = cam_from_world.rotation * Eigen::Vector3d(c.world[i].x, c.world[i].y, c.world[i].z) + cam_from_world.translation;
    if (x.z() <= 0) {
      sum += 1e6;
      continue;
    }
    const double dx = x.x() / x.z() - c.normalized[i].x, dy = x.y() / x.z() - c.normalized[i].y;
    sum += (dx * dx + dy * dy) * focal * focal;
  }
  return std::sqrt(sum / static_cast<double>(inliers.size()));
}

Rigid3d FromRodrigues(const cv::Mat& rvec, const cv::Mat& tvec) {
  cv::Mat r;
  cv::Rodrigues(rvec, r);
  Eigen::Matrix3d rotation;
  cv::cv2eigen(r, rotation);
  return Rigid3d(rotation, Eigen::Vector3d(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)));
}

}  // namespace

bool ReposeOptions::Check(std::string* error) const {
  auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (max_features < 100 || max_features > 100000) return fail("max_features: must be in [100, 100000], got " + std::to_string(max_features));
  if (!(ratio > 0 && ratio <= 1)) return fail("ratio: must be in (0, 1], got " + std::to_string(ratio));
  if (!(ransac_px > 0)) return fail("ransac_px: must be > 0, got " + std::to_string(ransac_px));
  if (min_inliers < 6) return fail("min_inliers: must be >= 6, got " + std::to_string(min_inliers));
  if (!(min_rms_px >= 0)) return fail("min_rms_px: must be >= 0, got " + std::to_string(min_rms_px));
  if (!(max_rotation_deg > 0)) return fail("max_rotation_deg: must be > 0, got " + std::to_string(max_rotation_deg));
  if (num_neighbors < 1 || num_neighbors > 64) return fail("num_neighbors: must be in [1, 64], got " + std::to_string(num_neighbors));
  return true;
}

ReposeResult RefineViewPose(const ReposeView& view, const std::vector<ReposeView>& references, const ReposeOptions& options) {
  ReposeResult result;
  result.cam_from_world = view.cam_from_world;
  const Features features = Detect(view.gray, options.max_features);
  Correspondences c;
  for (const ReposeView& reference : references) AddMatches(features, view, reference, options, &c);
  result.correspondences = c.world.size();
  if (static_cast<int>(c.world.size()) < options.min_inliers) {
    result.reason = std::to_string(c.world.size()) + " matches with a depth, fewer than min_inliers " + std::to_string(options.min_inliers);
    return result;
  }
  const double focal = 0.5 * (view.camera.FocalX() + view.camera.FocalY());
  // Started from the current pose (RANSAC scores hypotheses without it; LM starts from the best).
  cv::Mat rotation, rvec, tvec;
  cv::eigen2cv(Eigen::Matrix3d(view.cam_from_world.R()), rotation);
  cv::Rodrigues(rotation, rvec);
  tvec = (cv::Mat_<double>(3, 1) << view.cam_from_world.translation.x(), view.cam_from_world.translation.y(),
          view.cam_from_world.translation.z());
  std::vector<int> inliers;
  const cv::Mat identity = cv::Mat::eye(3, 3, CV_64F);
  const bool solved = cv::solvePnPRansac(c.world, c.normalized, identity, cv::noArray(), rvec, tvec, /*useExtrinsicGuess=*/false,
                                         /*iterationsCount=*/2000, static_cast<float>(options.ransac_px / focal), 0.999, inliers,
                                         cv::SOLVEPNP_EPNP);
  result.inliers = inliers.size();
  if (!solved || static_cast<int>(inliers.size()) < options.min_inliers) {
    result.reason = std::to_string(inliers.size()) + " RANSAC inliers of " + std::to_string(c.world.size()) + " matches, fewer than min_inliers " +
                    std::to_string(options.min_inliers);
    return result;
  }
  std::vector<cv::Point3d> world_in;
  std::vector<cv::Point2d> image_in;
  for (int i : inliers) world_in.push_back(c.world[i]), image_in.push_back(c.normalized[i]);
  cv::solvePnPRefineLM(world_in, image_in, identity, cv::noArray(), rvec, tvec);
  const Rigid3d refined = FromRodrigues(rvec, tvec);
  result.rms_before_px = RmsPixels(c, inliers, view.cam_from_world, focal);
  result.rms_after_px = RmsPixels(c, inliers, refined, focal);
  result.rotation_change_deg = view.cam_from_world.rotation.angularDistance(refined.rotation) * 180.0 / kPi;
  result.center_change = (view.cam_from_world.Inverse().translation - refined.Inverse().translation).norm();
  if (result.rms_before_px < options.min_rms_px) {
    result.reason = "its matches reproject within " + std::to_string(result.rms_before_px) +
                    " px RMS under the current pose already (min_rms_px): the pose is not what disagrees";
    return result;
  }
  if (result.rotation_change_deg > options.max_rotation_deg) {
    result.reason = "correction of " + std::to_string(result.rotation_change_deg) + " degrees exceeds max_rotation_deg";
    return result;
  }
  if (!(result.rms_after_px <= result.rms_before_px)) {
    result.reason = "the refined pose reprojects the inliers worse than the initial one";
    return result;
  }
  result.cam_from_world = refined;
  result.accepted = true;
  return result;
}

}  // namespace ibmr
