// Disparity planes of the two-view layered method (disparity_planes.h): sequential RANSAC of
// planes on the initial disparity, Ceres refinement, refits to a label assignment. Follows seed 000
// lines 5625-5811 (Szeliski, BMVC'99, section 4: a plane equation per layer, estimated from the
// pixels assigned to it, the masked pieces M_kl) and 3798-3846 (slides "Layered Stereo").
#include "stages/layered_stereo/disparity_planes.h"

#include <ceres/ceres.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include "stages/layered_stereo/layered_pair_internal.h"

namespace ibmr {
namespace layered_internal {

namespace {

// Points of a RANSAC round scored per hypothesis, and points given to Ceres per plane, at most:
// both are statistics of a large set, a subsample gives them to a fraction of a pixel.
constexpr size_t kScoringPoints = 2000;
constexpr size_t kRefinePoints = 200;
constexpr size_t kFitPoints = 5000;  // least-squares refits in RANSAC
// Initial disparities below this are treated as holes (see ValidPoints).
constexpr float kMinPlaneDisparity = 0.5f;
// An initial disparity that gives no point: below kMinPlaneDisparity, NaN or infinite.
inline bool IsHole(float d) { return !(d >= kMinPlaneDisparity) || !std::isfinite(d); }

struct PlanePoint {
  float x, y, d;
};

// The plane through three points, false when they are (nearly) collinear or the plane too steep.
bool PlaneThrough(const PlanePoint& p, const PlanePoint& q, const PlanePoint& r, DisparityPlane* plane) {
  Eigen::Matrix3d m;
  m << p.x, p.y, 1, q.x, q.y, 1, r.x, r.y, 1;
  const double det = m.determinant();  // twice the triangle's area, pixels^2
  if (std::fabs(det) < 8.0) return false;
  const Eigen::Vector3d abc = m.inverse() * Eigen::Vector3d(p.d, q.d, r.d);
  if (std::fabs(abc[0]) > kMaxGradient || std::fabs(abc[1]) > kMaxGradient) return false;
  plane->a = abc[0], plane->b = abc[1], plane->c = abc[2];
  return true;
}

// Least-squares plane through `indices` of `points` (centred coordinates for conditioning).
DisparityPlane FitLeastSquares(const std::vector<PlanePoint>& points, const std::vector<int>& indices) {
  double mx = 0, my = 0;
  for (int i : indices) mx += points[i].x, my += points[i].y;
  mx /= indices.size(), my /= indices.size();
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  for (int i : indices) {
    const Eigen::Vector3d row(points[i].x - mx, points[i].y - my, 1.0);
    ata += row * row.transpose();
    atb += row * points[i].d;
  }
  const Eigen::Vector3d abc = ata.ldlt().solve(atb);
  DisparityPlane plane;
  plane.a = abc[0], plane.b = abc[1], plane.c = abc[2] - abc[0] * mx - abc[1] * my;
  return plane;
}

// Residual d - plane(x, y) of one point, analytic derivatives, in centred coordinates.
class PlaneResidual : public ceres::SizedCostFunction<1, 3> {
 public:
  PlaneResidual(double x, double y, double d) : x_(x), y_(y), d_(d) {}
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const double* abc = parameters[0];
    residuals[0] = d_ - (abc[0] * x_ + abc[1] * y_ + abc[2]);
    if (jacobians != nullptr && jacobians[0] != nullptr) {
      jacobians[0][0] = -x_, jacobians[0][1] = -y_, jacobians[0][2] = -1.0;
    }
    return true;
  }

 private:
  double x_, y_, d_;
};

// Step 3: the plane minimising the Cauchy-robustified disparity residuals of the points
// (subsampled to kRefinePoints), starting from `plane`.
DisparityPlane RefinePlane(const DisparityPlane& plane, const std::vector<PlanePoint>& points,
                           const std::vector<int>& indices, double loss_scale) {
  if (indices.size() < 3) return plane;
  const size_t step = std::max<size_t>(1, indices.size() / kRefinePoints);
  double mx = 0, my = 0;
  size_t n = 0;
  for (size_t k = 0; k < indices.size(); k += step) mx += points[indices[k]].x, my += points[indices[k]].y, ++n;
  mx /= n, my /= n;
  double abc[3] = {plane.a, plane.b, plane.Disparity(mx, my)};
  ceres::Problem::Options problem_options;
  problem_options.cost_function_ownership = ceres::TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  ceres::CauchyLoss loss(loss_scale);
  for (size_t k = 0; k < indices.size(); k += step) {
    const PlanePoint& p = points[indices[k]];
    problem.AddResidualBlock(new PlaneResidual(p.x - mx, p.y - my, p.d), &loss, abc);
  }
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.max_num_iterations = 10;
  solver.logging_type = ceres::SILENT;
  solver.minimizer_progress_to_stdout = false;
  solver.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  if (!summary.IsSolutionUsable()) return plane;
  DisparityPlane refined = plane;
  refined.a = abc[0], refined.b = abc[1], refined.c = abc[2] - abc[0] * mx - abc[1] * my;
  return refined;
}

// Points not yet taken by a plane, contiguous (vectorised passes), with their index in `points`.
struct Remaining {
  std::vector<float> x, y, d;
  std::vector<int> index;
  std::vector<uint8_t> inlier;  // of the current plane
  size_t Size() const { return index.size(); }
};

// Marks the remaining points within `tolerance` of `plane`; returns their number.
size_t MarkInliers(const DisparityPlane& plane, double tolerance, Remaining* r) {
  const float a = static_cast<float>(plane.a), b = static_cast<float>(plane.b), c = static_cast<float>(plane.c);
  const float t = static_cast<float>(tolerance);
  const size_t n = r->Size();
  r->inlier.resize(n);
  const float* __restrict x = r->x.data();
  const float* __restrict y = r->y.data();
  const float* __restrict d = r->d.data();
  uint8_t* __restrict inlier = r->inlier.data();
  for (size_t i = 0; i < n; ++i) inlier[i] = std::fabs(d[i] - (a * x[i] + b * y[i] + c)) <= t ? 1 : 0;
  uint32_t count = 0;
  for (size_t i = 0; i < n; ++i) count += inlier[i];
  return count;
}

// Drops the marked points, and flags them in `removed` (by index into `points`).
void RemoveMarked(Remaining* r, std::vector<uint8_t>* removed) {
  size_t kept = 0;
  for (size_t i = 0; i < r->Size(); ++i) {
    if (r->inlier[i]) {
      (*removed)[r->index[i]] = 1;
      continue;
    }
    r->x[kept] = r->x[i], r->y[kept] = r->y[i], r->d[kept] = r->d[i], r->index[kept] = r->index[i];
    ++kept;
  }
  r->x.resize(kept), r->y.resize(kept), r->d.resize(kept), r->index.resize(kept);
}

// A uniform integer in [0, n) from 32 random bits (Lemire's multiply-shift; unlike
// std::uniform_int_distribution, the same sequence with every standard library).
uint32_t Below(std::mt19937& rng, size_t n) {
  return static_cast<uint32_t>((static_cast<uint64_t>(rng()) * n) >> 32);
}

// About `at_most` of the `count` marked points, evenly spread through the remaining ones, as indices
// into `points` (a subsample for fits: it skips whole stretches rather than testing every point).
std::vector<int> MarkedIndices(const Remaining& r, size_t count, size_t at_most) {
  const size_t step = std::max<size_t>(1, count / at_most);
  std::vector<int> out;
  out.reserve(at_most + 1);
  for (size_t i = 0; i < r.Size(); i += step) {
    if (r.inlier[i]) out.push_back(r.index[i]);
  }
  return out;
}

// The valid pixels of the initial disparity as points, and per pixel its point's index (-1: none).
// Winners below kMinPlaneDisparity are left out: at disparity 0, the end of the searched range,
// they are mostly pixels without a match (left border), not surfaces at infinity.
std::vector<PlanePoint> ValidPoints(const cv::Mat& initial, std::vector<int>* index_of) {
  std::vector<PlanePoint> points;
  index_of->assign(initial.total(), -1);
  for (int y = 0; y < initial.rows; ++y) {
    const float* d = initial.ptr<float>(y);
    for (int x = 0; x < initial.cols; ++x) {
      if (IsHole(d[x])) continue;
      (*index_of)[static_cast<size_t>(y) * initial.cols + x] = static_cast<int>(points.size());
      points.push_back({static_cast<float>(x), static_cast<float>(y), d[x]});
    }
  }
  return points;
}

// Up to kScoringPoints remaining points drawn at random (with replacement), padded to a multiple of 8.
struct ScoringSample {
  std::vector<float> x, y, d;
};
ScoringSample DrawScoringSample(const Remaining& remaining, std::mt19937* rng) {
  ScoringSample sample;
  for (size_t k = 0; k < std::min(kScoringPoints, remaining.Size()); ++k) {
    const size_t i = Below(*rng, remaining.Size());
    sample.x.push_back(remaining.x[i]), sample.y.push_back(remaining.y[i]), sample.d.push_back(remaining.d[i]);
  }
  while (sample.x.size() % 8 != 0) {
    sample.x.push_back(sample.x.back()), sample.y.push_back(sample.y.back()), sample.d.push_back(sample.d.back());
  }
  return sample;
}

// options.ransac_iterations minimal samples (fewer hypotheses where a sample is degenerate): a
// random remaining point and two more within sample_radius of it, on one surface far more often
// than uniformly drawn ones. Sequential, so that the seed fixes the result.
std::vector<DisparityPlane> DrawHypotheses(const std::vector<PlanePoint>& points, const std::vector<int>& index_of,
                                           const std::vector<uint8_t>& removed, const Remaining& remaining, int w,
                                           int h, const LayeredPairOptions& options, std::mt19937* rng) {
  const int radius = options.sample_radius;
  auto near_point = [&](const PlanePoint& p, int exclude) {
    for (int attempt = 0; attempt < 16; ++attempt) {
      const int x = static_cast<int>(p.x) + static_cast<int>(Below(*rng, 2 * radius + 1)) - radius;
      const int y = static_cast<int>(p.y) + static_cast<int>(Below(*rng, 2 * radius + 1)) - radius;
      if (x < 0 || y < 0 || x >= w || y >= h) continue;
      const int i = index_of[static_cast<size_t>(y) * w + x];
      if (i >= 0 && !removed[i] && i != exclude) return i;
    }
    return -1;
  };
  std::vector<DisparityPlane> hypotheses;
  for (int iteration = 0; iteration < options.ransac_iterations; ++iteration) {
    const int i0 = remaining.index[Below(*rng, remaining.Size())];
    const int i1 = near_point(points[i0], i0);
    const int i2 = i1 < 0 ? -1 : near_point(points[i0], i1);
    DisparityPlane hypothesis;
    if (i2 >= 0 && i2 != i0 && PlaneThrough(points[i0], points[i1], points[i2], &hypothesis)) {
      hypotheses.push_back(hypothesis);
    }
  }
  return hypotheses;
}

// The hypothesis with the lowest MSAC score (truncated squared residuals) on the sample; the
// hypotheses scored in parallel, eight partial sums each (vectorised).
DisparityPlane BestHypothesis(const std::vector<DisparityPlane>& hypotheses, const ScoringSample& sample,
                              double tolerance) {
  std::vector<float> scores(hypotheses.size());
  const float t2 = static_cast<float>(tolerance * tolerance);
  const size_t n = sample.x.size();
  const float* sx = sample.x.data();
  const float* sy = sample.y.data();
  const float* sd = sample.d.data();
  tbb::parallel_for(tbb::blocked_range<size_t>(0, hypotheses.size(), 16), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t k = range.begin(); k < range.end(); ++k) {
      const float a = static_cast<float>(hypotheses[k].a), b = static_cast<float>(hypotheses[k].b),
                  c = static_cast<float>(hypotheses[k].c);
      float partial[8] = {0, 0, 0, 0, 0, 0, 0, 0};
      for (size_t i = 0; i < n; i += 8) {
        for (int j = 0; j < 8; ++j) {
          const float r = sd[i + j] - (a * sx[i + j] + b * sy[i + j] + c);
          partial[j] += Min(r * r, t2);
        }
      }
      scores[k] = ((partial[0] + partial[1]) + (partial[2] + partial[3])) +
                  ((partial[4] + partial[5]) + (partial[6] + partial[7]));
    }
  });
  return hypotheses[std::min_element(scores.begin(), scores.end()) - scores.begin()];
}

}  // namespace

std::vector<DisparityPlane> FindPlanes(const cv::Mat& initial, const LayeredPairOptions& options) {
  std::vector<int> index_of;
  const std::vector<PlanePoint> points = ValidPoints(initial, &index_of);
  if (points.size() < 3) throw std::invalid_argument("LayeredStereoPair: fewer than 3 valid initial disparities");
  const size_t min_support =
      std::max<size_t>(3, static_cast<size_t>(std::ceil(options.min_layer_fraction * points.size())));
  const double tol = options.inlier_tolerance;
  std::mt19937 rng(options.seed);
  std::vector<uint8_t> removed(points.size(), 0);
  Remaining remaining;
  for (size_t i = 0; i < points.size(); ++i) {
    remaining.x.push_back(points[i].x), remaining.y.push_back(points[i].y), remaining.d.push_back(points[i].d);
    remaining.index.push_back(static_cast<int>(i));
  }
  std::vector<DisparityPlane> planes;
  std::vector<std::vector<int>> members;  // a subsample of each plane's inliers, for step 3
  while (static_cast<int>(planes.size()) < options.max_layers && remaining.Size() >= min_support) {
    const ScoringSample sample = DrawScoringSample(remaining, &rng);
    const std::vector<DisparityPlane> hypotheses =
        DrawHypotheses(points, index_of, removed, remaining, initial.cols, initial.rows, options, &rng);
    if (hypotheses.empty()) break;
    DisparityPlane best = BestHypothesis(hypotheses, sample, tol);
    for (int round = 0; round < 2; ++round) {  // least-squares refits on (a subsample of) the inliers
      const size_t count = MarkInliers(best, tol, &remaining);
      if (count < 3) break;
      best = FitLeastSquares(points, MarkedIndices(remaining, count, kFitPoints));
    }
    const size_t count = MarkInliers(best, tol, &remaining);
    if (count < min_support) break;
    best.support = count;
    planes.push_back(best);
    members.push_back(MarkedIndices(remaining, count, kRefinePoints));
    RemoveMarked(&remaining, &removed);
  }
  // Step 3, the planes in parallel.
  tbb::parallel_for(0, static_cast<int>(planes.size()), [&](int l) {
    const size_t support = planes[l].support;
    planes[l] = RefinePlane(planes[l], points, members[l], options.loss_scale);
    planes[l].support = support;
  });
  if (planes.empty()) {  // too few points for a layer of the minimum size: one plane through all
    std::vector<int> all(points.size());
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
    DisparityPlane plane = FitLeastSquares(points, all);
    plane.support = points.size();
    planes.push_back(plane);
  }
  return planes;
}

void RefitPlanes(const cv::Mat& labels, const std::vector<float>& disparity, const std::vector<uint8_t>& hole,
                 const LayeredPairOptions& options, std::vector<DisparityPlane>* planes) {
  const int w = labels.cols, h = labels.rows, nl = static_cast<int>(planes->size());
  std::vector<PlanePoint> points;
  std::vector<std::vector<int>> members(nl);
  for (int y = 0; y < h; ++y) {
    const int* label = labels.ptr<int>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (hole[i]) continue;
      const DisparityPlane& plane = (*planes)[label[x]];
      const float d = disparity[label[x] * static_cast<size_t>(w) * h + i];
      if (std::fabs(d - plane.Disparity(x, y)) > options.residual_range - 0.5 + 1e-3 && options.residual_range > 0) continue;
      members[label[x]].push_back(static_cast<int>(points.size()));
      points.push_back({static_cast<float>(x), static_cast<float>(y), d});
    }
  }
  tbb::parallel_for(0, nl, [&](int l) {
    if (members[l].size() < 3) return;
    (*planes)[l] = RefinePlane((*planes)[l], points, members[l], options.loss_scale);
  });
}

std::vector<uint8_t> Holes(const cv::Mat& initial) {
  std::vector<uint8_t> hole(initial.total());
  for (int y = 0; y < initial.rows; ++y) {
    const float* d = initial.ptr<float>(y);
    for (int x = 0; x < initial.cols; ++x) {
      hole[static_cast<size_t>(y) * initial.cols + x] = IsHole(d[x]);
    }
  }
  return hole;
}

}  // namespace layered_internal
}  // namespace ibmr
