// Multiple consistent depth maps: visibility, depth compatibility and rejection across views
// (seed 000 lines 3847-3894 and 5812-5950; refinement after lines 4399-4453). See multi_depth.h.
#include "stages/multi_depth/multi_depth.h"

#include "pipeline/core/depth_normals.h"
#include "pipeline/core/median.h"
#include "pipeline/core/residual_falloff.h"
#include "stages/multi_depth/geometric_consistency.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace ibmr {

namespace {

constexpr double kPi = 3.14159265358979323846;

// Per-pixel normalised rays (x, y, 1) of a camera, row-major; exact for distorted models too.
// A neighbour prepared for the inner loop: key-camera point -> neighbour-camera point.
struct PreparedNeighbor {
  const DepthView* view = nullptr;
  Eigen::Matrix3f rotation;     // neighbour_from_key
  Eigen::Vector3f translation;
  float fx = 0, fy = 0, cx = 0, cy = 0;  // intrinsics at the depth map's resolution
  bool distorted = false;
  double scale_x = 1, scale_y = 1;       // depth-map pixels per camera pixel
};

PreparedNeighbor Prepare(const DepthView& key, const DepthView& neighbor) {
  PreparedNeighbor p;
  p.view = &neighbor;
  const Rigid3d neighbor_from_key = neighbor.cam_from_world.Compose(key.cam_from_world.Inverse());
  p.rotation = neighbor_from_key.R().cast<float>();
  p.translation = neighbor_from_key.translation.cast<float>();
  p.scale_x = static_cast<double>(neighbor.depth.width) / neighbor.camera.width;
  p.scale_y = static_cast<double>(neighbor.depth.height) / neighbor.camera.height;
  p.fx = static_cast<float>(neighbor.camera.FocalX() * p.scale_x);
  p.fy = static_cast<float>(neighbor.camera.FocalY() * p.scale_y);
  p.cx = static_cast<float>(neighbor.camera.PrincipalX() * p.scale_x);
  p.cy = static_cast<float>(neighbor.camera.PrincipalY() * p.scale_y);
  p.distorted = neighbor.camera.HasDistortion();
  return p;
}

// Projects a neighbour-camera point to the neighbour's depth-map pixel coordinates.
inline Eigen::Vector2f Project(const PreparedNeighbor& n, const Eigen::Vector3f& x) {
  if (!n.distorted) return Eigen::Vector2f(n.fx * x.x() / x.z() + n.cx, n.fy * x.y() / x.z() + n.cy);
  const Eigen::Vector2d p = n.view->camera.ImgFromCam(x.cast<double>());
  return Eigen::Vector2f(static_cast<float>(p.x() * n.scale_x), static_cast<float>(p.y() * n.scale_y));
}

// Normalised ray (x, y, 1) of neighbour depth-map pixel coordinates (forward warping).
inline Eigen::Vector3f Unproject(const PreparedNeighbor& n, const Eigen::Vector2f& p) {
  if (!n.distorted) return Eigen::Vector3f((p.x() - n.cx) / n.fx, (p.y() - n.cy) / n.fy, 1.f);
  return n.view->camera.CamFromImg(Eigen::Vector2d(p.x() / n.scale_x, p.y() / n.scale_y)).cast<float>();
}

// The neighbour's depth at depth-map coordinates `p`: bilinear between the four nearest pixel
// centres when all are valid and within `smooth` relative spread (one surface), else the nearest
// pixel's (across a depth edge interpolation would invent a surface). 0 outside or unknown; the
// nearest pixel is returned in (*px, *py).
inline float DepthAt(const DepthMap& depth, const Eigen::Vector2f& p, float smooth, int* px, int* py) {
  // Tested as floats: a point just in front of the camera projects too far for an int.
  if (!(p.x() >= 0 && p.y() >= 0 && p.x() < depth.width && p.y() < depth.height)) {
    *px = *py = -1;
    return 0.f;
  }
  *px = static_cast<int>(p.x());
  *py = static_cast<int>(p.y());
  const float nearest = depth.At(*px, *py);
  const float fx = p.x() - 0.5f, fy = p.y() - 0.5f;
  const int x0 = static_cast<int>(std::floor(fx)), y0 = static_cast<int>(std::floor(fy));
  if (x0 < 0 || y0 < 0 || x0 + 1 >= depth.width || y0 + 1 >= depth.height || !IsValidDepth(nearest)) return nearest;
  const float d00 = depth.At(x0, y0), d10 = depth.At(x0 + 1, y0), d01 = depth.At(x0, y0 + 1), d11 = depth.At(x0 + 1, y0 + 1);
  if (!IsValidDepth(d00) || !IsValidDepth(d10) || !IsValidDepth(d01) || !IsValidDepth(d11)) return nearest;
  const float lo = std::min(std::min(d00, d10), std::min(d01, d11)), hi = std::max(std::max(d00, d10), std::max(d01, d11));
  if (hi > lo * (1 + smooth)) return nearest;
  const float ax = fx - x0, ay = fy - y0;
  return (1 - ay) * ((1 - ax) * d00 + ax * d10) + ay * ((1 - ax) * d01 + ax * d11);
}

inline float ConfidenceAt(const FloatMap& confidence, int x, int y) {
  return confidence.Empty() ? 1.f : UsableConfidence(confidence.At(x, y));
}

}  // namespace

bool MultiDepthOptions::Check(std::string* error) const {
  auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (!(depth_tolerance > 0 && depth_tolerance <= 0.5)) return fail("depth_tolerance: must be in (0, 0.5], got " + std::to_string(depth_tolerance));
  if (min_consistent_views < 1 || min_consistent_views > 64) return fail("min_consistent_views: must be in [1, 64], got " + std::to_string(min_consistent_views));
  if (!(violation_tolerance > 0 && violation_tolerance <= 1)) return fail("violation_tolerance: must be in (0, 1], got " + std::to_string(violation_tolerance));
  if (!(max_violation_ratio >= 0)) return fail("max_violation_ratio: must be >= 0, got " + std::to_string(max_violation_ratio));
  if (!(min_confidence >= 0 && min_confidence <= 1)) return fail("min_confidence: must be in [0, 1], got " + std::to_string(min_confidence));
  if (max_neighbors < 1 || max_neighbors > 64) return fail("max_neighbors: must be in [1, 64], got " + std::to_string(max_neighbors));
  if (max_neighbors < min_consistent_views) {
    return fail("max_neighbors: must be >= min_consistent_views (" + std::to_string(min_consistent_views) + "), got " + std::to_string(max_neighbors));
  }
  // A filled pixel needs min_consistent_views confirmations besides the view it came from.
  if (fill_from_neighbors && max_neighbors == min_consistent_views) {
    return fail("max_neighbors: must exceed min_consistent_views (" + std::to_string(min_consistent_views) +
                ") when fill_from_neighbors is on (a filled depth needs that many confirmations besides its source); "
                "got " + std::to_string(max_neighbors) + ": raise max_neighbors or set fill_from_neighbors: false");
  }
  if (!(max_view_angle_deg > 0 && max_view_angle_deg <= 180)) return fail("max_view_angle_deg: must be in (0, 180], got " + std::to_string(max_view_angle_deg));
  if (!(geometric_sigma >= 0 && geometric_sigma <= 0.5)) return fail("geometric_sigma: must be in [0, 0.5] (0: off), got " + std::to_string(geometric_sigma));
  if (!(view_agreement_reference >= 0 && view_agreement_reference <= 1))
    return fail("view_agreement_reference: must be in [0, 1] (0: off), got " + std::to_string(view_agreement_reference));
  if (surface_window < 0 || surface_window > 15) return fail("surface_window: must be in [0, 15] (0: off), got " + std::to_string(surface_window));
  if (!(surface_residual_scale > 0 && std::isfinite(surface_residual_scale))) {
    return fail("surface_residual_scale: must be > 0, got " + std::to_string(surface_residual_scale));
  }
  if (!(surface_floor >= 0 && surface_floor <= 1)) return fail("surface_floor: must be in [0, 1], got " + std::to_string(surface_floor));
  if (!(min_baseline_ratio >= 0 && min_baseline_ratio < 1)) return fail("min_baseline_ratio: must be in [0, 1), got " + std::to_string(min_baseline_ratio));
  return true;
}

std::vector<int> SelectNeighbors(const Image& key, const std::vector<const Image*>& candidates,
                                 const MultiDepthOptions& options) {
  const Eigen::Vector3d center = key.Center(), direction = key.ViewingDirection();
  std::vector<double> baselines;
  for (const Image* c : candidates) {
    if (c->name != key.name) baselines.push_back((c->Center() - center).norm());
  }
  if (baselines.empty()) return {};
  std::nth_element(baselines.begin(), baselines.begin() + baselines.size() / 2, baselines.end());
  const double min_baseline = options.min_baseline_ratio * baselines[baselines.size() / 2];
  const double cos_max = std::cos(options.max_view_angle_deg * kPi / 180.0);
  std::vector<std::pair<double, int>> ranked;  // (-cos angle, index)
  for (int i = 0; i < static_cast<int>(candidates.size()); ++i) {
    const Image* c = candidates[i];
    if (c->name == key.name) continue;
    const double cos_angle = c->ViewingDirection().dot(direction);
    if (cos_angle < cos_max || (c->Center() - center).norm() < min_baseline) continue;
    ranked.emplace_back(-cos_angle, i);
  }
  std::sort(ranked.begin(), ranked.end());
  std::vector<int> selected;
  for (size_t i = 0; i < ranked.size() && static_cast<int>(i) < options.max_neighbors; ++i) selected.push_back(ranked[i].second);
  return selected;
}

namespace {

// The votes of the neighbours on a key-camera point `ray * depth`.
struct Votes {
  int confirmations = 0;
  int violations = 0;
  double weight_sum = 0, weighted_depth = 0, confidence_sum = 0;
  float geometric = 1;  // GeometricConsistency of the neighbours that see the point (1: off or none)
  int seen = 0;         // neighbours that see it
};

// `needed` > 0 (the fill pass): only a point no neighbour sees through and at least `needed`
// confirm is of use, so the votes stop at the first violation, or once the neighbours left
// cannot bring the confirmations to `needed`; such a point's returned votes show the failure
// (a violation, or too few confirmations) and nothing else. On the synthetic forward-facing
// capture the fill pass votes on 45 M candidate depths, two thirds of them seen through.
// `tally` (the first pass; one per prepared neighbour, or null) counts each neighbour's agreement.
Votes Vote(const Eigen::Vector3f& ray, float depth, float confidence, const std::vector<PreparedNeighbor>& prepared,
           const MultiDepthOptions& options, int needed = 0, NeighborAgreement* tally = nullptr) {
  const float tolerance = static_cast<float>(options.depth_tolerance), smooth = 5 * tolerance;
  const float see_through = std::max(tolerance, static_cast<float>(options.violation_tolerance));
  Votes votes;
  GeometricConsistency consistency(static_cast<float>(options.geometric_sigma > 0 ? options.geometric_sigma : 1.0));
  votes.weight_sum = votes.confidence_sum = confidence;
  votes.weighted_depth = confidence * depth;
  const Eigen::Vector3f point = ray * depth;
  const int count = static_cast<int>(prepared.size());
  // The fill pass's relative depths of the neighbours that see the point, kept for the end: at
  // most 64 in the stage (max_neighbors' range); a longer list from another caller adds them as
  // they come, the same sums in the same order.
  const bool defer = needed > 0 && count <= 64;
  float seen_relative[64];
  int seen_count = 0;
  for (int i = 0; i < count; ++i) {
    if (needed > 0 && votes.confirmations + (count - i) < needed) break;
    const PreparedNeighbor& n = prepared[i];
    const Eigen::Vector3f in_neighbor = n.rotation * point + n.translation;
    if (in_neighbor.z() <= 0) continue;
    const Eigen::Vector2f p = Project(n, in_neighbor);
    int px = 0, py = 0;
    const float neighbor_depth = DepthAt(n.view->depth, p, smooth, &px, &py);
    if (!IsValidDepth(neighbor_depth)) continue;  // the neighbour knows nothing here
    const float neighbor_confidence = ConfidenceAt(n.view->confidence, px, py);
    if (neighbor_confidence < options.min_confidence) continue;
    const float relative = (neighbor_depth - in_neighbor.z()) / in_neighbor.z();
    // Seen (not behind a clearly nearer surface): the disagreement counts against the point.
    if (relative >= -see_through) {
      if (defer) {
        seen_relative[seen_count++] = relative;  // its exponential only if the point passes
      } else {
        const float term = consistency.Add(relative);
        if (tally != nullptr) {
          NeighborAgreement& t = tally[i];
          ++t.seen;
          t.consistency_sum += term;
          if (std::abs(relative) <= tolerance) ++t.confirmed;
        }
      }
    }
    if (relative < -tolerance) continue;  // visibility: a nearer surface hides the point from this view
    if (relative > see_through) {         // the neighbour saw through the point: free-space violation
      ++votes.violations;
      if (needed > 0) break;
      continue;
    }
    if (relative > tolerance) continue;   // neither agreement nor clearly free space
    ++votes.confirmations;
    votes.confidence_sum += neighbor_confidence;
    if (options.refine_depth) {
      // The neighbour's relative depth difference, carried over to the key's depth.
      votes.weighted_depth += neighbor_confidence * depth * (1 + relative);
      votes.weight_sum += neighbor_confidence;
    }
  }
  if (needed > 0 && (votes.violations > 0 || votes.confirmations < needed)) return votes;
  for (int i = 0; i < seen_count; ++i) consistency.Add(seen_relative[i]);  // in neighbour order, as above
  if (options.geometric_sigma > 0) votes.geometric = consistency.Value();
  votes.seen = consistency.seen();
  return votes;
}

// Each neighbour's confident samples forward-warped into the key view (nearest surface per key
// pixel, z-buffered): the candidate depths for key pixels without an accepted sample.
std::vector<DepthMap> WarpNeighbors(const std::vector<PreparedNeighbor>& prepared, const Camera& key_camera, int w, int h,
                                    const MultiDepthOptions& options) {
  const double sx = static_cast<double>(w) / key_camera.width, sy = static_cast<double>(h) / key_camera.height;
  const bool distorted = key_camera.HasDistortion();
  const float fx = static_cast<float>(key_camera.FocalX() * sx), fy = static_cast<float>(key_camera.FocalY() * sy);
  const float cx = static_cast<float>(key_camera.PrincipalX() * sx), cy = static_cast<float>(key_camera.PrincipalY() * sy);
  std::vector<DepthMap> warped;
  for (const PreparedNeighbor& n : prepared) {
    DepthMap z(w, h, 1, 0.f);
    const DepthMap& depth = n.view->depth;
    const Eigen::Matrix3f key_from_neighbor = n.rotation.transpose();
    for (int v = 0; v < depth.height; ++v) {
      for (int u = 0; u < depth.width; ++u) {
        const float d = depth.At(u, v);
        if (!IsValidDepth(d) || ConfidenceAt(n.view->confidence, u, v) < options.min_confidence) continue;
        const Eigen::Vector3f in_key = key_from_neighbor * (Unproject(n, Eigen::Vector2f(u + 0.5f, v + 0.5f)) * d - n.translation);
        if (in_key.z() <= 0) continue;
        Eigen::Vector2f p(fx * in_key.x() / in_key.z() + cx, fy * in_key.y() / in_key.z() + cy);
        if (distorted) p = (key_camera.ImgFromCam(in_key.cast<double>()).array() * Eigen::Array2d(sx, sy)).cast<float>().matrix();
        // Tested as floats: a point just in front of the key camera projects too far for an int.
        if (!(p.x() >= 0 && p.y() >= 0 && p.x() < w && p.y() < h)) continue;
        const int x = static_cast<int>(p.x()), y = static_cast<int>(p.y());
        float& target = z.At(x, y);
        if (target == 0.f || in_key.z() < target) target = in_key.z();
      }
    }
    warped.push_back(std::move(z));
  }
  return warped;
}

// Range of the accepted depths within `radius` of (x, y); false when there is none.
bool KeptRange(const DepthMap& depth, int x, int y, int radius, float* lo, float* hi) {
  *lo = 1e30f;
  *hi = 0;
  for (int v = std::max(0, y - radius); v <= std::min(depth.height - 1, y + radius); ++v) {
    for (int u = std::max(0, x - radius); u <= std::min(depth.width - 1, x + radius); ++u) {
      const float d = depth.At(u, v);
      if (d > 0) *lo = std::min(*lo, d), *hi = std::max(*hi, d);
    }
  }
  return *hi > 0;
}

// The confidence factor of a key view whose samples agree with its neighbours by `agreement` on
// average: agreement / view_agreement_reference, at most 1 (1 when the reference is 0: off).
float ViewFactor(double agreement, const MultiDepthOptions& options) {
  if (!(options.view_agreement_reference > 0)) return 1.f;
  return static_cast<float>(std::clamp(agreement / options.view_agreement_reference, 0.0, 1.0));
}

void ScaleConfidence(float factor, FloatMap* confidence) {
  if (factor == 1.f) return;
  for (float& c : confidence->data) c *= factor;
}

}  // namespace

namespace {

// MakeDepthConsistent before the surface factor.
MultiDepthResult ConsistentDepth(const DepthView& key, const std::vector<const DepthView*>& neighbors,
                                 const MultiDepthOptions& options) {
  const int w = key.depth.width, h = key.depth.height;
  MultiDepthResult result;
  result.depth = DepthMap(w, h, 1, 0.f);
  result.normals = FloatMap(w, h, 3, 0.f);
  result.confidence = FloatMap(w, h, 1, 0.f);
  const FloatMap key_normals = key.normals.Empty() ? NormalsFromDepth(key.camera, key.depth) : FloatMap();
  const FloatMap& normals = key.normals.Empty() ? key_normals : key.normals;
  const std::vector<Eigen::Vector3f> rays = PixelRays(key.camera, w, h);
  std::vector<PreparedNeighbor> prepared;
  for (const DepthView* n : neighbors) {
    if (n != nullptr && !n->depth.Empty()) prepared.push_back(Prepare(key, *n));
  }
  // The key view's agreement factor (ViewFactor), known after the first pass: the first pass's
  // confidences are scaled by it then, the fill pass's as they are stored.
  float view_factor = 1.f;
  auto store = [&](int x, int y, const Votes& votes, float depth, const Eigen::Vector3f& ray, Eigen::Vector3f normal) {
    // No weight (the key and its confirming views all of confidence 0, which min_confidence 0
    // lets through): the sample's own depth.
    const bool refine = options.refine_depth && votes.weight_sum > 0;
    result.depth.At(x, y) = refine ? static_cast<float>(votes.weighted_depth / votes.weight_sum) : depth;
    // The geometric mean of the photometric confidence (mean over the key and its confirming
    // views, diluted by the violations) and the geometric consistency: both in [0, 1], and on the
    // photometric scale downstream thresholds (fuse's min_confidence) were set on.
    const double photometric = votes.confidence_sum / (1 + votes.confirmations + votes.violations);
    // With geometric_sigma 0 (off) the photometric confidence as it was, not its square root.
    result.confidence.At(x, y) =
        static_cast<float>(options.geometric_sigma > 0 ? std::sqrt(photometric * votes.geometric) : photometric) * view_factor;
    if (!(normal.squaredNorm() > 0.25f)) normal = -ray.normalized();  // unknown: face the camera
    for (int c = 0; c < 3; ++c) result.normals.At(x, y, c) = normal[c];
  };
  MultiDepthStats& stats = result.stats;
  stats.neighbors.resize(prepared.size());
  for (size_t i = 0; i < prepared.size(); ++i) stats.neighbors[i].name = prepared[i].view->name;
  // The key view's agreement with its neighbours: the mean geometric consistency of its samples
  // that some neighbour sees, kept or not (a camera whose pose is off disagrees everywhere).
  double agreement_sum = 0;
  size_t agreement_samples = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float d = key.depth.At(x, y);
      if (!IsValidDepth(d)) continue;
      ++stats.input_samples;
      const float key_confidence = ConfidenceAt(key.confidence, x, y);
      if (key_confidence < options.min_confidence) {
        ++stats.low_confidence;
        continue;
      }
      const Eigen::Vector3f& ray = rays[static_cast<size_t>(y) * w + x];
      const Votes votes = Vote(ray, d, key_confidence, prepared, options, 0, stats.neighbors.data());
      if (votes.seen > 0) agreement_sum += votes.geometric, ++agreement_samples;
      if (votes.violations > options.max_violation_ratio * votes.confirmations) {
        ++stats.violated;
        continue;
      }
      if (votes.confirmations < options.min_consistent_views) {
        ++stats.unconfirmed;
        continue;
      }
      ++stats.kept;
      store(x, y, votes, d, ray, Eigen::Vector3f(normals.At(x, y, 0), normals.At(x, y, 1), normals.At(x, y, 2)));
    }
  }
  stats.view_agreement = agreement_samples > 0 ? agreement_sum / static_cast<double>(agreement_samples) : 1.0;
  view_factor = ViewFactor(stats.view_agreement, options);
  ScaleConfidence(view_factor, &result.confidence);
  if (!options.fill_from_neighbors || prepared.empty()) return result;

  // Depth compatibility fills the key pixels left empty where the key's own sample was missing or
  // an outlier (not where the key's stereo gave a low-confidence depth): the nearest
  // neighbour-warped candidate that other views confirm. Neighbours contribute confident samples
  // only, so an area that no view matched (untextured) stays empty.
  const std::vector<DepthMap> warped = WarpNeighbors(prepared, key.camera, w, h, options);
  const DepthMap first_pass = result.depth;
  // Pixels with an accepted depth within 2 pixels (KeptRange's window): only they can be filled, and
  // most empty pixels (background) are far from any, so they skip the candidate search.
  cv::Mat near_kept(h, w, CV_8U);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) near_kept.at<uint8_t>(y, x) = first_pass.At(x, y) > 0 ? 255 : 0;
  cv::dilate(near_kept, near_kept, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(5, 5)), cv::Point(-1, -1), 1,
             cv::BORDER_CONSTANT, cv::Scalar(0));
  const float tolerance = static_cast<float>(options.depth_tolerance);
  std::vector<float> candidates;
  std::vector<size_t> filled;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (result.depth.At(x, y) > 0) continue;
      if (IsValidDepth(key.depth.At(x, y)) && ConfidenceAt(key.confidence, x, y) < options.min_confidence) continue;
      if (near_kept.at<uint8_t>(y, x) == 0) continue;
      constexpr int kR = 1;  // candidates from a 3x3 window: forward warping leaves gaps
      candidates.clear();
      for (const DepthMap& z : warped) {
        for (int v = std::max(0, y - kR); v <= std::min(h - 1, y + kR); ++v) {
          for (int u = std::max(0, x - kR); u <= std::min(w - 1, x + kR); ++u) {
            const float c = z.At(u, v);
            if (c > 0) candidates.push_back(c);
          }
        }
      }
      if (candidates.empty()) continue;
      // Accepted own depths around the pixel bound the candidates (a weak smoothness term that
      // keeps surfaces hidden from the key, warped in from far neighbours, out of it); near_kept
      // says there is one.
      float lo = 0, hi = 0;
      KeptRange(first_pass, x, y, 2, &lo, &hi);
      lo *= 1 - 3 * tolerance, hi *= 1 + 3 * tolerance;
      candidates.erase(std::remove_if(candidates.begin(), candidates.end(), [&](float c) { return c < lo || c > hi; }),
                       candidates.end());
      std::sort(candidates.begin(), candidates.end());
      const Eigen::Vector3f& ray = rays[static_cast<size_t>(y) * w + x];
      for (size_t i = 0; i < candidates.size(); ++i) {
        const float candidate = candidates[i];
        if (i > 0 && candidate == candidates[i - 1]) continue;  // the same votes: failed already
        // Stricter than for the key's own samples (the key's photometry did not choose this depth):
        // besides its source, min_consistent_views views confirm it and none sees through it.
        const int needed = options.min_consistent_views + 1;
        const Votes votes = Vote(ray, candidate, 0.f, prepared, options, needed);  // depth from the confirming views only
        if (votes.violations > 0 || votes.confirmations < needed) continue;
        ++stats.filled;
        store(x, y, votes, candidate, ray, Eigen::Vector3f::Zero());
        filled.push_back(static_cast<size_t>(y) * w + x);
        break;
      }
    }
  }
  if (filled.empty()) return result;
  // Filled pixels have no photometric normal: take the normal of the final depth map there.
  const FloatMap filled_normals = NormalsFromDepth(key.camera, result.depth);
  for (const size_t i : filled) {
    const int x = static_cast<int>(i % w), y = static_cast<int>(i / w);
    if (filled_normals.At(x, y, 2) == 0.f) continue;  // no normal from the depth: keep facing the camera
    for (int c = 0; c < 3; ++c) result.normals.At(x, y, c) = filled_normals.At(x, y, c);
  }
  return result;
}

}  // namespace

void ApplySurfaceFactor(const DepthMap& depth, int radius, double scale, double floor, FloatMap* confidence) {
  if (radius <= 0 || confidence->Empty()) return;
  const int w = depth.width, h = depth.height;
  // Per pixel, the least-squares plane a + b dx + c dy through the inverse depths of the window's
  // pixels with a depth (inverse depth is affine in the image over any scene plane), and the
  // pixel's relative distance to it.
  std::vector<double> residual(static_cast<size_t>(w) * h, -1.0);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        const float z = depth.At(x, y);
        if (!(z > 0)) continue;
        Eigen::Matrix3d normal_matrix = Eigen::Matrix3d::Zero();
        Eigen::Vector3d rhs = Eigen::Vector3d::Zero();
        int n = 0;
        for (int dy = -radius; dy <= radius; ++dy) {
          const int v = y + dy;
          if (v < 0 || v >= h) continue;
          for (int dx = -radius; dx <= radius; ++dx) {
            const int u = x + dx;
            if (u < 0 || u >= w) continue;
            const float zz = depth.At(u, v);
            if (!(zz > 0)) continue;
            const Eigen::Vector3d a(1, dx, dy);
            normal_matrix += a * a.transpose();
            rhs += a / zz;
            ++n;
          }
        }
        if (n < 6) continue;  // too few to judge: the factor stays 1
        const Eigen::Vector3d plane = normal_matrix.ldlt().solve(rhs);
        // (kept in float, as measured: the factor's figures in multi_depth.h)
        residual[static_cast<size_t>(y) * w + x] = static_cast<float>(std::abs(1.0 / z - plane(0)) * z);
      }
    }
  });
  // At least 1e-4 (relative depth): a map as smooth as float rounding has no scatter to rank.
  const std::vector<float> factors = ResidualFalloff(residual, scale, 1e-4, floor);
  for (size_t i = 0; i < factors.size(); ++i) confidence->data[i] *= factors[i];
}

MultiDepthResult MakeDepthConsistent(const DepthView& key, const std::vector<const DepthView*>& neighbors,
                                     const MultiDepthOptions& options) {
  MultiDepthResult result = ConsistentDepth(key, neighbors, options);
  ApplySurfaceFactor(result.depth, options.surface_window, options.surface_residual_scale, options.surface_floor,
                     &result.confidence);
  return result;
}

bool ViewConfirmedFraction(const MultiDepthStats& stats, size_t min_seen, double* fraction) {
  std::vector<double> fractions;
  for (const NeighborAgreement& n : stats.neighbors) {
    if (n.seen > 0 && n.seen >= min_seen) fractions.push_back(static_cast<double>(n.confirmed) / static_cast<double>(n.seen));
  }
  if (fractions.empty()) return false;
  *fraction = Median(std::move(fractions));
  return true;
}

DepthAccuracy CompareDepth(const DepthMap& depth, const DepthMap& truth, double relative_tolerance) {
  DepthAccuracy accuracy;
  if (depth.Empty() || truth.Empty()) return accuracy;
  // Truth sampled at the estimate's pixel centres (nearest), so a downscaled map compares too.
  for (int y = 0; y < depth.height; ++y) {
    const int ty = std::min(truth.height - 1, static_cast<int>((y + 0.5) * truth.height / depth.height));
    for (int x = 0; x < depth.width; ++x) {
      const int tx = std::min(truth.width - 1, static_cast<int>((x + 0.5) * truth.width / depth.width));
      const float t = truth.At(tx, ty);
      if (!IsValidDepth(t)) continue;
      ++accuracy.truth_pixels;
      const float d = depth.At(x, y);
      if (!IsValidDepth(d)) continue;
      ++accuracy.estimated;
      if (std::abs(d - t) <= relative_tolerance * t) ++accuracy.within_tolerance;
    }
  }
  return accuracy;
}

}  // namespace ibmr
