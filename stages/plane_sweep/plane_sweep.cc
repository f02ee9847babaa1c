// Plane-sweep and two-view stereo on top of the sweep engine (see plane_sweep.h and
// sweep_engine.h for the method and the seed-paper sections).
#include "stages/plane_sweep/plane_sweep.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <stdexcept>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/noise_estimate.h"
#include "pipeline/core/plane_homography.h"
#include "stages/plane_sweep/sweep_engine.h"

namespace ibmr {

namespace {

constexpr double kPi = 3.14159265358979323846;

template <typename T>
bool Fail(std::string* error, const std::string& key, const std::string& what, T value) {
  if (error) *error = key + ": " + what + ", got " + std::to_string(value);
  return false;
}

sweep::EngineOptions ToEngine(const PlaneSweepOptions& o) {
  sweep::EngineOptions e;
  e.cost = o.cost == MatchCost::kCensus ? sweep::Cost::kCensus
           : o.cost == MatchCost::kSad  ? sweep::Cost::kSad
                                        : sweep::Cost::kZncc;
  e.census_radius_x = o.census_radius_x;
  e.census_radius_y = o.census_radius_y;
  e.census_sampling = o.census_bilinear ? sweep::CensusSampling::kBilinear : sweep::CensusSampling::kAlongEpipolar;
  e.window_radius = o.window_radius;
  e.best_k = o.best_k;
  e.semi_global = o.aggregation == CostAggregation::kSemiGlobal;
  e.paths = o.sgm_paths;
  e.p1 = o.p1;
  e.p2 = o.p2;
  e.p2_gamma = o.p2_gamma;
  e.sgm_threads = o.sgm_threads;
  return e;
}

cv::Mat ToGray(const cv::Mat& image) {
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else if (image.channels() == 4) {
    cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
  } else {
    gray = image;
  }
  if (gray.depth() != CV_8U) gray.convertTo(gray, CV_8U);
  return gray;
}

// Rejected pixels (<= 0) of row y take the smaller of the nearest valid disparities left and right
// on the row: occlusions belong to the background.
void FillHoles(cv::Mat* disparity, int y) {
  float* d = disparity->ptr<float>(y);
  const int w = disparity->cols;
  std::vector<float> left(w, -1.f);
  float last = -1.f;
  for (int x = 0; x < w; ++x) {
    if (d[x] > 0) last = d[x];
    left[x] = last;
  }
  last = -1.f;
  for (int x = w - 1; x >= 0; --x) {
    if (d[x] > 0) {
      last = d[x];
      continue;
    }
    const float l = left[x], r = last;
    d[x] = l > 0 && r > 0 ? std::min(l, r) : std::max(l, r);
  }
}

// cv::medianBlur (square window of radius r, borders replicated) in two bands of rows filtered in
// parallel (OpenCV filters a float image on one thread); each band carries r rows of its
// neighbour's as context, so the result equals the whole image's.
cv::Mat MedianInBands(const cv::Mat& image, int r) {
  cv::Mat out(image.size(), image.type());
  const int half = image.rows / 2;
  tbb::parallel_for(0, 2, [&](int band) {
    const int y0 = band == 0 ? 0 : half, y1 = band == 0 ? half : image.rows;
    const int c0 = std::max(0, y0 - r), c1 = std::min(image.rows, y1 + r);  // with context rows
    cv::Mat filtered;
    cv::medianBlur(image.rowRange(c0, c1), filtered, 2 * r + 1);
    filtered.rowRange(y0 - c0, y1 - c0).copyTo(out.rowRange(y0, y1));
  });
  return out;
}

// The certainty's scales of `options`.
sweep::CertaintyOptions Certainty(const PlaneSweepOptions& options) {
  sweep::CertaintyOptions certainty;
  certainty.margin_scale = options.confidence_scale;
  certainty.peak_ratio_scale = options.peak_ratio_scale;
  return certainty;
}

}  // namespace

bool PlaneSweepOptions::Check(std::string* error) const {
  if (num_planes < 2 || num_planes > 1024) return Fail(error, "num_planes", "must be in [2, 1024]", num_planes);
  if (num_neighbors < 1 || num_neighbors > 16) return Fail(error, "num_neighbors", "must be in [1, 16]", num_neighbors);
  if (best_k < 1 || best_k > num_neighbors) return Fail(error, "best_k", "must be in [1, num_neighbors]", best_k);
  if (census_radius_x < 1 || census_radius_x > 7) return Fail(error, "census_radius_x", "must be in [1, 7]", census_radius_x);
  if (census_radius_y < 1 || census_radius_y > 7) return Fail(error, "census_radius_y", "must be in [1, 7]", census_radius_y);
  const int bits = (2 * census_radius_x + 1) * (2 * census_radius_y + 1) - 1;
  if (bits > 64) return Fail(error, "census_radius_x", "census window must have at most 64 bits ((2rx+1)(2ry+1)-1)", bits);
  if (window_radius < 0 || window_radius > 15) return Fail(error, "window_radius", "must be in [0, 15]", window_radius);
  if (cost == MatchCost::kZncc && window_radius < 1)
    return Fail(error, "window_radius", "must be >= 1 for the zncc cost", window_radius);
  if (sgm_paths != 4 && sgm_paths != 8) return Fail(error, "sgm_paths", "must be 4 or 8", sgm_paths);
  if (sgm_threads != 1 && sgm_threads != 2) return Fail(error, "sgm_threads", "must be 1 or 2", sgm_threads);
  if (p1 < 0 || p1 > 2000) return Fail(error, "p1", "must be in [0, 2000]", p1);
  if (p2 < p1 || p2 > 6000) return Fail(error, "p2", "must be in [p1, 6000]", p2);
  if (!(p2_gamma >= 0)) return Fail(error, "p2_gamma", "must be >= 0", p2_gamma);
  if (!(confidence_scale > 0)) return Fail(error, "confidence_scale", "must be > 0", confidence_scale);
  if (!(peak_ratio_scale >= 0 && peak_ratio_scale <= 100))
    return Fail(error, "peak_ratio_scale", "must be in [0, 100] (0: off)", peak_ratio_scale);
  if (!(texture_scale >= 0)) return Fail(error, "texture_scale", "must be >= 0", texture_scale);
  if (!(noise_snr >= 0 && noise_snr <= 100)) return Fail(error, "noise_snr", "must be in [0, 100]", noise_snr);
  if (!(confidence_threshold >= 0 && confidence_threshold <= 1))
    return Fail(error, "confidence_threshold", "must be in [0, 1]", confidence_threshold);
  if (min_depth != -1 && !(min_depth > 0)) return Fail(error, "min_depth", "must be > 0 or -1", min_depth);
  if (max_depth != -1 && !(max_depth > 0 && (min_depth == -1 || max_depth > min_depth)))
    return Fail(error, "max_depth", "must be > min_depth (or -1)", max_depth);
  if (max_view_memory_mb < 0) return Fail(error, "max_view_memory_mb", "must be >= 0 (0: unlimited)", max_view_memory_mb);
  if (!(depth_margin >= 0 && depth_margin <= 2)) return Fail(error, "depth_margin", "must be in [0, 2]", depth_margin);
  if (!(near_quantile >= 0 && near_quantile <= 0.5)) return Fail(error, "near_quantile", "must be in [0, 0.5]", near_quantile);
  if (!(min_angle_deg >= 0 && min_angle_deg < max_angle_deg))
    return Fail(error, "min_angle_deg", "must be in [0, max_angle_deg)", min_angle_deg);
  if (!(max_angle_deg <= 180)) return Fail(error, "max_angle_deg", "must be <= 180", max_angle_deg);
  if (!(target_angle_deg >= min_angle_deg && target_angle_deg <= max_angle_deg))
    return Fail(error, "target_angle_deg", "must be in [min_angle_deg, max_angle_deg]", target_angle_deg);
  if (lr_tolerance < 0 || lr_tolerance > 16) return Fail(error, "lr_tolerance", "must be in [0, 16]", lr_tolerance);
  if (median_radius < 0 || median_radius > 2) return Fail(error, "median_radius", "must be in [0, 2]", median_radius);
  return true;
}

StereoPairResult StereoPair(const cv::Mat& left_image, const cv::Mat& right_image, int max_disparity,
                            const PlaneSweepOptions& options) {
  if (max_disparity < 1) {
    throw std::invalid_argument("StereoPair: max_disparity must be at least 1, got " + std::to_string(max_disparity));
  }
  if (left_image.empty() || left_image.size() != right_image.size()) {
    throw std::invalid_argument("StereoPair: a rectified pair needs two non-empty images of one size");
  }
  const auto start = std::chrono::steady_clock::now();
  const cv::Mat left = ToGray(left_image), right = ToGray(right_image);
  sweep::Neighbour neighbour;
  neighbour.gray = right;
  for (int d = 0; d < max_disparity; ++d) {
    Eigen::Matrix3d h = Eigen::Matrix3d::Identity();
    h(0, 2) = -d;
    neighbour.homographies.push_back(h);
  }
  sweep::EngineOptions engine = ToEngine(options);
  engine.best_k = 1;
  // Pooled buffers: the volume pages are faulted in once across calls.
  sweep::BufferLease buffers;
  sweep::CostVolume& volume = buffers->volume;
  sweep::Aggregated& aggregated = buffers->aggregated;
  StereoPairResult result;
  auto lap = [t = std::chrono::steady_clock::now()](const char* what) mutable {
    if (!std::getenv("IBMR_PLANE_SWEEP_TIMING")) return;
    const auto now = std::chrono::steady_clock::now();
    std::fprintf(stderr, "  %s %.1f ms\n", what, std::chrono::duration<double>(now - t).count() * 1e3);
    t = now;
  };
  result.evaluations = sweep::BuildCostVolume(left, {neighbour}, engine, &volume).evaluations;
  lap("cost volume");
  sweep::Aggregate(volume, left, engine, &aggregated);
  lap("aggregation");
  const sweep::Winners winners = sweep::WinnerTakeAll(aggregated, nullptr, sweep::CertaintyOptions{}, options.lr_check);
  lap("winner");
  cv::Mat disparity = winners.plane;
  tbb::parallel_for(0, disparity.rows, [&](int y) {
    float* d = disparity.ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      if (d[x] == 0.f) d[x] = 1e-3f;  // disparity 0 is an answer, but "<= 0" means none in the output
    }
    if (options.lr_check) {
      const int* r = winners.right.ptr<int>(y);
      for (int x = 0; x < disparity.cols; ++x) {
        const int di = static_cast<int>(std::lround(d[x]));
        const int xr = x - di;
        if (d[x] < 0 || xr < 0 || std::abs(r[xr] - di) > options.lr_tolerance) d[x] = -1.f;
      }
    }
    if (options.fill_holes) FillHoles(&disparity, y);
  });
  if (options.median_radius > 0) disparity = MedianInBands(disparity, options.median_radius);
  result.unfilled_fraction = 1.0 - static_cast<double>(cv::countNonZero(disparity > 0)) / disparity.total();
  result.disparity = disparity;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

double SweepFixedBytesPerPixel(int num_neighbors) {
  // Grey images (1 byte each), winners (8: plane, confidence), texture factor (4), plane ranges
  // (4), the output maps (4 + 12 + 4) and the float working copies of the texture factor (12).
  return 1.0 + num_neighbors + 8 + 4 + 4 + 20 + 12;
}

namespace {
// Entries per pixel of a cost volume of `num_planes` (padded to a multiple of 16, as the engine's).
int VolumeStride(int num_planes) { return (num_planes + 15) / 16 * 16; }
}  // namespace

double SweepVolumeBytesPerRow(int width, int num_planes) {
  return 2.0 * width * VolumeStride(num_planes) * sizeof(uint16_t);
}

int SweepBands(int width, int height, const PlaneSweepOptions& options, int64_t view_pixels) {
  if (options.max_view_memory_mb <= 0) return 1;
  // What the program itself holds (code, TBB, pools) is counted in the stage's estimate, not here.
  // The fixed maps cover the whole reference, however small the part swept.
  const double budget = options.max_view_memory_mb * 1048576.0 -
                        SweepFixedBytesPerPixel(options.num_neighbors) *
                            static_cast<double>(view_pixels >= 0 ? view_pixels : static_cast<int64_t>(width) * height);
  const double per_row = SweepVolumeBytesPerRow(width, options.num_planes);
  if (per_row * height <= budget) return 1;
  // A band's own rows plus its context rows must fit; at least 16 own rows however small the budget.
  const int rows = std::max(16, static_cast<int>(budget / per_row) - 2 * kBandContextRows);
  return (height + rows - 1) / rows;
}

PlaneSweepResult PlaneSweep(const SweepView& reference, const std::vector<SweepView>& neighbours, double near,
                            double far, const PlaneSweepOptions& options, const PixelDepthBounds* pixel_bounds) {
  const int w = reference.gray.cols, h = reference.gray.rows, np = options.num_planes;
  const InverseDepthPlanes planes{near, far, np};
  const double w_min = planes.MinInverse(), step = planes.Step();
  std::vector<double> inverse_depths(np);
  for (int p = 0; p < np; ++p) inverse_depths[p] = planes.InverseDepth(p);
  std::vector<sweep::Neighbour> engine_neighbours;
  for (const SweepView& view : neighbours) {
    sweep::Neighbour n;
    n.gray = view.gray;
    n.census = view.census;
    if (options.cost == MatchCost::kCensus &&
        sweep::IsHalfTurned(reference.cam_from_world.R(), view.cam_from_world.R())) {  // sweep_engine.h
      const int bits = (2 * options.census_radius_x + 1) * (2 * options.census_radius_y + 1) - 1;
      n.census = std::make_shared<const std::vector<uint64_t>>(sweep::ReverseCensusBits(
          view.census ? *view.census : sweep::CensusTransform(view.gray, options.census_radius_x, options.census_radius_y),
          bits));
    }
    n.homographies = PlaneHomographies(reference.camera, reference.cam_from_world, view.camera, view.cam_from_world,
                                       inverse_depths);
    engine_neighbours.push_back(std::move(n));
  }
  const sweep::EngineOptions engine = ToEngine(options);
  sweep::PlaneRanges ranges;  // of the whole reference
  if (pixel_bounds != nullptr) {
    const bool has_far = !pixel_bounds->far.Empty();
    if (pixel_bounds->near.width != w || pixel_bounds->near.height != h ||
        (has_far && (pixel_bounds->far.width != w || pixel_bounds->far.height != h))) {
      throw std::invalid_argument("PlaneSweep: pixel bounds must have the reference image's size");
    }
    // Planes are uniform in inverse depth: plane p holds 1/z = w_min + p * step.
    auto plane_of = [&](double z) { return (1.0 / z - w_min) / step; };
    ranges.first.resize(static_cast<size_t>(w) * h);
    ranges.last.resize(ranges.first.size());
    for (size_t i = 0; i < ranges.first.size(); ++i) {
      const double z_near = pixel_bounds->near.data[i] * (1.0 - options.depth_margin);
      const double z_far = has_far ? pixel_bounds->far.data[i] * (1.0 + options.depth_margin) : far;
      if (!(pixel_bounds->near.data[i] > 0) || !(z_far >= pixel_bounds->near.data[i])) {
        ranges.first[i] = 0, ranges.last[i] = static_cast<uint16_t>(np - 1);  // unbounded: every plane
        continue;
      }
      const double first = std::floor(plane_of(z_far)) - 1;
      const double last = z_near > 0 ? std::ceil(plane_of(z_near)) + 1 : np - 1;
      ranges.first[i] = static_cast<uint16_t>(std::clamp(first, 0.0, np - 1.0));
      ranges.last[i] = static_cast<uint16_t>(std::clamp(last, 0.0, np - 1.0));
      if (last < 0 || first > np - 1) ranges.first[i] = 1, ranges.last[i] = 0;  // outside the swept range
    }
  }
  const double noise_sigma = options.noise_snr > 0 ? EstimateNoiseSigma(reference.gray) : 0.0;
  // Texture factor: where the reference has no contrast over the census window, no cost curve
  // can be trusted (untextured surfaces, black backgrounds), however it looks.
  cv::Mat texture(h, w, CV_32F, cv::Scalar(1.f));
  if (options.texture_scale > 0) {
    cv::Mat f, mean, mean_sq;
    reference.gray.convertTo(f, CV_32F);
    const cv::Size window(2 * options.census_radius_x + 1, 2 * options.census_radius_y + 1);
    cv::boxFilter(f, mean, CV_32F, window, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
    cv::boxFilter(f.mul(f), mean_sq, CV_32F, window, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
    const float scale = static_cast<float>(options.texture_scale);
    const float noise = static_cast<float>(noise_sigma);
    const float noise_variance = noise * noise;
    const float noise_scale = static_cast<float>(options.noise_snr) * noise;
    for (int y = 0; y < h; ++y) {
      const float *mean_row = mean.ptr<float>(y), *mean_sq_row = mean_sq.ptr<float>(y);
      float* texture_row = texture.ptr<float>(y);
      for (int x = 0; x < w; ++x) {
        const float variance = std::max(0.f, mean_sq_row[x] - mean_row[x] * mean_row[x]);
        float factor = std::min(1.f, std::sqrt(variance) / scale);
        if (noise_scale > 0) factor = std::min(factor, std::sqrt(std::max(0.f, variance - noise_variance)) / noise_scale);
        texture_row[x] = factor;
      }
    }
  }
  // A pixel whose texture factor is below the confidence threshold cannot keep a depth, whatever
  // its cost curve. Where every pixel within three census radii of it is like that too, it is not
  // matched (one cost on every plane, flat in the semi-global passes, except where the box filter
  // mixes in a matched neighbour's curve); nearer to texture its curve still supports its
  // textured neighbours along the paths. On templeRing the black background is two thirds of
  // every view.
  if (options.texture_scale > 0 && options.confidence_threshold > 0) {
    if (ranges.first.empty()) {
      ranges.first.assign(static_cast<size_t>(w) * h, 0);
      ranges.last.assign(ranges.first.size(), static_cast<uint16_t>(np - 1));
    }
    cv::Mat untextured = texture < options.confidence_threshold;
    cv::erode(untextured, untextured,
              cv::getStructuringElement(cv::MORPH_RECT, cv::Size(6 * options.census_radius_x + 1, 6 * options.census_radius_y + 1)));
    for (int y = 0; y < h; ++y) {
      const uchar* t = untextured.ptr<uchar>(y);
      for (int x = 0; x < w; ++x) {
        if (!t[x]) continue;
        const size_t i = static_cast<size_t>(y) * w + x;
        ranges.first[i] = 1, ranges.last[i] = 0;
      }
    }
  }
  // The part of the view that can hold a winner: the bounding box of the matched pixels, widened
  // by twice the box filter's radius. Outside it every pixel is unmatched and so far from a
  // matched one that its filtered costs are flat (kOutsideCost on every plane), and a semi-global
  // path carries a flat curve unchanged (L = C: the penalties never apply), so the paths that
  // start at the part's edge reach its pixels with the sums they had when started at the image's:
  // the part's winners are those of the whole view (census, SAD and ZNCC alike: the engine
  // projects the part's pixels from the whole image's coordinates; SweepEngine.APartAtItsOrigin-
  // MatchesLikeTheWholeView). The filter, the semi-global passes, the winners and the volumes'
  // pages shrink with the part (on templeSparseRing it spans every row and 81-96% of a view).
  cv::Rect region(0, 0, w, h);
  if (!ranges.first.empty()) {
    int x_lo = w, x_hi = -1, y_lo = h, y_hi = -1;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        if (ranges.Empty(i, np)) continue;
        x_lo = std::min(x_lo, x), x_hi = std::max(x_hi, x), y_lo = std::min(y_lo, y), y_hi = std::max(y_hi, y);
      }
    }
    const int margin = 2 * options.window_radius;
    region = x_hi < 0 ? cv::Rect() : cv::Rect(cv::Point(x_lo - margin, y_lo - margin), cv::Point(x_hi + margin + 1, y_hi + margin + 1)) &
                                         cv::Rect(0, 0, w, h);
  }
  // Bands of rows of the part (one: all of it), each matched with context rows around it.
  PlaneSweepResult result;
  result.noise_sigma = noise_sigma;
  result.bands = region.empty() ? 0 : SweepBands(region.width, region.height, options, static_cast<int64_t>(w) * h);
  // A part's census codes are the whole view's (a window cut at the part's edge would differ).
  std::shared_ptr<const std::vector<uint64_t>> census = reference.census;
  const bool census_cost = options.cost == MatchCost::kCensus;
  if (census_cost && result.bands > 0 && (region.area() < w * h || result.bands > 1) &&
      (census == nullptr || census->size() != static_cast<size_t>(w) * h)) {
    census = std::make_shared<std::vector<uint64_t>>(
        sweep::CensusTransform(reference.gray, options.census_radius_x, options.census_radius_y));
  }
  result.full_evaluations = static_cast<int64_t>(np) * w * h * static_cast<int64_t>(neighbours.size());
  cv::Mat winner_plane(h, w, CV_32F, cv::Scalar(-1.f)), winner_confidence(h, w, CV_32F, cv::Scalar(0.f));
  sweep::BufferLease buffers;
  if (result.bands == 1) {
    // The pooled volumes keep the capacity of a whole view, so that the parts of different sizes
    // that views have reuse the pages earlier views faulted in (a vector that grows reallocates,
    // to as much as twice its size, and every page of the new block faults again: on
    // templeSparseRing 560 MB of first touches instead of 300). Only the pages a part touches
    // take memory.
    const size_t entries = static_cast<size_t>(w) * h * VolumeStride(np);
    for (LargeBuffer<uint16_t>* buffer : {&buffers->volume.data, &buffers->aggregated.a}) {
      if (buffer->capacity() >= entries) continue;
      buffer->clear();  // no contents to move
      buffer->reserve(entries);
    }
  }
  for (int band = 0; band < result.bands; ++band) {
    const int y0 = region.y + static_cast<int>(static_cast<int64_t>(band) * region.height / result.bands);
    const int y1 = region.y + static_cast<int>(static_cast<int64_t>(band + 1) * region.height / result.bands);
    const int c0 = result.bands == 1 ? region.y : std::max(region.y, y0 - kBandContextRows);
    const int c1 = result.bands == 1 ? region.br().y : std::min(region.br().y, y1 + kBandContextRows);
    const cv::Rect part(region.x, c0, region.width, c1 - c0);
    const bool whole = part == cv::Rect(0, 0, w, h);
    const cv::Mat part_gray = whole ? reference.gray : reference.gray(part).clone();
    sweep::PlaneRanges part_ranges;
    std::vector<uint64_t> part_census;
    for (int y = part.y; y < part.br().y; ++y) {
      const size_t begin = static_cast<size_t>(y) * w + part.x, end = begin + part.width;
      if (!ranges.first.empty()) {
        part_ranges.first.insert(part_ranges.first.end(), ranges.first.begin() + begin, ranges.first.begin() + end);
        part_ranges.last.insert(part_ranges.last.end(), ranges.last.begin() + begin, ranges.last.begin() + end);
      }
      if (!whole && census_cost) part_census.insert(part_census.end(), census->begin() + begin, census->begin() + end);
    }
    sweep::CostVolume& volume = buffers->volume;
    const sweep::VolumeWork work = sweep::BuildCostVolume(part_gray, engine_neighbours, engine, &volume,
                                                          part_ranges.first.empty() ? nullptr : &part_ranges,
                                                          whole ? census.get() : &part_census, part.tl());
    result.evaluations += work.evaluations;
    result.evaluation_seconds += work.seconds;
    result.box_filter_seconds += work.box_filter_seconds;
    LargeBuffer<uint16_t>& sums = buffers->aggregated.a;
    LargeBuffer<uint16_t>().swap(buffers->aggregated.b);  // pages a two-view sweep may have left
    // The semi-global passes run on this thread (and a helper of its own), outside any parallel
    // loop, so its CPU clock counts them alone.
    const double aggregation_started = sweep::ThreadCpuSeconds();
    const sweep::Winners winners = sweep::AggregateAndPick(volume, part_gray, engine, Certainty(options), &sums);
    if (engine.semi_global) result.aggregation_seconds += sweep::ThreadCpuSeconds() - aggregation_started;
    result.volume_bytes = std::max(result.volume_bytes, (volume.data.size() + sums.size()) * sizeof(uint16_t));
    const cv::Rect own(region.x, y0, region.width, y1 - y0);
    winners.plane.rowRange(y0 - c0, y1 - c0).copyTo(winner_plane(own));
    winners.confidence.rowRange(y0 - c0, y1 - c0).copyTo(winner_confidence(own));
    // Whether a depth exists: the margin and texture factors, as before the peak ratio. The peak
    // ratio says how ambiguous a match is, not whether there is one: an ambiguous pixel keeps
    // its depth at its lowered confidence and multi_depth's views decide (on the synthetic ring,
    // dropping them here lost fused completeness 0.9146 -> 0.9131). Decided per band, so that the
    // margins need not outlive it.
    for (int y = y0; y < y1; ++y) {
      float* plane = winner_plane.ptr<float>(y) + region.x;
      const float* margin = winners.margin.ptr<float>(y - c0);
      const float* texture_row = texture.ptr<float>(y) + region.x;
      for (int x = 0; x < region.width; ++x) {
        if (margin[x] * texture_row[x] < options.confidence_threshold) plane[x] = -1.f;
      }
    }
  }
  result.depth = DepthMap(w, h, 1, 0.f);
  result.confidence = FloatMap(w, h, 1, 0.f);
  size_t valid = 0;
  for (int y = 0; y < h; ++y) {
    const float* plane = winner_plane.ptr<float>(y);
    const float* conf = winner_confidence.ptr<float>(y);
    const float* texture_row = texture.ptr<float>(y);
    for (int x = 0; x < w; ++x) {
      result.confidence.At(x, y) = conf[x] * texture_row[x];
      if (plane[x] < 0) continue;  // no winner, or below the confidence threshold (above)
      if (!ranges.first.empty()) {  // smoothing can carry a winner out of the pixel's bounds: no surface there
        const size_t i = static_cast<size_t>(y) * w + x;
        if (plane[x] < ranges.first[i] - 0.5f || plane[x] > ranges.last[i] + 0.5f) continue;
      }
      // Planes are uniform in inverse depth, so the sub-pixel plane index maps linearly to 1/z.
      result.depth.At(x, y) = static_cast<float>(1.0 / (w_min + plane[x] * step));
      ++valid;
    }
  }
  result.valid_fraction = static_cast<double>(valid) / (static_cast<double>(w) * h);
  result.normals = NormalsFromDepth(result.depth, reference.camera);
  return result;
}

std::vector<int> SelectNeighbors(const SparseModel& model, const std::vector<int>& image_ids, int reference_index,
                                 double scene_depth, const PlaneSweepOptions& options) {
  const Image& ref = model.images.at(image_ids[reference_index]);
  const Eigen::Vector3d c_ref = ref.Center();
  const double sigma = std::max(5.0, 0.7 * options.target_angle_deg);
  auto weight = [&](double angle_deg) {
    if (angle_deg < options.min_angle_deg || angle_deg > options.max_angle_deg) return 0.0;
    const double t = (angle_deg - options.target_angle_deg) / sigma;
    return std::exp(-0.5 * t * t);
  };
  auto angle_at = [](const Eigen::Vector3d& x, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
    const Eigen::Vector3d u = (a - x).normalized(), v = (b - x).normalized();
    return std::acos(std::clamp(u.dot(v), -1.0, 1.0)) * 180.0 / kPi;
  };
  std::vector<double> score(image_ids.size(), 0.0);
  std::map<int, int> index_of;
  for (size_t i = 0; i < image_ids.size(); ++i) index_of[image_ids[i]] = static_cast<int>(i);
  for (const auto& [id, point] : model.points) {
    bool seen = false;
    for (const TrackElement& e : point.track) seen |= e.image_id == ref.image_id;
    if (!seen) continue;
    for (const TrackElement& e : point.track) {
      auto it = index_of.find(e.image_id);
      if (it == index_of.end() || it->second == reference_index) continue;
      score[it->second] += weight(angle_at(point.xyz, c_ref, model.images.at(e.image_id).Center()));
    }
  }
  const bool from_points = std::any_of(score.begin(), score.end(), [](double s) { return s > 0; });
  if (!from_points) {
    const Eigen::Vector3d x = c_ref + ref.ViewingDirection() * scene_depth;
    for (size_t i = 0; i < image_ids.size(); ++i) {
      if (static_cast<int>(i) == reference_index) continue;
      const Image& other = model.images.at(image_ids[i]);
      const Camera& cam = model.CameraOf(other);
      const Eigen::Vector3d xc = other.cam_from_world * x;
      if (xc.z() <= 0) continue;
      const Eigen::Vector2d uv = cam.ImgFromCam(xc);
      if (uv.x() < 0 || uv.y() < 0 || uv.x() > cam.width || uv.y() > cam.height) continue;
      score[i] = weight(angle_at(x, c_ref, other.Center()));
    }
  }
  std::vector<int> order;
  for (size_t i = 0; i < image_ids.size(); ++i)
    if (score[i] > 0) order.push_back(static_cast<int>(i));
  std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return score[a] > score[b]; });
  if (static_cast<int>(order.size()) > options.num_neighbors) order.resize(options.num_neighbors);
  return order;
}

bool DepthBoundsFromPoints(const SparseModel& model, const Image& image, double margin, double near_quantile, double* near,
                           double* far) {
  const Camera& camera = model.CameraOf(image);
  std::vector<double> observed, projected;
  for (const auto& [id, point] : model.points) {
    const Eigen::Vector3d xc = image.cam_from_world * point.xyz;
    if (xc.z() <= 0) continue;
    bool seen = false;
    for (const TrackElement& e : point.track) seen |= e.image_id == image.image_id;
    if (seen) observed.push_back(xc.z());
    const Eigen::Vector2d uv = camera.ImgFromCam(xc);
    if (uv.x() >= 0 && uv.y() >= 0 && uv.x() < camera.width && uv.y() < camera.height) projected.push_back(xc.z());
  }
  std::vector<double>& z = observed.size() >= 8 ? observed : projected;
  if (z.size() < 8) return false;
  std::sort(z.begin(), z.end());
  const double lo = z[static_cast<size_t>(near_quantile * (z.size() - 1))];
  const double hi = z[static_cast<size_t>(0.98 * (z.size() - 1))];
  *near = lo * (1.0 - std::min(0.9, margin));
  *far = hi * (1.0 + margin);
  return true;
}

FloatMap NormalsFromDepth(const DepthMap& depth, const Camera& camera) {
  const int w = depth.width, h = depth.height;
  FloatMap normals(w, h, 3, 0.f);
  const Eigen::Matrix3d k_inv = camera.K().inverse();
  auto point = [&](int x, int y) -> Eigen::Vector3d {
    return depth.At(x, y) * (k_inv * Eigen::Vector3d(x + 0.5, y + 0.5, 1.0));
  };
  auto valid = [&](int x, int y) { return x >= 0 && y >= 0 && x < w && y < h && IsValidDepth(depth.At(x, y)); };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (!valid(x, y)) continue;
      const Eigen::Vector3d p = point(x, y);
      Eigen::Vector3d dx, dy;
      if (valid(x + 1, y) && valid(x - 1, y)) dx = point(x + 1, y) - point(x - 1, y);
      else if (valid(x + 1, y)) dx = point(x + 1, y) - p;
      else if (valid(x - 1, y)) dx = p - point(x - 1, y);
      else continue;
      if (valid(x, y + 1) && valid(x, y - 1)) dy = point(x, y + 1) - point(x, y - 1);
      else if (valid(x, y + 1)) dy = point(x, y + 1) - p;
      else if (valid(x, y - 1)) dy = p - point(x, y - 1);
      else continue;
      Eigen::Vector3d n = dy.cross(dx);
      if (n.norm() <= 0) continue;
      n.normalize();
      if (n.dot(p) > 0) n = -n;
      for (int c = 0; c < 3; ++c) normals.At(x, y, c) = static_cast<float>(n[c]);
    }
  }
  return normals;
}

}  // namespace ibmr
