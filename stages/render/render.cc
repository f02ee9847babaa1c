// Unstructured Lumigraph Rendering, per pixel (seed 001, section 4.1 [U 107-161]): penalties,
// k-nearest blending weights, bilinear sampling; plane and mesh proxies. See render.h.
#include "stages/render/render.h"

#include <tbb/blocked_range.h>
#include <Eigen/Eigenvalues>
#include <Eigen/Cholesky>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/rasterizer.h"
#include "stages/render/arc_tangent_bound.h"

namespace ibmr {

namespace {

// Penalties below this count as zero (the desired ray passes through the camera centre).
constexpr double kZeroPenalty = 1e-12;


// World direction of the ray through pixel (x, y) (not normalised; camera z component = 1).
Eigen::Vector3d RayDirection(const Camera& camera, const Eigen::Matrix3d& world_from_cam_rotation, double x,
                             double y) {
  const Eigen::Vector3d in_cam((x - camera.PrincipalX()) / camera.FocalX(), (y - camera.PrincipalY()) / camera.FocalY(),
                               1.0);
  return world_from_cam_rotation * in_cam;
}

// Bilinear sample of a CV_8UC3 image at COLMAP pixel coordinates (u, v), added with `weight`.
inline void AddBilinear(const cv::Mat& image, double u, double v, double weight, double* bgr) {
  const double x = u - 0.5, y = v - 0.5;
  int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const double ax = x - x0, ay = y - y0;
  x0 = std::clamp(x0, 0, image.cols - 1);
  y0 = std::clamp(y0, 0, image.rows - 1);
  const int x1 = std::min(x0 + 1, image.cols - 1), y1 = std::min(y0 + 1, image.rows - 1);
  const uint8_t* r0 = image.ptr<uint8_t>(y0);
  const uint8_t* r1 = image.ptr<uint8_t>(y1);
  const double w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay, w11 = ax * ay;
  for (int c = 0; c < 3; ++c) {
    bgr[c] += weight * (w00 * r0[3 * x0 + c] + w01 * r0[3 * x1 + c] + w10 * r1[3 * x0 + c] + w11 * r1[3 * x1 + c]);
  }
}

}  // namespace

bool VisibleInSource(const DepthMap& depth, double u, double v, double z, double eps) {
  const int x0 = std::clamp(static_cast<int>(std::floor(u - 0.5)), 0, depth.width - 1);
  const int y0 = std::clamp(static_cast<int>(std::floor(v - 0.5)), 0, depth.height - 1);
  const int x1 = std::min(x0 + 1, depth.width - 1), y1 = std::min(y0 + 1, depth.height - 1);
  const double tolerance = eps * z;
  for (const float d : {depth.At(x0, y0), depth.At(x1, y0), depth.At(x0, y1), depth.At(x1, y1)}) {
    if (!IsValidDepth(d) || std::abs(z - d) > tolerance) return false;
  }
  return true;
}

bool RenderOptions::Check(std::string* error) const {
  if (k < 2 || k > 64) {
    *error = "k: must be in [2, 64], got " + std::to_string(k);
    return false;
  }
  const std::pair<const char*, double> weights[] = {{"alpha", alpha}, {"beta", beta}, {"gamma", gamma}};
  for (const auto& [key, value] : weights) {
    if (!(value >= 0) || !std::isfinite(value)) {
      *error = std::string(key) + ": must be a finite number >= 0, got " + std::to_string(value);
      return false;
    }
  }
  if (alpha + beta + gamma <= 0) {
    *error = "alpha: alpha, beta and gamma are all 0; at least one penalty must count";
    return false;
  }
  if (!(fov_margin > 0 && fov_margin < 0.5)) {
    *error = "fov_margin: must be in (0, 0.5), got " + std::to_string(fov_margin);
    return false;
  }
  if (!(max_penalty > 0) || !std::isfinite(max_penalty)) {
    *error = "max_penalty: must be a finite number > 0, got " + std::to_string(max_penalty);
    return false;
  }
  if (!(visibility_epsilon > 0 && visibility_epsilon < 1)) {
    *error = "visibility_epsilon: must be in (0, 1), got " + std::to_string(visibility_epsilon);
    return false;
  }
  if (proxy_extend_px < 0 || proxy_extend_px > 16) {
    *error = "proxy_extend_px: must be in [0, 16], got " + std::to_string(proxy_extend_px);
    return false;
  }
  return true;
}

ProxySurface PlaneSurface(const Plane& plane, const Camera& camera, const Rigid3d& cam_from_world) {
  ProxySurface surface;
  surface.width = camera.width;
  surface.height = camera.height;
  surface.points = FloatMap(camera.width, camera.height, 3);
  surface.hit.assign(static_cast<size_t>(camera.width) * camera.height, 0);
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  const Eigen::Matrix3d rotation = world_from_cam.R();
  const Eigen::Vector3d center = world_from_cam.translation;
  const double offset = plane.normal.dot(plane.point - center);
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const Eigen::Vector3d direction = RayDirection(camera, rotation, x + 0.5, y + 0.5);
      const double denom = plane.normal.dot(direction);
      if (std::abs(denom) < 1e-12) continue;
      const double t = offset / denom;
      if (!(t > 0) || !std::isfinite(t)) continue;
      const Eigen::Vector3d p = center + t * direction;
      for (int c = 0; c < 3; ++c) surface.points.At(x, y, c) = static_cast<float>(p[c]);
      surface.hit[static_cast<size_t>(y) * camera.width + x] = 1;
    }
  }
  return surface;
}

namespace {

// World points of the pixels with a valid depth.
ProxySurface SurfaceFromDepth(const DepthMap& depth, const Camera& camera, const Rigid3d& cam_from_world) {
  ProxySurface surface;
  surface.width = camera.width;
  surface.height = camera.height;
  surface.points = FloatMap(camera.width, camera.height, 3);
  surface.hit.assign(static_cast<size_t>(camera.width) * camera.height, 0);
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const float z = depth.At(x, y);
      if (!IsValidDepth(z)) continue;
      const Eigen::Vector3d in_cam = camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)) * static_cast<double>(z);
      const Eigen::Vector3d p = world_from_cam * in_cam;
      for (int c = 0; c < 3; ++c) surface.points.At(x, y, c) = static_cast<float>(p[c]);
      surface.hit[static_cast<size_t>(y) * camera.width + x] = 1;
    }
  }
  return surface;
}

}  // namespace

ProxySurface MeshSurface(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world) {
  return SurfaceFromDepth(Rasterize(mesh, camera, cam_from_world).depth, camera, cam_from_world);
}

DepthMap MeshDepth(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world) {
  return Rasterize(mesh, camera, cam_from_world).depth;
}

DepthMap MeshDepth(const std::vector<const TriangleMesh*>& layers, const Camera& camera, const Rigid3d& cam_from_world,
                   int extend_px) {
  DepthMap depth;
  for (const TriangleMesh* mesh : layers) {
    const DepthMap next = MeshDepth(*mesh, camera, cam_from_world);
    if (depth.Empty()) {
      depth = next;
      continue;
    }
    for (size_t i = 0; i < depth.data.size(); ++i) {
      if (!IsValidDepth(depth.data[i])) depth.data[i] = next.data[i];
    }
  }
  ExtendIntoHoles(&depth, extend_px);
  return depth;
}

std::vector<int> HoleSources(const DepthMap& depth, int radius) {
  const int w = depth.width, h = depth.height;
  const size_t n = static_cast<size_t>(w) * h;
  std::vector<int> source(n);
  cv::Mat valid(h, w, CV_8UC1);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 32), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      uint8_t* row = valid.ptr<uint8_t>(y);
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        row[x] = IsValidDepth(depth.data[i]);
        source[i] = row[x] ? static_cast<int>(i) : -1;
      }
    }
  });
  if (radius <= 0 || n == 0) return source;
  // Each step, a hole next to a pixel with a depth (8-neighbourhood) takes the front-most such
  // neighbour's depth and source (the first of equals in row-major order): a 3x3 erosion of the
  // depths with holes as +infinity. Only the holes next to a pixel that gained its depth in the
  // step before can change (a hole next to an older one took its depth then), so each step visits
  // that frontier, not the image: the first frontier is the holes a 3x3 dilation of the covered
  // pixels reaches.
  cv::Mat reached;
  cv::dilate(valid, reached, cv::Mat::ones(3, 3, CV_8UC1));
  std::vector<int> frontier;
  for (int y = 0; y < h; ++y) {
    const uint8_t* hit = valid.ptr<uint8_t>(y);
    const uint8_t* near = reached.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) {
      if (near[x] && !hit[x]) frontier.push_back(y * w + x);
    }
  }
  std::vector<uint8_t> queued(n, 0);  // in the next step's frontier already
  std::vector<std::pair<int, int>> taken;  // this step's (hole, source), applied after the step
  std::vector<int> next;
  for (int step = 0; step < radius && !frontier.empty(); ++step) {
    taken.clear();
    for (const int i : frontier) {
      const int x = i % w, y = i / w;
      float best = std::numeric_limits<float>::infinity();
      int best_source = -1;
      for (int ny = std::max(0, y - 1); ny <= std::min(h - 1, y + 1); ++ny) {
        for (int nx = std::max(0, x - 1); nx <= std::min(w - 1, x + 1); ++nx) {
          const int s = source[static_cast<size_t>(ny) * w + nx];
          if (s >= 0 && depth.data[s] < best) best = depth.data[s], best_source = s;
        }
      }
      if (best_source >= 0) taken.emplace_back(i, best_source);
    }
    for (const auto& [i, s] : taken) source[i] = s;
    if (step + 1 == radius) break;
    next.clear();
    for (const auto& [i, s] : taken) {
      const int x = i % w, y = i / w;
      for (int ny = std::max(0, y - 1); ny <= std::min(h - 1, y + 1); ++ny) {
        for (int nx = std::max(0, x - 1); nx <= std::min(w - 1, x + 1); ++nx) {
          const int j = ny * w + nx;
          if (source[j] < 0 && !queued[j]) queued[j] = 1, next.push_back(j);
        }
      }
    }
    for (const int j : next) queued[j] = 0;
    frontier.swap(next);
  }
  return source;
}

void ExtendIntoHoles(DepthMap* depth, int radius) {
  if (radius <= 0 || depth->Empty()) return;
  const std::vector<int> source = HoleSources(*depth, radius);
  // A hole's source is a pixel the mesh covers, whose depth this loop never changes: rows in any order.
  tbb::parallel_for(tbb::blocked_range<size_t>(0, source.size(), 1 << 15), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i < range.end(); ++i) {
      if (source[i] >= 0 && source[i] != static_cast<int>(i)) depth->data[i] = depth->data[source[i]];
    }
  });
}

std::vector<uint8_t> ExtendIntoHoles(RasterResult* raster, int radius) {
  if (radius <= 0 || raster->depth.Empty()) return {};
  std::vector<uint8_t> extended(raster->face_id.size(), 0);
  const std::vector<int> source = HoleSources(raster->depth, radius);
  const int w = raster->depth.width;
  // As above: each hole copies from a covered pixel, which stays as it is.
  tbb::parallel_for(tbb::blocked_range<size_t>(0, source.size(), 1 << 15), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i < range.end(); ++i) {
      if (source[i] < 0 || source[i] == static_cast<int>(i)) continue;
      const int x = static_cast<int>(i % w), y = static_cast<int>(i / w);
      const int sx = source[i] % w, sy = source[i] / w;
      raster->depth.data[i] = raster->depth.data[source[i]];
      raster->face_id[i] = raster->face_id[source[i]];
      for (int c = 0; c < 3; ++c) raster->barycentric.At(x, y, c) = raster->barycentric.At(sx, sy, c);
      extended[i] = 1;
    }
  });
  return extended;
}

std::vector<SourceView> WithProxyDepth(const std::vector<SourceView>& sources,
                                       const std::vector<const TriangleMesh*>& layers, int extend_px) {
  std::vector<SourceView> with_depth = sources;  // shares pixels
  tbb::parallel_for(size_t{0}, with_depth.size(), [&](size_t i) {
    with_depth[i].proxy_depth = MeshDepth(layers, with_depth[i].camera, with_depth[i].cam_from_world, extend_px);
  });
  return with_depth;
}

ProxySurface MeshSurface(const std::vector<const TriangleMesh*>& layers, const Camera& camera,
                         const Rigid3d& cam_from_world, int extend_px) {
  return SurfaceFromDepth(MeshDepth(layers, camera, cam_from_world, extend_px), camera, cam_from_world);
}

bool PlaneAtMeanInverseDepth(const std::vector<Eigen::Vector3d>& points, const Rigid3d& desired_cam_from_world,
                             Plane* plane) {
  double sum_inverse = 0;
  size_t count = 0;
  for (const Eigen::Vector3d& point : points) {
    const double z = (desired_cam_from_world * point).z();
    if (z > 1e-9 && std::isfinite(z)) {
      sum_inverse += 1.0 / z;
      ++count;
    }
  }
  if (count == 0) return false;
  const double depth = count / sum_inverse;
  const Rigid3d world_from_cam = desired_cam_from_world.Inverse();
  plane->normal = world_from_cam.rotation * Eigen::Vector3d::UnitZ();
  plane->point = world_from_cam.translation + depth * plane->normal;
  return true;
}

UlrRenderer::UlrRenderer(const std::vector<SourceView>* sources, const RenderOptions& options)
    : sources_(sources), options_(options) {
  // RenderOptions::Check refuses negative weights; a caller that skipped it gets the exhaustive search.
  prunable_ = options.alpha >= 0 && options.beta >= 0 && options.gamma >= 0;
  for (const SourceView& source : *sources) {
    Prepared prepared;
    prepared.rotation = source.cam_from_world.R();
    prepared.translation = source.cam_from_world.translation;
    prepared.center = source.cam_from_world.Inverse().translation;
    prepared.fx = source.camera.FocalX();
    prepared.fy = source.camera.FocalY();
    prepared.cx = source.camera.PrincipalX();
    prepared.cy = source.camera.PrincipalY();
    prepared.width = source.camera.width;
    prepared.height = source.camera.height;
    prepared.margin = options.fov_margin * std::min(source.camera.width, source.camera.height);
    prepared_.push_back(prepared);
  }
}

double UlrRenderer::Penalty(const Candidate& c) const {
  // atan2 of |sin| and cos: exact 0 for parallel rays (acos loses ~1e-8 near 1).
  return options_.alpha * std::atan2(c.sin, c.cos) + options_.beta * c.resolution + options_.gamma * c.fov;
}

UlrRenderer::BlendScratch UlrRenderer::NewScratch() const {
  BlendScratch scratch;
  scratch.candidates.resize(prepared_.size() + 1);
  scratch.best.resize(static_cast<size_t>(options_.k) + 1);
  scratch.heap.resize(prepared_.size() + 1);
  scratch.weights.resize(prepared_.size() + 1);
  return scratch;
}

int UlrRenderer::Blend(const Eigen::Vector3d& p, const Eigen::Vector3d& desired_center, BlendScratch* scratch,
                       bool exhaustive) const {
  const Eigen::Vector3d to_desired = desired_center - p;
  const double desired_distance = to_desired.norm();
  const Eigen::Vector3d desired_dir = desired_distance > 0 ? Eigen::Vector3d(to_desired / desired_distance) : to_desired;
  // Every source p projects into (in front, inside the bilinear range), with its penalty's parts.
  Candidate* candidates = scratch->candidates.data();
  int in_view = 0;
  bool bounded = true;
  for (size_t i = 0; i < prepared_.size(); ++i) {
    const Prepared& s = prepared_[i];
    const Eigen::Vector3d x = s.rotation * p + s.translation;
    if (!(x.z() > 0)) continue;
    const double u = s.fx * x.x() / x.z() + s.cx, v = s.fy * x.y() / x.z() + s.cy;
    // Distance to the border of the range where bilinear sampling stays inside the image.
    const double border = std::min(std::min(u - 0.5, s.width - 0.5 - u), std::min(v - 0.5, s.height - 0.5 - v));
    if (!(border > 0)) continue;  // field-of-view penalty infinite
    Candidate& c = candidates[in_view++];
    c.u = u, c.v = v, c.z = x.z(), c.source = static_cast<int>(i);
    c.fov = border >= s.margin ? 0.0 : (s.margin / border - 1.0) * (s.margin / border - 1.0);
    const Eigen::Vector3d to_source = s.center - p;
    const double source_distance = to_source.norm();
    c.sin = c.cos = 0.0;  // atan2(0, 0) = 0: no angle when either centre is at p
    if (source_distance > 0 && desired_distance > 0) {
      c.sin = to_source.cross(desired_dir).norm();
      c.cos = to_source.dot(desired_dir);
    }
    c.resolution = std::max(0.0, source_distance - desired_distance);
    // A lower bound of the penalty from a polynomial arctangent (error below kAngleBound), less
    // the rounding of the sums: sources are visited from the lowest bound up and the search stops
    // once no remaining source can be among the k smallest penalties.
    const double approx = options_.alpha * ArcTangentBelowPi(c.sin, c.cos) + options_.beta * c.resolution +
                          options_.gamma * c.fov;
    c.lower = std::isinf(approx) ? approx : approx - options_.alpha * kAngleBound - 1e-9 * std::abs(approx);
    bounded = bounded && !std::isnan(c.lower) && std::isfinite(c.sin) && std::isfinite(c.cos);
  }
  if (in_view == 0) return 0;
  const int k = options_.k;
  const auto by_penalty = [](const Candidate& a, const Candidate& b) {
    return a.penalty < b.penalty || (a.penalty == b.penalty && a.source < b.source);
  };
  const auto visible = [&](const Candidate& c) {
    const DepthMap& depth = (*sources_)[c.source].proxy_depth;
    return depth.Empty() || VisibleInSource(depth, c.u, c.v, c.z, options_.visibility_epsilon);
  };
  // The k smallest (penalty, source) among the visible sources, in order, in `best[0, n)`; n == k
  // exactly when at least k sources are visible.
  Candidate* best = scratch->best.data();
  int n = 0;
  if (exhaustive || !bounded || !prunable_) {
    // The definition: every visible source's penalty, the k smallest kept.
    int count = 0;
    for (int j = 0; j < in_view; ++j) {
      if (!visible(candidates[j])) continue;
      candidates[count] = candidates[j];
      candidates[count].penalty = Penalty(candidates[count]);
      ++count;
    }
    if (count == 0) return 0;
    n = std::min(count, k);
    std::partial_sort(candidates, candidates + n, candidates + count, by_penalty);
    std::copy(candidates, candidates + n, best);
  } else {
    // The same k from the lowest bounds up: a source whose bound exceeds the k-th smallest
    // penalty found so far cannot rank before it, nor can any after it; the sources never
    // reached skip their visibility test and arctangent (most of them: k of ~40 on templeRing).
    int* heap = scratch->heap.data();
    for (int j = 0; j < in_view; ++j) heap[j] = j;
    const auto higher_bound = [candidates](int a, int b) { return candidates[a].lower > candidates[b].lower; };
    std::make_heap(heap, heap + in_view, higher_bound);
    int remaining = in_view;
    while (remaining > 0) {
      const Candidate& next = candidates[heap[0]];
      if (n == k && next.lower > best[k - 1].penalty) break;
      std::pop_heap(heap, heap + remaining, higher_bound);
      Candidate c = candidates[heap[--remaining]];
      if (!visible(c)) continue;
      c.penalty = Penalty(c);
      // Insert into the sorted `best`, keeping k.
      if (n == k && !by_penalty(c, best[k - 1])) continue;
      int at = n;
      while (at > 0 && by_penalty(c, best[at - 1])) {
        if (at < k) best[at] = best[at - 1];
        --at;
      }
      best[at] = c;
      n = std::min(n + 1, k);
    }
    if (n == 0) return 0;
  }
  double* weights = scratch->weights.data();
  // The k-th smallest penalty is the threshold [U 124], capped at max_penalty: with fewer than k
  // usable cameras the missing ones count as penalty max_penalty, so a camera's weight still
  // falls continuously to 0 as it leaves (field of view, visibility) however few cameras remain.
  const double thresh = n == k ? std::min(best[n - 1].penalty, options_.max_penalty) : options_.max_penalty;
  double sum = 0;
  if (options_.epipole_consistent && best[0].penalty <= kZeroPenalty) {
    // The desired ray passes through a source centre: 1/penalty is infinite for it [U 130].
    for (int j = 0; j < n; ++j) sum += weights[j] = best[j].penalty <= kZeroPenalty ? 1.0 : 0.0;
  } else {
    for (int j = 0; j < n; ++j) {
      double w = thresh > 0 ? 1.0 - best[j].penalty / thresh : 0.0;
      if (options_.epipole_consistent) w /= best[j].penalty;
      sum += weights[j] = std::max(0.0, w);
    }
  }
  if (!(sum > 0) || !std::isfinite(sum)) {
    // Every kept penalty reached the threshold: all kept penalties equal (the k-th is the
    // threshold), or every one exceeds max_penalty (e.g. near the borders of every source). The
    // weight goes to the smallest-penalty camera(s), the limit of the weights just before (the
    // others fall to 0 first); uniform only when all are equal. Uniform weights here made a
    // camera whose penalty had risen to 1e27 at its border weigh 1/3 (a jump, not continuity).
    int tied = 0;
    for (int j = 0; j < n; ++j) tied += !(best[j].penalty > best[0].penalty);
    for (int j = 0; j < n; ++j) weights[j] = !(best[j].penalty > best[0].penalty) ? 1.0 / tied : 0.0;
    return n;
  }
  for (int j = 0; j < n; ++j) weights[j] /= sum;
  return n;
}

std::vector<BlendWeight> UlrRenderer::Weights(const Eigen::Vector3d& p, const Eigen::Vector3d& desired_center,
                                              bool exhaustive) const {
  BlendScratch scratch = NewScratch();
  const int n = Blend(p, desired_center, &scratch, exhaustive);
  std::vector<BlendWeight> result;
  for (int j = 0; j < n; ++j) result.push_back({scratch.best[j].source, scratch.weights[j], scratch.best[j].penalty});
  return result;
}

RenderResult UlrRenderer::Render(const Camera& camera, const Rigid3d& cam_from_world,
                                 const ProxySurface& surface) const {
  RenderResult result;
  result.image = cv::Mat(camera.height, camera.width, CV_8UC3, cv::Scalar::all(0));
  result.coverage = cv::Mat(camera.height, camera.width, CV_8UC1, cv::Scalar::all(0));
  const Eigen::Vector3d desired_center = cam_from_world.Inverse().translation;
  std::vector<size_t> row_covered(camera.height, 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
    BlendScratch scratch = NewScratch();  // once per block of rows, not per pixel
    for (int y = rows.begin(); y < rows.end(); ++y) {
      uint8_t* out = result.image.ptr<uint8_t>(y);
      uint8_t* covered = result.coverage.ptr<uint8_t>(y);
      for (int x = 0; x < camera.width; ++x) {
        if (!surface.hit[static_cast<size_t>(y) * surface.width + x]) continue;
        const Eigen::Vector3d p(surface.points.At(x, y, 0), surface.points.At(x, y, 1), surface.points.At(x, y, 2));
        const int n = Blend(p, desired_center, &scratch);
        if (n == 0) continue;
        double bgr[3] = {0, 0, 0};
        for (int j = 0; j < n; ++j) {
          const double weight = scratch.weights[j];
          if (weight <= 0) continue;
          const Candidate& c = scratch.best[j];
          AddBilinear((*sources_)[c.source].image, c.u, c.v, weight, bgr);
        }
        for (int c = 0; c < 3; ++c) out[3 * x + c] = cv::saturate_cast<uint8_t>(bgr[c]);
        covered[x] = 255;
        ++row_covered[y];
      }
    }
  });
  for (size_t n : row_covered) result.covered_pixels += n;
  return result;
}

ProxySurface HitsOf(const RenderResult& fine) {
  ProxySurface surface;
  surface.width = fine.coverage.cols;
  surface.height = fine.coverage.rows;
  surface.hit.assign(static_cast<size_t>(surface.width) * surface.height, 0);
  for (int y = 0; y < surface.height; ++y) {
    const uint8_t* row = fine.coverage.ptr<uint8_t>(y);
    for (int x = 0; x < surface.width; ++x) surface.hit[static_cast<size_t>(y) * surface.width + x] = row[x] != 0;
  }
  return surface;
}

RenderResult Downsample(const RenderResult& fine, const ProxySurface& fine_surface, int factor) {
  if (factor <= 1) return fine;
  const int width = fine.image.cols / factor, height = fine.image.rows / factor;
  RenderResult result;
  result.image = cv::Mat(height, width, CV_8UC3, cv::Scalar::all(0));
  result.coverage = cv::Mat(height, width, CV_8UC1, cv::Scalar::all(0));
  // Rows on the threads, each counting its covered pixels.
  std::vector<size_t> row_covered(static_cast<size_t>(std::max(height, 0)), 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, height, 16), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      uint8_t* out = result.image.ptr<uint8_t>(y);
      uint8_t* out_coverage = result.coverage.ptr<uint8_t>(y);
      for (int x = 0; x < width; ++x) {
        double bgr[3] = {0, 0, 0};
        int covered = 0, missed = 0;
        for (int j = 0; j < factor; ++j) {
          const int fy = y * factor + j;
          const uint8_t* row = fine.image.ptr<uint8_t>(fy);
          const uint8_t* cov = fine.coverage.ptr<uint8_t>(fy);
          for (int i = 0; i < factor; ++i) {
            const int fx = x * factor + i;
            if (!fine_surface.hit[static_cast<size_t>(fy) * fine_surface.width + fx]) ++missed;
            if (!cov[fx]) continue;
            ++covered;
            for (int c = 0; c < 3; ++c) bgr[c] += row[3 * fx + c];
          }
        }
        if (covered == 0) continue;
        const double count = covered + missed;
        for (int c = 0; c < 3; ++c) out[3 * x + c] = cv::saturate_cast<uint8_t>(bgr[c] / count);
        out_coverage[x] = static_cast<uint8_t>(std::max(1L, std::lround(255.0 * covered / count)));
        ++row_covered[y];
      }
    }
  });
  for (const size_t count : row_covered) result.covered_pixels += count;
  return result;
}

// The background stands in for the rest of the scene only where the model covers less than half of
// a pixel. Compositing the model's share over it everywhere would be exact for a true background,
// but a fill (the plane) is a poor one right at an object's silhouette: on the synthetic ring, held
// out, filled, compositing cost textured 2.0 dB and ULR 1.6 dB against this rule.
constexpr uint8_t kHalfCovered = 128;

RenderResult FillWithColour(const RenderResult& model, const cv::Vec3b& background_bgr) {
  RenderResult filled;
  filled.image.create(model.image.size(), CV_8UC3);
  filled.coverage = cv::Mat(model.image.size(), CV_8UC1, cv::Scalar(255));
  filled.covered_pixels = model.image.total();
  for (int y = 0; y < model.image.rows; ++y) {
    const cv::Vec3b* in = model.image.ptr<cv::Vec3b>(y);
    const uint8_t* alpha = model.coverage.ptr<uint8_t>(y);
    cv::Vec3b* out = filled.image.ptr<cv::Vec3b>(y);
    for (int x = 0; x < model.image.cols; ++x) {
      const int rest = 255 - alpha[x];
      for (int c = 0; c < 3; ++c) {
        // in + bg * (1 - alpha), rounded; at most 255 for a premultiplied colour (in <= alpha).
        out[x][c] = static_cast<uint8_t>(std::min(255, in[x][c] + (background_bgr[c] * rest + 127) / 255));
      }
    }
  }
  return filled;
}

RenderResult FillHoles(const RenderResult& model, const RenderResult& background) {
  RenderResult filled;
  filled.image = model.image.clone();
  filled.coverage = model.coverage.clone();
  filled.covered_pixels = 0;
  for (int y = 0; y < filled.image.rows; ++y) {
    cv::Vec3b* out = filled.image.ptr<cv::Vec3b>(y);
    uint8_t* covered = filled.coverage.ptr<uint8_t>(y);
    const cv::Vec3b* fill = background.image.ptr<cv::Vec3b>(y);
    const uint8_t* fill_covered = background.coverage.ptr<uint8_t>(y);
    for (int x = 0; x < filled.image.cols; ++x) {
      if (covered[x] < kHalfCovered && fill_covered[x]) {
        out[x] = fill[x];
        covered[x] = 255;
      }
      if (covered[x]) ++filled.covered_pixels;
    }
  }
  return filled;
}

}  // namespace ibmr
