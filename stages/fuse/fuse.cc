// Uncertainty-weighted merging of depth samples into points (seed 000 lines 4352-4453). See fuse.h.
#include "stages/fuse/fuse.h"

#include "pipeline/core/depth_normals.h"
#include "pipeline/core/point_index.h"
#include "pipeline/core/residual_falloff.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace ibmr {

namespace {

constexpr double kPi = 3.14159265358979323846;

// One merged point: sums of the information matrices and information-weighted positions
// (seed 000 line ~4396: "replace them with a single measurement with a reduced uncertainty").
struct FusedPoint {
  Eigen::Matrix3d information = Eigen::Matrix3d::Zero();
  Eigen::Vector3d information_x = Eigen::Vector3d::Zero();
  Eigen::Vector3d position = Eigen::Vector3d::Zero();  // information^-1 * information_x
  Eigen::Vector3f normal_sum = Eigen::Vector3f::Zero();
  Eigen::Vector3f color_sum = Eigen::Vector3f::Zero();
  float confidence_sum = 0;
  float weight_sum = 0;  // of the normals and colours: the confidences, at least 0.01 each
  int views = 0;
  // The samples' scatter about the merged position: sum of (x_i - origin)^T I_i (x_i - origin),
  // origin the first sample's position (keeps the difference in Chi2 well conditioned).
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  double weighted_square = 0;
  // Chi-square of the samples about the merged position: sum of (x_i - p)^T I_i (x_i - p).
  double Chi2() const {
    const Eigen::Vector3d d = position - origin;
    return std::max(0.0, weighted_square - d.dot(information * d));
  }
};

// The agreement factor of a point's confidence: 1 while its samples scatter no more than their
// covariances predict (chi-square per degree of freedom, views - 1, at most 1), then
// exp(-(chi2 / dof - 1) / 2).
float AgreementFactor(const FusedPoint& p) {
  if (p.views < 2) return 1.f;
  const double per_dof = p.Chi2() / (p.views - 1);
  return per_dof <= 1 ? 1.f : static_cast<float>(std::exp(-0.5 * (per_dof - 1)));
}

}  // namespace

struct PointFuser::State {
  FuseOptions options;
  std::vector<FusedPoint> points;
  // Per-view scratch, kept from view to view: allocating it afresh for every view (a few MB each
  // on templeRing) cost more in page faults than the fusion's arithmetic.
  std::vector<int32_t> hit_pixel;
  std::vector<double> hit_distance;
  std::vector<int> candidate;
  std::vector<float> candidate_score;
  std::vector<char> touched;
};

bool FuseOptions::Check(std::string* error) const {
  auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (!(relative_depth_sigma > 0 && relative_depth_sigma <= 0.2)) return fail("relative_depth_sigma: must be in (0, 0.2], got " + std::to_string(relative_depth_sigma));
  if (!(lateral_sigma_pixels > 0 && lateral_sigma_pixels <= 10)) return fail("lateral_sigma_pixels: must be in (0, 10], got " + std::to_string(lateral_sigma_pixels));
  if (!(merge_sigmas > 0 && merge_sigmas <= 100)) return fail("merge_sigmas: must be in (0, 100], got " + std::to_string(merge_sigmas));
  // A point is a candidate for the one pixel it falls in, whose centre is at most sqrt(1/2) away:
  // a larger radius would promise merges across pixels that never happen.
  if (!(merge_pixel_radius > 0 && merge_pixel_radius <= 0.71)) {
    return fail("merge_pixel_radius: must be in (0, 0.71] (a point merges only within the pixel it falls in; 0.71: "
                "anywhere in it), got " + std::to_string(merge_pixel_radius));
  }
  if (!(max_normal_angle_deg > 0 && max_normal_angle_deg <= 180)) return fail("max_normal_angle_deg: must be in (0, 180], got " + std::to_string(max_normal_angle_deg));
  if (!(min_confidence >= 0 && min_confidence <= 1)) return fail("min_confidence: must be in [0, 1], got " + std::to_string(min_confidence));
  if (min_views < 1 || min_views > 1000) return fail("min_views: must be in [1, 1000], got " + std::to_string(min_views));
  if (surface_neighbours != 0 && (surface_neighbours < 4 || surface_neighbours > 256)) {
    return fail("surface_neighbours: must be 0 (off) or in [4, 256], got " + std::to_string(surface_neighbours));
  }
  if (!(surface_residual_scale > 0 && std::isfinite(surface_residual_scale))) {
    return fail("surface_residual_scale: must be > 0, got " + std::to_string(surface_residual_scale));
  }
  return true;
}

std::vector<float> SurfaceFactors(const std::vector<Eigen::Vector3f>& positions, int neighbours, double scale) {
  if (neighbours < 4 || positions.size() < static_cast<size_t>(neighbours) + 1) return std::vector<float>(positions.size(), 1.f);
  const PointIndex index(positions);
  std::vector<double> residual(positions.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, positions.size(), 256), [&](const tbb::blocked_range<size_t>& range) {
    std::vector<std::pair<uint32_t, float>> nearest;  // reused within the block
    for (size_t i = range.begin(); i < range.end(); ++i) {
      index.Nearest(positions[i], neighbours, &nearest);
      Eigen::Vector3d centre = Eigen::Vector3d::Zero();
      for (const auto& [j, d2] : nearest) centre += positions[j].cast<double>();
      centre /= static_cast<double>(nearest.size());
      Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
      for (const auto& [j, d2] : nearest) {
        const Eigen::Vector3d q = positions[j].cast<double>() - centre;
        scatter += q * q.transpose();
      }
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);  // ascending: column 0 the normal
      residual[i] = std::abs(solver.eigenvectors().col(0).dot(positions[i].cast<double>() - centre));
    }
  });
  Eigen::AlignedBox3f box;
  for (const Eigen::Vector3f& p : positions) box.extend(p);
  const double floor = 1e-9 * std::max(1e-30, static_cast<double>(box.diagonal().norm()));
  return ResidualFalloff(residual, scale, floor, 0.0);
}

PointFuser::PointFuser(const FuseOptions& options) : state_(std::make_unique<State>()) { state_->options = options; }
PointFuser::~PointFuser() = default;

void PointFuser::AddView(const FuseView& view) {
  const FuseOptions& o = state_->options;
  std::vector<FusedPoint>& points = state_->points;
  const int w = view.depth.width, h = view.depth.height;
  if (w == 0 || h == 0) return;
  const double sx = static_cast<double>(w) / view.camera.width, sy = static_cast<double>(h) / view.camera.height;
  const double focal = 0.5 * (view.camera.FocalX() * sx + view.camera.FocalY() * sy);
  const Eigen::Matrix3d world_from_cam = view.cam_from_world.R().transpose();
  const Eigen::Vector3d center = view.cam_from_world.Inverse().translation;
  const double cos_normal = std::cos(o.max_normal_angle_deg * kPi / 180.0);
  auto confidence_at = [&](int x, int y) { return view.confidence.Empty() ? 1.f : UsableConfidence(view.confidence.At(x, y)); };
  auto sample_usable = [&](int x, int y) { return IsValidDepth(view.depth.At(x, y)) && confidence_at(x, y) >= o.min_confidence; };
  auto ray_at = [&](double px, double py) { return view.camera.CamFromImg(Eigen::Vector2d(px / sx, py / sy)); };
  auto depth_sigma = [&](float depth, float confidence) {
    return o.relative_depth_sigma * depth / std::sqrt(std::max(confidence, 0.01f));
  };
  const FloatMap computed_normals = view.normals.Empty() ? NormalsFromDepth(view.camera, view.depth) : FloatMap();
  const FloatMap& normals = view.normals.Empty() ? computed_normals : view.normals;
  auto world_normal = [&](int x, int y) -> Eigen::Vector3d {
    const Eigen::Vector3d n(normals.At(x, y, 0), normals.At(x, y, 1), normals.At(x, y, 2));
    return n.squaredNorm() > 0.25 ? (world_from_cam * n).normalized() : Eigen::Vector3d::Zero();
  };

  // 1. Earlier points re-projected into this view: each is a candidate for the one pixel it falls
  //    in, when near that pixel's centre, depth-compatible in the 1-D uncertainty-weighted sense,
  //    and of a similar normal; per pixel the best (smallest distance) candidate wins. The tests
  //    run in parallel; the choice per pixel is made in point order, as a serial loop would.
  std::vector<int32_t>& hit_pixel = state_->hit_pixel;
  std::vector<double>& hit_distance = state_->hit_distance;
  hit_pixel.assign(points.size(), -1);
  hit_distance.assign(points.size(), 0.0);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i < range.end(); ++i) {
      const FusedPoint& p = points[i];
      const Eigen::Vector3d in_cam = view.cam_from_world * p.position;
      if (in_cam.z() <= 0) continue;
      Eigen::Vector2d pixel = view.camera.ImgFromCam(in_cam);
      pixel.x() *= sx, pixel.y() *= sy;
      // Tested as doubles before the conversion: a point just in front of the camera projects
      // beyond any int (and NaN fails both tests).
      if (!(pixel.x() >= 0 && pixel.y() >= 0 && pixel.x() < w && pixel.y() < h)) continue;
      const int x = static_cast<int>(pixel.x()), y = static_cast<int>(pixel.y());
      if (!sample_usable(x, y)) continue;
      if ((pixel - Eigen::Vector2d(x + 0.5, y + 0.5)).norm() > o.merge_pixel_radius) continue;
      const float depth = view.depth.At(x, y);
      const Eigen::Vector3d ray = ray_at(x + 0.5, y + 0.5);
      const Eigen::Vector3d u = (world_from_cam * ray).normalized();
      const double sample_sigma = depth_sigma(depth, confidence_at(x, y)) * ray.norm();
      const double point_variance = u.dot(p.information.ldlt().solve(u));
      const double distance = std::abs(in_cam.z() - depth) * ray.norm() / std::sqrt(sample_sigma * sample_sigma + point_variance);
      if (distance > o.merge_sigmas) continue;
      const Eigen::Vector3d n = world_normal(x, y);
      if (n.squaredNorm() > 0 && p.normal_sum.squaredNorm() > 0 && n.dot(p.normal_sum.cast<double>().normalized()) < cos_normal) continue;
      hit_pixel[i] = y * w + x;
      hit_distance[i] = distance;
    }
  });
  std::vector<int>& candidate = state_->candidate;
  std::vector<float>& candidate_score = state_->candidate_score;
  candidate.assign(static_cast<size_t>(w) * h, -1);
  candidate_score.assign(candidate.size(), 0.f);
  for (size_t i = 0; i < points.size(); ++i) {
    const int32_t index = hit_pixel[i];
    if (index < 0) continue;
    if (candidate[index] < 0 || hit_distance[i] < candidate_score[index]) {
      candidate[index] = static_cast<int>(i);
      candidate_score[index] = static_cast<float>(hit_distance[i]);
    }
  }

  // 2. Each sample merges into its candidate or starts a new point. A sample's measurement is
  //    computed in parallel, a band of rows at a time; the merge runs in pixel order. A point takes
  //    at most one sample per view (its candidate pixel), so positions are solved once, after.
  struct Sample {
    int pixel;
    Eigen::Matrix3d information;
    Eigen::Vector3d position, normal;
    Eigen::Vector3f color;
    float confidence;
  };
  constexpr int kBand = 32;
  std::vector<std::vector<Sample>> rows(kBand);
  std::vector<char>& touched = state_->touched;
  touched.assign(points.size(), 0);
  for (int y0 = 0; y0 < h; y0 += kBand) {
    const int y1 = std::min(h, y0 + kBand);
    tbb::parallel_for(y0, y1, [&](int y) {
      std::vector<Sample>& row = rows[y - y0];
      row.clear();
      for (int x = 0; x < w; ++x) {
        if (!sample_usable(x, y)) continue;
        Sample sample;
        sample.pixel = y * w + x;
        const float depth = view.depth.At(x, y);
        sample.confidence = confidence_at(x, y);
        const Eigen::Vector3d ray = ray_at(x + 0.5, y + 0.5);
        sample.position = world_from_cam * (ray * depth) + center;
        const Eigen::Vector3d u = (world_from_cam * ray).normalized();
        const double along = depth_sigma(depth, sample.confidence) * ray.norm();
        const double across = o.lateral_sigma_pixels * depth * ray.norm() / focal;
        // Information matrix of the sample: 1/across^2 across the ray, 1/along^2 along it.
        sample.information =
            Eigen::Matrix3d::Identity() / (across * across) + (1 / (along * along) - 1 / (across * across)) * u * u.transpose();
        sample.color = Eigen::Vector3f(0.5f, 0.5f, 0.5f);
        if (!view.image.empty()) {
          const int ix = std::min(view.image.cols - 1, static_cast<int>((x + 0.5) * view.image.cols / w));
          const int iy = std::min(view.image.rows - 1, static_cast<int>((y + 0.5) * view.image.rows / h));
          const cv::Vec3b bgr = view.image.at<cv::Vec3b>(iy, ix);
          sample.color = Eigen::Vector3f(bgr[2], bgr[1], bgr[0]) / 255.f;
        }
        sample.normal = world_normal(x, y);
        if (sample.normal.squaredNorm() == 0) sample.normal = -u;
        row.push_back(sample);
      }
    });
    for (int y = y0; y < y1; ++y) {
      for (const Sample& sample : rows[y - y0]) {
        const int c = candidate[sample.pixel];
        FusedPoint* p = nullptr;
        if (c >= 0) {
          p = &points[c];
          touched[c] = 1;
        } else {
          points.emplace_back();
          p = &points.back();
          p->origin = sample.position;
        }
        const Eigen::Vector3d offset = sample.position - p->origin;
        p->weighted_square += offset.dot(sample.information * offset);
        p->information += sample.information;
        p->information_x += sample.information * sample.position;
        // Normals and colours weigh samples by confidence, floored as depth_sigma floors it: with
        // min_confidence 0, samples of confidence 0 would otherwise make black points without normals.
        const float weight = std::max(sample.confidence, 0.01f);
        p->normal_sum += weight * sample.normal.cast<float>();
        p->color_sum += weight * sample.color;
        p->weight_sum += weight;
        p->confidence_sum += sample.confidence;
        ++p->views;
      }
    }
  }
  touched.resize(points.size(), 1);  // the new points
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i < range.end(); ++i) {
      if (touched[i]) points[i].position = points[i].information.ldlt().solve(points[i].information_x);
    }
  });
}

PointCloud PointFuser::Finish(FuseStats* stats) const {
  PointCloud cloud;
  FuseStats local;
  local.points = state_->points.size();
  for (const FusedPoint& p : state_->points) {
    local.samples += p.views;
    local.merged += p.views - 1;
    if (p.views < state_->options.min_views) continue;
    cloud.positions.push_back(p.position.cast<float>());
    const float norm = p.normal_sum.norm();
    cloud.normals.push_back(norm > 0 ? Eigen::Vector3f(p.normal_sum / norm) : Eigen::Vector3f::Zero());
    const Eigen::Vector3f color = (p.color_sum / p.weight_sum * 255.f).array().round().min(255.f).max(0.f).matrix();
    cloud.colors.push_back(color.cast<uint8_t>());
    const float mean_confidence = p.confidence_sum / p.views;
    cloud.confidence.push_back(state_->options.agreement_weighting ? mean_confidence * AgreementFactor(p) : mean_confidence);
  }
  local.kept_points = cloud.size();
  if (stats) *stats = local;
  return cloud;
}

}  // namespace ibmr
