// Steps 1 and 2 of layers.h: sequential RANSAC of world planes on a depth map, and their robust
// refinement across views with Ceres (seed 000 lines 5705-5716: the planes of the layers).
// A depth sample's distance to a plane is measured along its viewing ray, relative to its depth
// (the depth map's own error measure), not perpendicular to the plane: a wall seen at a grazing
// angle (a ceiling, a side wall) lies within a perpendicular tolerance of every surface that
// meets it far away, and those samples tilted the fitted planes (by 0.5 degrees on the synthetic
// room, which moved the planes 1.5% at the camera); along the ray they are several tolerances off.
#include <ceres/ceres.h>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>
#include <algorithm>
#include <cmath>
#include <random>

#include "stages/layered_stereo/layers.h"

namespace ibmr {

namespace {

struct Sample {
  Eigen::Vector3d point;
  Eigen::Vector3d ray;  // point minus the camera centre
  bool interior;        // at least edge_margin_px from a depth discontinuity
  int x, y;             // its pixel
};

// Distance of each pixel to the nearest depth discontinuity: a pixel whose inverse depth departs
// from the mean of its two neighbours (along x or along y) by more than `jump` of itself (a step
// of 2 * jump between two pixels), or next to a pixel without depth (the image border counts as
// one). Inverse depth is linear in the image on any plane, so a floor seen at a grazing angle (its
// depth changing by several percent a pixel) is smooth by this test; a step is an edge, and so is
// a sharp crease, but not one as gentle as a floor meeting a far wall (a slope change of 2% of
// the inverse depth a pixel in the synthetic room).
cv::Mat DistanceToDepthEdges(const cv::Mat& depth, double jump) {
  cv::Mat smooth(depth.size(), CV_8U, cv::Scalar(0));
  auto inverse = [&](int y, int x) {
    const float z = depth.at<float>(y, x);
    return z > 0 && std::isfinite(z) ? 1.0 / z : 0.0;
  };
  for (int y = 1; y + 1 < depth.rows; ++y) {
    for (int x = 1; x + 1 < depth.cols; ++x) {
      const double w = inverse(y, x), left = inverse(y, x - 1), right = inverse(y, x + 1), up = inverse(y - 1, x),
                   down = inverse(y + 1, x);
      if (!(w > 0 && left > 0 && right > 0 && up > 0 && down > 0)) continue;
      smooth.at<uchar>(y, x) = std::abs(0.5 * (left + right) - w) <= jump * w && std::abs(0.5 * (up + down) - w) <= jump * w;
    }
  }
  cv::Mat distance;
  cv::distanceTransform(smooth, distance, cv::DIST_L2, 3);
  return distance;
}

std::vector<Sample> Samples(const LayerView& view, int step, const LayeredOptions& options) {
  std::vector<Sample> samples;
  const Eigen::Matrix3d world_from_cam = view.cam_from_world.R().transpose();
  const Eigen::Vector3d centre = -(world_from_cam * view.cam_from_world.translation);
  const cv::Mat edge_distance = DistanceToDepthEdges(view.depth, 3 * options.plane_tolerance);
  for (int y = step / 2; y < view.depth.rows; y += step) {
    const float* row = view.depth.ptr<float>(y);
    for (int x = step / 2; x < view.depth.cols; x += step) {
      const double z = row[x];
      if (!(z > 0) || !std::isfinite(z)) continue;
      const Eigen::Vector3d ray = world_from_cam * (z * view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)));
      samples.push_back({centre + ray, ray, edge_distance.at<float>(y, x) >= options.edge_margin_px, x, y});
    }
  }
  return samples;
}

bool PlaneThrough(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c, WorldPlane* plane) {
  const Eigen::Vector3d n = (b - a).cross(c - a);
  const double norm = n.norm();
  if (!(norm > 1e-12 * (b - a).squaredNorm())) return false;
  plane->normal = n / norm;
  plane->offset = plane->normal.dot(a);
  return true;
}

// Least-squares plane through points (principal axis of least variance).
WorldPlane FitLeastSquares(const std::vector<Eigen::Vector3d>& points) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : points) scatter += (p - mean) * (p - mean).transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);
  WorldPlane plane;
  plane.normal = solver.eigenvectors().col(0).normalized();
  plane.offset = plane.normal.dot(mean);
  return plane;
}

// The sample's ray meets the plane at a depth that differs from the sample's by the fraction
// (n.X - d) / (n.ray) (the ray runs from the camera centre to the point X; depth along the optical
// axis and distance along the ray differ by the same factor). A plane seen edge-on (n.ray = 0)
// holds no sample.
bool OnPlane(const WorldPlane& plane, const Sample& s, double tolerance) {
  return std::abs(plane.normal.dot(s.point) - plane.offset) <= tolerance * std::abs(plane.normal.dot(s.ray));
}

// The samples on a plane that a fit should use: the interior ones when there are at least
// `min_interior` of them (a small layer may lie entirely near discontinuities), else all.
std::vector<const Sample*> FitSamples(const std::vector<Sample>& samples, const WorldPlane& plane, double tolerance,
                                      size_t min_interior) {
  std::vector<const Sample*> all, interior;
  for (const Sample& s : samples) {
    if (!OnPlane(plane, s, tolerance)) continue;
    all.push_back(&s);
    if (s.interior) interior.push_back(&s);
  }
  return interior.size() >= min_interior ? interior : all;
}

// The label of the largest 8-connected component of a non-zero mask (0 when there is none), the
// labels and, when asked, its area in cells.
int LargestComponent(const cv::Mat& mask, cv::Mat* labels, int* area) {
  cv::Mat stats, centroids;
  const int count = cv::connectedComponentsWithStats(mask, *labels, stats, centroids, 8, CV_32S);
  int largest = 0, largest_area = 0;
  for (int label = 1; label < count; ++label) {
    if (stats.at<int>(label, cv::CC_STAT_AREA) > largest_area) largest_area = stats.at<int>(label, cv::CC_STAT_AREA), largest = label;
  }
  if (area) *area = largest_area;
  return largest;
}

// The largest 8-connected region (on the sampling grid of `step` pixels) of samples on a plane.
// Two surfaces apart in the image that a plane crosses within the tolerance (a box's face and the
// front of an object beside it at the same depth) are not one plane: fitted together, the plane
// tilts between them.
std::vector<const Sample*> LargestRegion(const std::vector<const Sample*>& on_plane, int step) {
  if (on_plane.empty()) return {};
  int cols = 0, rows = 0;
  for (const Sample* s : on_plane) cols = std::max(cols, s->x / step + 1), rows = std::max(rows, s->y / step + 1);
  cv::Mat mask(rows, cols, CV_8U, cv::Scalar(0));
  for (const Sample* s : on_plane) mask.at<uchar>(s->y / step, s->x / step) = 255;
  cv::Mat labels;
  const int largest = LargestComponent(mask, &labels, nullptr);
  std::vector<const Sample*> region;
  for (const Sample* s : on_plane) {
    if (labels.at<int>(s->y / step, s->x / step) == largest) region.push_back(s);
  }
  return region;
}


// That relative depth difference divided by the tolerance, for a plane (n, d); the scale of
// (n, d) cancels, so the 4 parameters need no normalisation.
struct PlaneResidual {
  PlaneResidual(const Sample& s, double tolerance) : sample(s), inverse_tolerance(1.0 / tolerance) {}
  template <typename T>
  bool operator()(const T* const plane, T* residual) const {
    const T along = plane[0] * T(sample.ray.x()) + plane[1] * T(sample.ray.y()) + plane[2] * T(sample.ray.z());
    // A step that turns the plane edge-on to this ray is no plane for it: Ceres rejects the step.
    if (ceres::abs(along) < T(1e-12 * sample.ray.norm())) return false;
    const T off = plane[0] * T(sample.point.x()) + plane[1] * T(sample.point.y()) + plane[2] * T(sample.point.z()) - plane[3];
    residual[0] = off / along * T(inverse_tolerance);
    return true;
  }
  Sample sample;
  double inverse_tolerance;
};

// A hypothesis' support: the size of the largest 8-connected region of its inliers among
// `coarse` (samples on a grid of 2 sampling steps, marked in `mask`, which has that grid's size).
// No region is larger than the inliers: when they are no more than `to_beat` (the best support so
// far), their count is returned without finding the regions, as it cannot win either (most
// hypotheses; the regions' labelling was a sixth of layered_stereo's time). `labels`: the
// labelling's working image, reused.
size_t RegionSupport(const std::vector<Sample>& samples, const std::vector<size_t>& coarse, const WorldPlane& plane,
                     double tolerance, int cell, size_t to_beat, cv::Mat* mask, cv::Mat* labels) {
  mask->setTo(0);
  size_t inliers = 0;
  for (size_t i : coarse) {
    if (!OnPlane(plane, samples[i], tolerance)) continue;
    mask->at<uchar>(samples[i].y / cell, samples[i].x / cell) = 255;
    ++inliers;
  }
  if (inliers <= to_beat) return inliers;
  int area = 0;
  LargestComponent(*mask, labels, &area);
  return static_cast<size_t>(area);
}

}  // namespace

std::vector<WorldPlane> FitPlanesRansac(const LayerView& reference, const LayeredOptions& options, unsigned seed) {
  std::vector<Sample> samples = Samples(reference, options.sample_step, options);
  const size_t total = samples.size();
  const size_t min_support = std::max<size_t>(3, static_cast<size_t>(options.min_layer_fraction * total));
  std::vector<WorldPlane> planes;
  std::mt19937 rng(seed);
  // Hypotheses are scored by their largest connected region of inliers (on a grid of two sampling
  // steps), not by all inliers: a plane through two surfaces at about the same depth (a box's face
  // and an object's front beside it) gathers the most inliers, but fits neither. The winner is
  // refitted to its largest region and kept when that plane has min_support inliers in the whole
  // view. Once the best region's plane has fewer, the rest is scored by all inliers: such a plane
  // still serves as a layer for the scattered surfaces it passes through (the count selection
  // decides whether it stays).
  const int cell = 2 * options.sample_step;
  cv::Mat mask(reference.depth.rows / cell + 1, reference.depth.cols / cell + 1, CV_8U), labels;
  // One round of sequential RANSAC: the best hypothesis, refitted, and its inlier count.
  auto find_plane = [&](bool by_region, size_t* support) {
    std::uniform_int_distribution<size_t> pick(0, samples.size() - 1);
    std::vector<size_t> coarse;
    for (size_t i = 0; i < samples.size(); ++i) {
      if ((samples[i].x / options.sample_step) % 2 == 0 && (samples[i].y / options.sample_step) % 2 == 0) coarse.push_back(i);
    }
    WorldPlane best;
    size_t best_score = 0;
    for (int iteration = 0; iteration < options.ransac_iterations; ++iteration) {
      // Three samples near each other (a local patch) propose planes that exist in the scene more
      // often than three samples from anywhere.
      const size_t i = pick(rng);
      size_t j = pick(rng), k = pick(rng);
      const double near = 0.1 * samples[i].ray.norm();
      for (int tries = 0; tries < 8 && (samples[j].point - samples[i].point).norm() > near; ++tries) j = pick(rng);
      for (int tries = 0; tries < 8 && (samples[k].point - samples[i].point).norm() > near; ++tries) k = pick(rng);
      WorldPlane candidate;
      if (i == j || j == k || i == k || !PlaneThrough(samples[i].point, samples[j].point, samples[k].point, &candidate)) continue;
      size_t score = 0;
      if (by_region) {
        score = RegionSupport(samples, coarse, candidate, options.plane_tolerance, cell, best_score, &mask, &labels);
      } else {
        for (size_t c : coarse) score += OnPlane(candidate, samples[c], options.plane_tolerance);
      }
      if (score > best_score) {
        best_score = score;
        best = candidate;
      }
    }
    *support = 0;
    if (best_score == 0) return best;
    // Refit to the inliers (of the largest region, when scored by regions) twice: the
    // least-squares plane gathers a few more.
    for (int round = 0; round < 2; ++round) {
      std::vector<Eigen::Vector3d> inliers;
      const auto on_plane = FitSamples(samples, best, options.plane_tolerance, std::max<size_t>(3, min_support / 4));
      for (const Sample* s : by_region ? LargestRegion(on_plane, options.sample_step) : on_plane) inliers.push_back(s->point);
      if (inliers.size() < 3) break;
      best = FitLeastSquares(inliers);
    }
    for (const Sample& s : samples) *support += OnPlane(best, s, options.plane_tolerance);
    return best;
  };
  bool by_region = true;
  while (static_cast<int>(planes.size()) < options.max_layers && samples.size() >= min_support) {
    size_t support = 0;
    WorldPlane best = find_plane(by_region, &support);
    if (support < min_support && by_region) {
      by_region = false;
      best = find_plane(by_region, &support);
    }
    if (support < min_support) break;
    best.support = support;
    best.connected = by_region;
    planes.push_back(best);
    std::vector<Sample> rest;
    for (const Sample& s : samples) {
      if (!OnPlane(best, s, options.plane_tolerance)) rest.push_back(s);
    }
    samples.swap(rest);
  }
  return planes;
}

void RefinePlanes(const std::vector<const LayerView*>& views, const LayeredOptions& options, std::vector<WorldPlane>* planes) {
  if (views.empty()) return;
  std::vector<std::vector<Sample>> per_view;
  for (const LayerView* view : views) per_view.push_back(Samples(*view, options.sample_step * 2, options));
  for (WorldPlane& plane : *planes) {
    double parameters[4] = {plane.normal.x(), plane.normal.y(), plane.normal.z(), plane.offset};
    ceres::Problem problem;
    size_t residuals = 0;
    for (const auto& samples : per_view) {
      // Samples within twice the tolerance (of a connected plane: in the largest region they form
      // in the view) take part; the Cauchy loss (scale 1 tolerance) weighs down those that belong
      // to something else.
      const auto on_plane = FitSamples(samples, plane, 2 * options.plane_tolerance, 32);
      for (const Sample* s : plane.connected ? LargestRegion(on_plane, options.sample_step * 2) : on_plane) {
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PlaneResidual, 1, 4>(
                                     new PlaneResidual(*s, options.plane_tolerance)),
                                 new ceres::CauchyLoss(1.0), parameters);
        ++residuals;
      }
    }
    if (residuals < 3) continue;
    ceres::Solver::Options solver;
    solver.max_num_iterations = 20;
    solver.linear_solver_type = ceres::DENSE_QR;
    solver.num_threads = 1;
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    const Eigen::Vector3d n(parameters[0], parameters[1], parameters[2]);
    if (!(n.norm() > 0) || !std::isfinite(parameters[3])) continue;
    plane.normal = n.normalized();
    plane.offset = parameters[3] / n.norm();
  }
}

}  // namespace ibmr
