// Two-view layered stereo (layered_pair.h): sequential RANSAC of disparity planes, Ceres
// refinement, plane-stabilised residual matching, Potts assignment with occlusion reasoning.
#include "stages/layered_stereo/layered_pair.h"

#include <ceres/ceres.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <random>
#include <stdexcept>

namespace ibmr {

namespace {

// Census window 9x7 (62 comparisons, as plane_sweep's two-view default): cost units 0..62.
constexpr int kCensusRadiusX = 4;
constexpr int kCensusRadiusY = 3;
// Points of a RANSAC round scored per hypothesis, and points given to Ceres per plane, at most:
// both are statistics of a large set, a subsample gives them to a fraction of a pixel.
constexpr size_t kScoringPoints = 2000;
constexpr size_t kRefinePoints = 200;
constexpr size_t kFitPoints = 5000;  // least-squares refits in RANSAC
// Steeper planes are not surfaces a stereo pair resolves (disparity gradient limit): rejected.
constexpr double kMaxGradient = 1.0;
// Initial disparities below this are treated as holes (see ValidPoints).
constexpr float kMinPlaneDisparity = 0.5f;
// A pixel is occluded under a layer when the right-image pixel it maps to shows a surface this many
// pixels of disparity nearer in the initial disparity.
constexpr float kOcclusionMargin = 1.0f;
constexpr int kMaxResidualSlices = 2 * 16 + 1;
// Cost of a negative disparity (behind the cameras' baseline at infinity): the worst census cost.
constexpr float kImpossibleCost = 62.f;

struct PlanePoint {
  float x, y, d;
};

// std::min by value: the compiler turns it into a vector min in loops (std::min returns a
// reference, whose select it does not if-convert).
inline float Min(float a, float b) { return b < a ? b : a; }

// std::lround without the library call (the baseline instruction set has no rounding instruction),
// saturated far beyond any image coordinate.
inline int RoundToInt(float v) {
  v = std::clamp(v, -1e9f, 1e9f);
  return static_cast<int>(v + (v >= 0.f ? 0.5f : -0.5f));
}

cv::Mat ToGray(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat gray;
  cv::cvtColor(image, gray, image.channels() == 4 ? cv::COLOR_BGRA2GRAY : cv::COLOR_BGR2GRAY);
  return gray;
}

// ------------------------------------------------------------------ step 2: sequential RANSAC

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
      if (!(d[x] >= kMinPlaneDisparity) || !std::isfinite(d[x])) continue;
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

// Steps 2 and 3 on the valid pixels of `initial`: sequential RANSAC (the plane with the best score,
// refitted by least squares to its inliers, takes them; again on the rest, until max_layers planes
// or too few points), then each plane refined robustly. Planes largest first.
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

// ------------------------------------------------------------------ step 4: costs per layer

// 9x7 census codes (bit set: neighbour brighter than the centre), image border replicated. The
// comparisons go offset by offset over whole rows into eight byte planes (16 pixels per vector
// instruction), which are then packed into one 64-bit code per pixel.
std::vector<uint64_t> Census(const cv::Mat& gray) {
  const int w = gray.cols, h = gray.rows;
  cv::Mat padded;
  cv::copyMakeBorder(gray, padded, kCensusRadiusY, kCensusRadiusY, kCensusRadiusX, kCensusRadiusX, cv::BORDER_REPLICATE);
  std::vector<uint64_t> codes(static_cast<size_t>(w) * h, 0);
  // Captured by value: a byte store may alias a captured reference, which would stop vectorisation.
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&codes, &padded, w](const tbb::blocked_range<int>& rows) {
    std::vector<uint8_t> planes(8 * static_cast<size_t>(w));  // per block of rows
    for (int y = rows.begin(); y < rows.end(); ++y) {
      std::fill(planes.begin(), planes.end(), 0);
      const uint8_t* __restrict centre = padded.ptr<uint8_t>(y + kCensusRadiusY) + kCensusRadiusX;
      int bit = 0;
      for (int dy = -kCensusRadiusY; dy <= kCensusRadiusY; ++dy) {
        const uint8_t* row = padded.ptr<uint8_t>(y + kCensusRadiusY + dy) + kCensusRadiusX;
        for (int dx = -kCensusRadiusX; dx <= kCensusRadiusX; ++dx) {
          if (dx == 0 && dy == 0) continue;
          const uint8_t* __restrict neighbour = row + dx;
          uint8_t* __restrict plane = planes.data() + static_cast<size_t>(bit / 8) * w;
          for (int x = 0; x < w; ++x) plane[x] = static_cast<uint8_t>((plane[x] << 1) | (neighbour[x] > centre[x] ? 1 : 0));
          ++bit;
        }
      }
      uint64_t* __restrict code = codes.data() + static_cast<size_t>(y) * w;
      for (int j = 0; j < 8; ++j) {
        const uint8_t* __restrict plane = planes.data() + static_cast<size_t>(j) * w;
        for (int x = 0; x < w; ++x) code[x] |= static_cast<uint64_t>(plane[x]) << (8 * j);
      }
    }
  });
  return codes;
}

struct MatchInput {
  int width = 0, height = 0;
  std::vector<uint64_t> left, right;  // census codes
};

// Row buffers of RawCostRow.
struct RawRowScratch {
  std::vector<int32_t> floor;   // floor of the plane's disparity
  std::vector<float> fraction;  // the disparity minus its floor
  std::vector<float> integer;   // (2R + 2) rows: costs at the integer disparities floor - R + k
};

// Costs at the integer disparities floor - R .. floor + R + 1: census Hamming distance, or
// `outside` left of the right image, or kImpossibleCost for a negative disparity. Inlined into a
// popcnt-enabled caller where available.
inline __attribute__((always_inline)) void IntegerCostsImpl(const uint64_t* __restrict left,
                                                           const uint64_t* __restrict right, int w, int range,
                                                           float outside, RawRowScratch* s) {
  static const auto kHamming = [] {  // Hamming distance as float, by table (no int-float conversion)
    std::array<float, 65> table{};
    for (int i = 0; i <= 64; ++i) table[i] = static_cast<float>(i);
    return table;
  }();
  const int32_t* __restrict floor = s->floor.data();
  for (int k = 0; k <= 2 * range + 1; ++k) {
    float* __restrict out = s->integer.data() + static_cast<size_t>(k) * w;
    for (int x = 0; x < w; ++x) {
      const int d = floor[x] - range + k, xr = x - d;
      out[x] = d < 0 ? kImpossibleCost : xr < 0 ? outside : kHamming[__builtin_popcountll(left[x] ^ right[xr])];
    }
  }
}

#if defined(__x86_64__) && defined(__GNUC__)
__attribute__((target("popcnt"))) void IntegerCostsPopcnt(const uint64_t* left, const uint64_t* right, int w,
                                                           int range, float outside, RawRowScratch* s) {
  IntegerCostsImpl(left, right, w, range, outside, s);
}
bool HavePopcnt() {
  static const bool have = [] {
    __builtin_cpu_init();  // may run before libgcc's own initialisation otherwise
    return __builtin_cpu_supports("popcnt") != 0;
  }();
  return have;
}
#endif
void IntegerCostsPortable(const uint64_t* left, const uint64_t* right, int w, int range, float outside,
                          RawRowScratch* s) {
  IntegerCostsImpl(left, right, w, range, outside, s);
}

// Raw (unaggregated) census costs of row y at disparities plane(x, y) + r, r = -R..R, linearly
// interpolated between the integer disparities around each (the plane-stabilised residual sweep):
// slices[k] gets residual k - R. A match left of the right image costs occlusion_cost, a negative
// disparity kImpossibleCost. Float passes over x (vectorised) around the integer pass.
void RawCostRow(const MatchInput& in, const DisparityPlane& plane, int y, int range, float occlusion_cost,
                RawRowScratch* s, float* const* slices) {
  const int w = in.width;
  s->floor.resize(w);
  s->fraction.resize(w);
  s->integer.resize(static_cast<size_t>(2 * range + 2) * w);
  const float e0 = static_cast<float>(std::clamp(plane.Disparity(0, y), -1e6, 1e6));
  const float a = static_cast<float>(std::clamp(plane.a, -kMaxGradient, kMaxGradient));
  int32_t* __restrict floor = s->floor.data();
  float* __restrict fraction = s->fraction.data();
  for (int x = 0; x < w; ++x) {
    const float e = e0 + a * x;
    const int32_t t = static_cast<int32_t>(e);  // towards zero; one less below zero
    floor[x] = t - (e < static_cast<float>(t) ? 1 : 0);
    fraction[x] = e - static_cast<float>(floor[x]);
  }
  const uint64_t* left = in.left.data() + static_cast<size_t>(y) * w;
  const uint64_t* right = in.right.data() + static_cast<size_t>(y) * w;
#if defined(__x86_64__) && defined(__GNUC__)
  if (HavePopcnt()) {
    IntegerCostsPopcnt(left, right, w, range, occlusion_cost, s);
  } else {
    IntegerCostsPortable(left, right, w, range, occlusion_cost, s);
  }
#else
  IntegerCostsPortable(left, right, w, range, occlusion_cost, s);
#endif
  for (int k = 0; k <= 2 * range; ++k) {
    const float* __restrict c0 = s->integer.data() + static_cast<size_t>(k) * w;
    const float* __restrict c1 = c0 + w;
    float* __restrict out = slices[k];
    for (int x = 0; x < w; ++x) out[x] = c0[x] + fraction[x] * (c1[x] - c0[x]);
  }
}

// Per-task working memory of LayerCosts, reused from layer to layer.
struct LayerScratch {
  std::vector<float> raw;   // per residual, one row of raw costs with r replicated values each side
  std::vector<float> hsum;  // per residual, an image of window sums along rows
  std::vector<float> vsum;  // per residual, one row of window sums (the running column sums)
  std::vector<float> best, best_k;  // one row each
  RawRowScratch raw_row;
};

// What LayerCosts needs besides the images: the initial disparity as a prior (0 at holes) and its
// weight per pixel (options.initial_weight, 0 at holes).
struct Prior {
  std::vector<float> disparity, weight;
};

// Raw costs of one layer (RawCostRow) summed over 2r+1 pixels along each row, border replicated:
// scratch->hsum, one image per residual.
void RowWindowSums(const MatchInput& in, const DisparityPlane& plane, const LayeredPairOptions& options,
                   LayerScratch* scratch) {
  const int w = in.width, h = in.height, n = 2 * options.residual_range + 1;
  const int r = options.window_radius, padded = w + 2 * r;
  const size_t image = static_cast<size_t>(w) * h;
  scratch->raw.resize(static_cast<size_t>(n) * padded);
  scratch->hsum.resize(n * image);
  float* rows[kMaxResidualSlices];
  for (int k = 0; k < n; ++k) rows[k] = scratch->raw.data() + static_cast<size_t>(k) * padded + r;
  for (int y = 0; y < h; ++y) {
    RawCostRow(in, plane, y, options.residual_range, static_cast<float>(options.occlusion_cost), &scratch->raw_row,
               rows);
    for (int k = 0; k < n; ++k) {
      float* row = rows[k];
      for (int j = 1; j <= r; ++j) row[-j] = row[0], row[w - 1 + j] = row[w - 1];
      float* __restrict out = scratch->hsum.data() + k * image + static_cast<size_t>(y) * w;
      const float* __restrict src = row - r;
      std::copy(src, src + w, out);
      for (int j = 1; j <= 2 * r; ++j) {
        for (int x = 0; x < w; ++x) out[x] += src[x + j];
      }
    }
  }
}

// Sub-pixel residual: where residual k is the best (best_k[x] == k), d[x] += the offset of the
// parabola's vertex through the costs c0, c1, c2 of residuals k - 1, k, k + 1, within half a pixel.
// Computed at every x and kept by a select, so that the loop is vectorised.
void AddParabolaOffsets(const float* __restrict c0, const float* __restrict c1, const float* __restrict c2,
                        const float* __restrict best_k, int k, int w, float* __restrict d) {
  const float kf = static_cast<float>(k);
  for (int x = 0; x < w; ++x) {
    const float curvature = c0[x] - 2.f * c1[x] + c2[x];
    const bool convex = curvature > 1e-6f;
    const float denominator = convex ? curvature : 1.f;  // (a variable: inline, it stops vectorisation)
    const float offset = 0.5f * (c0[x] - c2[x]) / denominator;
    const float clamped = Min(0.5f, -Min(0.5f, -offset));
    d[x] += (best_k[x] == kf) & convex ? clamped : 0.f;  // & not &&: no branch
  }
}

// Costs of one layer at every pixel i = y * width + x: the census cost over the (2r+1)^2 window
// following the plane, minimised over the residual (plus residual_penalty |residual|), plus the
// prior initial_weight * min(|d - initial d|, initial_truncation), written to cost[i]; the disparity
// at the minimum (plane + residual, + parabola sub-pixel) to disparity[i]. Row by row in passes
// over x that the compiler vectorises, except the census lookups.
void LayerCosts(const MatchInput& in, const DisparityPlane& plane, const LayeredPairOptions& options,
                const Prior& prior, LayerScratch* scratch, float* cost, float* disparity) {
  const int w = in.width, h = in.height, range = options.residual_range, n = 2 * range + 1;
  const int r = options.window_radius;
  const size_t image = static_cast<size_t>(w) * h;
  RowWindowSums(in, plane, options, scratch);
  scratch->vsum.resize(static_cast<size_t>(n) * w);
  scratch->best.resize(w);
  scratch->best_k.resize(w);
  // Column sums of the row sums, running down the image (border rows replicated).
  auto hsum_row = [&](int k, int y) {
    return scratch->hsum.data() + k * image + static_cast<size_t>(std::clamp(y, 0, h - 1)) * w;
  };
  auto vsum_row = [&](int k) { return scratch->vsum.data() + static_cast<size_t>(k) * w; };
  for (int k = 0; k < n; ++k) {
    float* v = vsum_row(k);
    std::fill(v, v + w, 0.f);
    for (int j = -r; j <= r; ++j) {
      const float* src = hsum_row(k, j);
      for (int x = 0; x < w; ++x) v[x] += src[x];
    }
  }
  const float scale = 1.f / ((2 * r + 1) * (2 * r + 1));
  const float penalty = static_cast<float>(options.residual_penalty);
  const float truncation = static_cast<float>(options.initial_truncation);
  float* __restrict best = scratch->best.data();
  float* __restrict best_k = scratch->best_k.data();
  for (int y = 0; y < h; ++y) {
    const float* centre = vsum_row(range);
    for (int x = 0; x < w; ++x) best[x] = centre[x] * scale, best_k[x] = static_cast<float>(range);
    for (int k = 0; k < n; ++k) {
      if (k == range) continue;
      const float* v = vsum_row(k);
      const float extra = penalty * std::abs(k - range), kf = static_cast<float>(k);
      for (int x = 0; x < w; ++x) {
        const float c = v[x] * scale + extra;
        best_k[x] = c < best[x] ? kf : best_k[x];
        best[x] = Min(best[x], c);
      }
    }
    const size_t row = static_cast<size_t>(y) * w;
    float* __restrict d = disparity + row;
    const float e0 = static_cast<float>(plane.Disparity(0, y)), a = static_cast<float>(plane.a);
    for (int x = 0; x < w; ++x) d[x] = e0 + a * x + (best_k[x] - range);
    for (int k = 1; options.subpixel && k + 1 < n; ++k) {
      AddParabolaOffsets(vsum_row(k - 1), vsum_row(k), vsum_row(k + 1), best_k, k, w, d);
    }
    const float* __restrict init = prior.disparity.data() + row;
    const float* __restrict weight = prior.weight.data() + row;
    float* __restrict out = cost + row;
    for (int x = 0; x < w; ++x) out[x] = best[x] + weight[x] * Min(std::fabs(init[x] - d[x]), truncation);
    if (y + 1 == h) break;
    for (int k = 0; k < n; ++k) {  // the next row's column sums
      float* __restrict v = vsum_row(k);
      const float* __restrict add = hsum_row(k, y + 1 + r);
      const float* __restrict sub = hsum_row(k, y - r);
      for (int x = 0; x < w; ++x) v[x] += add[x] - sub[x];
    }
  }
}

// ------------------------------------------------------------------ step 4: assignment

// Potts penalties of the edges to the right and below each pixel, weakened across grey-level edges.
void EdgePenalties(const cv::Mat& image, const LayeredPairOptions& options, std::vector<float>* right,
                   std::vector<float>* down) {
  const int w = image.cols, h = image.rows, channels = image.channels();
  right->assign(static_cast<size_t>(w) * h, 0.f);
  down->assign(static_cast<size_t>(w) * h, 0.f);
  const float strong = static_cast<float>(options.smoothness);
  const float weak = static_cast<float>(options.smoothness * options.edge_factor);
  auto step = [&](const uint8_t* p, const uint8_t* q) {
    int m = 0;
    for (int c = 0; c < channels; ++c) m = std::max(m, std::abs(p[c] - q[c]));
    return options.edge_threshold > 0 && m >= options.edge_threshold ? weak : strong;
  };
  tbb::parallel_for(0, h, [&](int y) {
    const uint8_t* row = image.ptr<uint8_t>(y);
    const uint8_t* below = image.ptr<uint8_t>(std::min(y + 1, h - 1));
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (x + 1 < w) (*right)[i] = step(row + x * channels, row + (x + 1) * channels);
      if (y + 1 < h) (*down)[i] = step(row + x * channels, below + x * channels);
    }
  });
}

// Minimum of v[0..n), four chains (the compiler keeps float min reductions scalar).
inline float MinOf(const float* v, int n) {
  float m0 = v[0], m1 = v[0], m2 = v[0], m3 = v[0];
  int l = 0;
  for (; l + 4 <= n; l += 4) {
    m0 = Min(m0, v[l]), m1 = Min(m1, v[l + 1]), m2 = Min(m2, v[l + 2]), m3 = Min(m3, v[l + 3]);
  }
  for (; l < n; ++l) m0 = Min(m0, v[l]);
  return Min(Min(m0, m1), Min(m2, m3));
}

// One step of a semi-global path: out[l] = cost[l] + min(prev[l], min prev + penalty) - min prev.
inline void PathStep(const float* __restrict cost, const float* __restrict prev, float penalty, int num_labels,
                     float* __restrict out) {
  const float m = MinOf(prev, num_labels), jump = m + penalty;
  for (int l = 0; l < num_labels; ++l) out[l] = cost[l] + Min(prev[l], jump) - m;
}

// Labels minimising sum_p cost(p, l_p) + sum_{pq} penalty_pq [l_p != l_q], approximately, by
// semi-global aggregation of the label costs (pixel-major: cost[i * num_labels + l]) along the 4
// image directions and winner-take-all. `sum` holds the horizontal paths' sums; each pass reads or
// writes it once (the passes are memory-bound).
void AssignLabels(const std::vector<float>& cost, int num_labels, int w, int h, const std::vector<float>& right,
                  const std::vector<float>& down, std::vector<float>* sum, cv::Mat* labels) {
  const int nl = num_labels;
  sum->resize(cost.size());
  float* total = sum->data();
  const float* c = cost.data();
  // Horizontal paths, a row per task: left to right into a row buffer, right to left added to it.
  tbb::parallel_for(0, h, [&](int y) {
    std::vector<float> forward(static_cast<size_t>(w) * nl), path(2 * nl);  // per row, not per pixel
    const size_t row = static_cast<size_t>(y) * w;
    std::copy(c + row * nl, c + (row + 1) * nl, forward.data());
    for (int x = 1; x < w; ++x) {
      PathStep(c + (row + x) * nl, forward.data() + (x - 1) * nl, right[row + x - 1], nl, forward.data() + x * nl);
    }
    float* prev = path.data();
    float* cur = prev + nl;
    std::copy(c + (row + w - 1) * nl, c + (row + w) * nl, prev);
    for (int l = 0; l < nl; ++l) total[(row + w - 1) * nl + l] = forward[(w - 1) * nl + l] + prev[l];
    for (int x = w - 2; x >= 0; --x) {
      const size_t i = row + x;
      PathStep(c + i * nl, prev, right[i], nl, cur);
      for (int l = 0; l < nl; ++l) total[i * nl + l] = forward[x * nl + l] + cur[l];
      std::swap(prev, cur);
    }
  });
  // Vertical paths, a block of columns per task: top to bottom into a block buffer, bottom to top
  // added to it and to the horizontal sums, and the label with the lowest total.
  labels->create(h, w, CV_32S);
  constexpr int kColumns = 16;
  // A block's downward paths (h * 16 * layers floats) in a buffer per thread: allocated per block,
  // they would be mapped and faulted in afresh each time.
  tbb::enumerable_thread_specific<std::vector<float>> buffers;
  tbb::parallel_for(0, (w + kColumns - 1) / kColumns, [&](int block) {
    const int x0 = block * kColumns, x1 = std::min(w, x0 + kColumns), bw = x1 - x0;
    const size_t row_size = static_cast<size_t>(bw) * nl;
    std::vector<float>& downward = buffers.local();
    downward.resize(static_cast<size_t>(h) * kColumns * nl);
    std::vector<float> path(2 * row_size);
    for (int x = x0; x < x1; ++x) std::copy(c + x * nl, c + (x + 1) * nl, downward.data() + (x - x0) * nl);
    for (int y = 1; y < h; ++y) {
      const size_t edge_row = static_cast<size_t>(y - 1) * w;
      for (int x = x0; x < x1; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        PathStep(c + i * nl, downward.data() + (y - 1) * row_size + (x - x0) * nl, down[edge_row + x], nl,
                 downward.data() + y * row_size + (x - x0) * nl);
      }
    }
    float* prev = path.data();
    float* cur = prev + row_size;
    for (int y = h - 1; y >= 0; --y) {
      int* label = labels->ptr<int>(y);
      for (int x = x0; x < x1; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        float* up = cur + (x - x0) * nl;
        if (y == h - 1) {
          std::copy(c + i * nl, c + (i + 1) * nl, up);
        } else {
          PathStep(c + i * nl, prev + (x - x0) * nl, down[i], nl, up);
        }
        const float* t = total + i * nl;
        const float* d = downward.data() + y * row_size + (x - x0) * nl;
        int best = 0;
        float best_sum = t[0] + d[0] + up[0];
        for (int l = 1; l < nl; ++l) {
          const float v = t[l] + d[l] + up[l];
          if (v < best_sum) best_sum = v, best = l;
        }
        label[x] = best;
      }
      std::swap(prev, cur);
    }
  });
}

// The right view's z-buffer: per row, the largest valid disparity of `disparity` (the initial one)
// landing on each right-image pixel, each pair of valid neighbours less than a pixel of disparity
// apart rasterised as a segment (so that a slanted surface leaves no gaps).
cv::Mat RightZBuffer(const cv::Mat& disparity, const std::vector<uint8_t>& hole) {
  const int w = disparity.cols, h = disparity.rows;
  cv::Mat zbuffer(h, w, CV_32F);
  tbb::parallel_for(0, h, [&](int y) {
    float* z = zbuffer.ptr<float>(y);
    std::fill(z, z + w, -std::numeric_limits<float>::infinity());
    const float* d = disparity.ptr<float>(y);
    const uint8_t* invalid = hole.data() + static_cast<size_t>(y) * w;
    for (int x = 0; x < w; ++x) {
      if (invalid[x]) continue;
      float lo = x - d[x], hi = lo, dmin = d[x];
      if (x + 1 < w && !invalid[x + 1] && std::fabs(d[x + 1] - d[x]) < 1.f) {
        lo = std::min(lo, x + 1 - d[x + 1]), hi = std::max(hi, x + 1 - d[x + 1]), dmin = std::min(d[x], d[x + 1]);
      }
      const int first = std::max(0, RoundToInt(lo));
      const int last = std::min(w - 1, RoundToInt(hi));
      for (int xr = first; xr <= last; ++xr) z[xr] = std::max(z[xr], dmin);
    }
  });
  return zbuffer;
}

// Occlusion reasoning at the pixels the initial left-right check rejected: under a layer whose match
// falls on a nearer surface of the initial disparity (zbuffer), the pixel is occluded and costs
// occlusion_cost. A farther layer is occluded there and a nearer is not, so such pixels join the
// background, where occluded regions belong.
void ApplyOcclusion(const std::vector<uint8_t>& hole, const cv::Mat& zbuffer, const std::vector<DisparityPlane>& planes,
                    float occlusion_cost, std::vector<float>* cost) {
  const int w = zbuffer.cols, h = zbuffer.rows, nl = static_cast<int>(planes.size());
  tbb::parallel_for(0, h, [&](int y) {
    const float* z = zbuffer.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (!hole[i]) continue;
      for (int l = 0; l < nl; ++l) {
        const float d = static_cast<float>(planes[l].Disparity(x, y));
        const int xr = RoundToInt(x - d);
        if (xr >= 0 && xr < w && z[xr] > d + kOcclusionMargin) (*cost)[i * nl + l] = occlusion_cost;
      }
    }
  });
}

// Step 5: each plane re-fitted (robustly) to the disparities of the pixels assigned to it, whose
// residual lies inside the searched range (at its ends the plane is off, not the pixel).
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

}  // namespace

bool LayeredPairOptions::Check(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error != nullptr) *error = message;
    return false;
  };
  auto in = [](double v, double lo, double hi) { return v >= lo && v <= hi; };  // false for NaN
  if (max_layers < 1 || max_layers > 64) return fail("max_layers = " + std::to_string(max_layers) + ": must be in [1, 64]");
  if (!(inlier_tolerance > 0 && inlier_tolerance <= 16))
    return fail("inlier_tolerance = " + std::to_string(inlier_tolerance) + ": must be in (0, 16] pixels");
  if (!(min_layer_fraction > 0 && min_layer_fraction < 1))
    return fail("min_layer_fraction = " + std::to_string(min_layer_fraction) + ": must be in (0, 1)");
  if (ransac_iterations < 1 || ransac_iterations > 100000)
    return fail("ransac_iterations = " + std::to_string(ransac_iterations) + ": must be in [1, 100000]");
  if (sample_radius < 2 || sample_radius > 4096)
    return fail("sample_radius = " + std::to_string(sample_radius) + ": must be in [2, 4096] pixels");
  if (!(loss_scale > 0 && loss_scale <= 16)) return fail("loss_scale = " + std::to_string(loss_scale) + ": must be in (0, 16] pixels");
  if (residual_range < 0 || residual_range > 16)
    return fail("residual_range = " + std::to_string(residual_range) + ": must be in [0, 16] pixels");
  if (!in(residual_penalty, 0, 1e6)) return fail("residual_penalty = " + std::to_string(residual_penalty) + ": must be >= 0");
  if (window_radius < 0 || window_radius > 10)
    return fail("window_radius = " + std::to_string(window_radius) + ": must be in [0, 10] pixels");
  if (!in(initial_weight, 0, 1e6)) return fail("initial_weight = " + std::to_string(initial_weight) + ": must be >= 0");
  if (!(initial_truncation > 0 && initial_truncation <= 1e6))
    return fail("initial_truncation = " + std::to_string(initial_truncation) + ": must be > 0 pixels");
  if (!in(smoothness, 0, 1e6)) return fail("smoothness = " + std::to_string(smoothness) + ": must be >= 0");
  if (!in(edge_threshold, 0, 1e6)) return fail("edge_threshold = " + std::to_string(edge_threshold) + ": must be >= 0");
  if (!in(edge_factor, 0, 1)) return fail("edge_factor = " + std::to_string(edge_factor) + ": must be in [0, 1]");
  if (!in(occlusion_cost, 0, 1e6)) return fail("occlusion_cost = " + std::to_string(occlusion_cost) + ": must be >= 0");
  if (refinement_passes < 0 || refinement_passes > 5)
    return fail("refinement_passes = " + std::to_string(refinement_passes) + ": must be in [0, 5]");
  return true;
}

namespace {

void CheckInputs(const cv::Mat& left, const cv::Mat& right, const cv::Mat& initial_disparity, int max_disparity,
                 const LayeredPairOptions& options) {
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument("LayeredStereoPair: " + error);
  if (left.empty() || left.size() != right.size() || left.type() != right.type() || left.depth() != CV_8U) {
    throw std::invalid_argument("LayeredStereoPair: left and right must be 8-bit images of one size and type");
  }
  if (initial_disparity.size() != left.size() || initial_disparity.type() != CV_32F) {
    throw std::invalid_argument("LayeredStereoPair: the initial disparity must be CV_32F of the images' size");
  }
  if (max_disparity < 1) throw std::invalid_argument("LayeredStereoPair: max_disparity must be >= 1");
}

// Pixels without an initial disparity (<= 0, NaN, or a winner at the range's end; see FindPlanes).
std::vector<uint8_t> Holes(const cv::Mat& initial) {
  std::vector<uint8_t> hole(initial.total());
  for (int y = 0; y < initial.rows; ++y) {
    const float* d = initial.ptr<float>(y);
    for (int x = 0; x < initial.cols; ++x) {
      hole[static_cast<size_t>(y) * initial.cols + x] = !(d[x] >= kMinPlaneDisparity) || !std::isfinite(d[x]);
    }
  }
  return hole;
}

Prior MakePrior(const cv::Mat& initial, const std::vector<uint8_t>& hole, double weight) {
  Prior prior;
  prior.disparity.resize(hole.size());
  prior.weight.resize(hole.size());
  for (int y = 0; y < initial.rows; ++y) {
    const float* d = initial.ptr<float>(y);
    for (int x = 0; x < initial.cols; ++x) {
      const size_t i = static_cast<size_t>(y) * initial.cols + x;
      prior.disparity[i] = hole[i] ? 0.f : d[x];
      prior.weight[i] = hole[i] ? 0.f : static_cast<float>(weight);
    }
  }
  return prior;
}

// Step 4's data costs of every layer: `cost` pixel-major (cost[i * layers + l], for the assignment),
// `disparity` layer-major (disparity[l * pixels + i]). The layers are computed in parallel, each
// into its own layer-major slice (no two tasks write one cache line), then transposed.
void AllLayerCosts(const MatchInput& match, const std::vector<DisparityPlane>& planes, const Prior& prior,
                   const LayeredPairOptions& options, tbb::enumerable_thread_specific<LayerScratch>* scratch,
                   std::vector<float>* layer_cost, std::vector<float>* cost, std::vector<float>* disparity) {
  const size_t n = static_cast<size_t>(match.width) * match.height;
  const int nl = static_cast<int>(planes.size());
  layer_cost->resize(n * nl);
  disparity->resize(n * nl);
  tbb::parallel_for(0, nl, [&](int l) {
    LayerCosts(match, planes[l], options, prior, &scratch->local(), layer_cost->data() + l * n,
               disparity->data() + l * n);
  });
  cost->resize(n * nl);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 4096), [&](const tbb::blocked_range<size_t>& pixels) {
    for (size_t i = pixels.begin(); i < pixels.end(); ++i) {
      for (int l = 0; l < nl; ++l) (*cost)[i * nl + l] = (*layer_cost)[l * n + i];
    }
  });
}

// Step 5's output: per pixel the disparity of its layer (plane + residual); the plane alone where the
// pixel is occluded under it (no match to refine by). Counts each layer's pixels into `support`.
cv::Mat OutputDisparity(const cv::Mat& labels, const std::vector<DisparityPlane>& planes,
                        const std::vector<float>& disparity, const std::vector<uint8_t>& hole, const cv::Mat& zbuffer,
                        int max_disparity, std::vector<size_t>* support) {
  const int w = labels.cols, h = labels.rows;
  const size_t n = static_cast<size_t>(w) * h;
  cv::Mat out(h, w, CV_32F);
  support->assign(planes.size(), 0);
  for (int y = 0; y < h; ++y) {
    const int* label = labels.ptr<int>(y);
    const float* z = zbuffer.ptr<float>(y);
    float* row = out.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const float plane = static_cast<float>(planes[label[x]].Disparity(x, y));
      const int xr = RoundToInt(x - plane);
      const bool occluded = xr < 0 || xr >= w || (hole[i] && z[xr] > plane + kOcclusionMargin);
      const float d = occluded ? plane : disparity[label[x] * n + i];
      // Disparity 0 is an answer, but "<= 0" means none in the output (as plane_sweep's).
      row[x] = std::clamp(d, 1e-3f, static_cast<float>(std::max(1, max_disparity - 1)));
      ++(*support)[label[x]];
    }
  }
  return out;
}

// Drops the layers no pixel chose and renumbers the labels; support = pixels assigned.
void DropUnusedLayers(const std::vector<size_t>& support, std::vector<DisparityPlane>* planes, cv::Mat* labels) {
  std::vector<int> renumber(planes->size(), -1);
  std::vector<DisparityPlane> kept;
  for (size_t l = 0; l < planes->size(); ++l) {
    if (support[l] == 0) continue;
    renumber[l] = static_cast<int>(kept.size());
    kept.push_back((*planes)[l]);
    kept.back().support = support[l];
  }
  for (int y = 0; y < labels->rows; ++y) {
    int* label = labels->ptr<int>(y);
    for (int x = 0; x < labels->cols; ++x) label[x] = renumber[label[x]];
  }
  *planes = std::move(kept);
}

}  // namespace

LayeredPairResult LayeredStereoPair(const cv::Mat& left_image, const cv::Mat& right_image,
                                    const cv::Mat& initial_disparity, int max_disparity,
                                    const LayeredPairOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  CheckInputs(left_image, right_image, initial_disparity, max_disparity, options);
  const int w = left_image.cols, h = left_image.rows;
  LayeredPairResult result;
  result.planes = FindPlanes(initial_disparity, options);  // steps 2 and 3

  MatchInput match;
  match.width = w, match.height = h;
  match.left = Census(ToGray(left_image));
  match.right = Census(ToGray(right_image));
  const std::vector<uint8_t> hole = Holes(initial_disparity);
  const Prior prior = MakePrior(initial_disparity, hole, options.initial_weight);
  const cv::Mat zbuffer = RightZBuffer(initial_disparity, hole);
  std::vector<float> right_penalty, down_penalty;
  EdgePenalties(left_image, options, &right_penalty, &down_penalty);

  std::vector<float> layer_cost, cost, disparity;
  tbb::enumerable_thread_specific<LayerScratch> scratch;
  cv::Mat labels;
  for (int pass = 0; pass <= options.refinement_passes; ++pass) {  // step 4 (and 5's refits)
    AllLayerCosts(match, result.planes, prior, options, &scratch, &layer_cost, &cost, &disparity);
    ApplyOcclusion(hole, zbuffer, result.planes, static_cast<float>(options.occlusion_cost), &cost);
    // The layer-major costs are spent: their memory holds the assignment's sums (no fresh pages).
    AssignLabels(cost, static_cast<int>(result.planes.size()), w, h, right_penalty, down_penalty, &layer_cost,
                 &labels);
    if (pass < options.refinement_passes) RefitPlanes(labels, disparity, hole, options, &result.planes);
  }
  std::vector<size_t> support;
  result.disparity = OutputDisparity(labels, result.planes, disparity, hole, zbuffer, max_disparity, &support);
  DropUnusedLayers(support, &result.planes, &labels);
  result.labels = labels;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

namespace {

int ParseInt(const std::string& key, const std::string& value) {
  size_t used = 0;
  long parsed = 0;
  try {
    parsed = std::stol(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.size() || parsed < std::numeric_limits<int>::min() ||
      parsed > std::numeric_limits<int>::max()) {
    throw std::invalid_argument("layered two-view option " + key + ": expected an integer, got '" + value + "'");
  }
  return static_cast<int>(parsed);
}

double ParseDouble(const std::string& key, const std::string& value) {
  size_t used = 0;
  double parsed = 0;
  try {
    parsed = std::stod(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != value.size()) {
    throw std::invalid_argument("layered two-view option " + key + ": expected a number, got '" + value + "'");
  }
  return parsed;
}

bool ParseBool(const std::string& key, const std::string& value) {
  if (value == "true") return true;
  if (value == "false") return false;
  throw std::invalid_argument("layered two-view option " + key + ": expected true or false, got '" + value + "'");
}

LayeredPairOptions ParseOptions(const TwoViewOptions& given) {
  LayeredPairOptions options;
  for (const auto& [key, value] : given) {
    if (key == "max_layers") options.max_layers = ParseInt(key, value);
    else if (key == "inlier_tolerance") options.inlier_tolerance = ParseDouble(key, value);
    else if (key == "min_layer_fraction") options.min_layer_fraction = ParseDouble(key, value);
    else if (key == "ransac_iterations") options.ransac_iterations = ParseInt(key, value);
    else if (key == "sample_radius") options.sample_radius = ParseInt(key, value);
    else if (key == "seed") options.seed = static_cast<uint32_t>(ParseInt(key, value));
    else if (key == "loss_scale") options.loss_scale = ParseDouble(key, value);
    else if (key == "residual_range") options.residual_range = ParseInt(key, value);
    else if (key == "residual_penalty") options.residual_penalty = ParseDouble(key, value);
    else if (key == "window_radius") options.window_radius = ParseInt(key, value);
    else if (key == "initial_weight") options.initial_weight = ParseDouble(key, value);
    else if (key == "initial_truncation") options.initial_truncation = ParseDouble(key, value);
    else if (key == "smoothness") options.smoothness = ParseDouble(key, value);
    else if (key == "edge_threshold") options.edge_threshold = ParseDouble(key, value);
    else if (key == "edge_factor") options.edge_factor = ParseDouble(key, value);
    else if (key == "occlusion_cost") options.occlusion_cost = ParseDouble(key, value);
    else if (key == "refinement_passes") options.refinement_passes = ParseInt(key, value);
    else if (key == "subpixel") options.subpixel = ParseBool(key, value);
    else throw std::invalid_argument("layered two-view: unknown option '" + key + "'");
  }
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument("layered two-view option " + error);
  return options;
}

}  // namespace

TwoViewOutput LayeredTwoView(const cv::Mat& left, const cv::Mat& right, int max_disparity,
                             const TwoViewOptions& given) {
  const LayeredPairOptions options = ParseOptions(given);  // before any work: bad options fail fast
  const TwoViewMethod plane_sweep = FindTwoViewMethod("plane_sweep");
  if (!plane_sweep) {
    throw std::runtime_error(
        "layered two-view: the initial disparity needs the \"plane_sweep\" two-view method, which no stage "
        "registered (register the plane_sweep stage first)");
  }
  const auto start = std::chrono::steady_clock::now();
  const TwoViewOutput initial = plane_sweep(left, right, max_disparity, {{"fill", "false"}});
  const double initial_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const LayeredPairResult result = LayeredStereoPair(left, right, initial.disparity, max_disparity, options);
  nlohmann::json planes = nlohmann::json::array();
  for (const DisparityPlane& p : result.planes) planes.push_back({{"a", p.a}, {"b", p.b}, {"c", p.c}, {"pixels", p.support}});
  TwoViewOutput output;
  output.disparity = result.disparity;
  output.facts = {{"layers", result.planes.size()}, {"planes", planes}, {"initial_seconds", initial_seconds},
                  {"layered_seconds", result.seconds}, {"seconds", initial_seconds + result.seconds}};
  return output;
}

}  // namespace ibmr
