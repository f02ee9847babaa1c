// Point splatting with quadratic depth falloff and blending by confidence and angle (seed 004
// section 5.4). See splat.h.
#include "stages/render/splat.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "pipeline/core/depth_normals.h"
#include "pipeline/core/large_buffer.h"

namespace ibmr {

namespace {

constexpr int kBandRows = 16;  // rows of one band; a band's buffers stay in cache
// Smallest axis of a footprint, in desired pixels. Small, so that an edge-on footprint stays thin
// (0.71, a disc that always holds a pixel centre, drew a ring outside silhouettes); a minified
// sample may then fall between pixel centres, where its neighbours cover.
constexpr float kMinRadius = 0.35f;
// A depth sample's disc: the smallest that covers its pixel's square, half the pixel's diagonal.
constexpr float kHalfDiagonal = 0.70710678f;
// Rim samples: the relative depth jump to a 4-neighbour that makes a silhouette, and their weight.
constexpr float kRimStep = 0.05f;
constexpr float kRimWeight = 0.05f;

// One sample as the desired camera sees it.
struct Projected {
  float u, v, z;     // pixel coordinates (COLMAP convention: pixel centres at +0.5) and depth
  float radius;      // half the bounding box's height in pixels
  float half_width;  // half the bounding box's width in pixels
  float q00, q01, q11;  // the footprint ellipse's conic: d2 = q00 dx^2 + 2 q01 dx dy + q11 dy^2 < 1
  float confidence;
  float angle;       // radians between the source ray and the desired ray at the sample (0: a surfel)
  int source;        // the sample's source view (-1: a surfel)
  uint32_t sample;   // index into the cloud (its colour)
};

// The k sources with the smallest angles among the samples at one pixel (ULR's neighbourhood
// [U 124]), ascending; a source appears once, with its smallest angle.
struct Nearest {
  static constexpr int kMax = 8;
  float angle[kMax];
  int source[kMax];
  int count = 0;

  void Add(int src, float a, int k) {
    for (int j = 0; j < count; ++j) {
      if (source[j] != src) continue;
      if (a >= angle[j]) return;
      // Smaller angle for a listed source: bubble it up.
      for (; j > 0 && angle[j - 1] > a; --j) {
        angle[j] = angle[j - 1];
        source[j] = source[j - 1];
      }
      angle[j] = a;
      source[j] = src;
      return;
    }
    if (count == k && a >= angle[k - 1]) return;
    int j = count < k ? count++ : k - 1;
    for (; j > 0 && angle[j - 1] > a; --j) {
      angle[j] = angle[j - 1];
      source[j] = source[j - 1];
    }
    angle[j] = a;
    source[j] = src;
  }
  bool Has(int src) const {
    for (int j = 0; j < count; ++j) {
      if (source[j] == src) return true;
    }
    return false;
  }
};

// Whether pixel (px, py) continues the surface of pixel (x, y): inside the image, with a depth
// within kRimStep of it (else (x, y) is on the rim of its image's surface there).
bool Continuous(const DepthImage& image, int x, int y, int px, int py) {
  if (px < 0 || py < 0 || px >= image.width() || py >= image.height()) return false;
  const float z = image.depth.At(x, y), n = image.depth.At(px, py);
  return IsValidDepth(n) && std::abs(n - z) <= kRimStep * z;
}

// A camera-frame normal for a sample whose normal map has none (NormalsFromDepth leaves the rim of
// a surface at 0): the cross product of one-sided differences to continuous 4-neighbours, towards
// the camera; 0 when a direction has no such neighbour. Without it a rim sample would be a disc
// facing the viewer, which spills past the silhouette of a surface the desired view sees edge-on.
Eigen::Vector3f OneSidedNormal(const DepthImage& image, const std::vector<Eigen::Vector3f>& rays, int x, int y) {
  const int width = image.width();
  const auto point = [&](int px, int py) { return rays[static_cast<size_t>(py) * width + px] * image.depth.At(px, py); };
  const auto step = [&](int dx, int dy, Eigen::Vector3f* out) {
    if (Continuous(image, x, y, x + dx, y + dy)) {
      *out = point(x + dx, y + dy) - point(x, y);
    } else if (Continuous(image, x, y, x - dx, y - dy)) {
      *out = point(x, y) - point(x - dx, y - dy);
    } else {
      return false;
    }
    return true;
  };
  Eigen::Vector3f along_x, along_y;
  if (!step(1, 0, &along_x) || !step(0, 1, &along_y)) return Eigen::Vector3f::Zero();
  Eigen::Vector3f n = along_x.cross(along_y);
  if (!(n.squaredNorm() > 0)) return Eigen::Vector3f::Zero();
  n.normalize();
  return n.dot(point(x, y)) > 0 ? -n : n;
}

bool Fail(std::string* error, const std::string& key, const std::string& what) {
  *error = key + ": " + what;
  return false;
}

}  // namespace

bool SplatOptions::Check(std::string* error) const {
  if (!(radius_scale > 0 && radius_scale <= 8)) return Fail(error, "radius_scale", "must be in (0, 8]");
  if (!(max_radius_px >= 0.5 && max_radius_px <= 256)) return Fail(error, "max_radius_px", "must be in [0.5, 256]");
  if (!(max_stretch >= 1 && max_stretch <= 16)) return Fail(error, "max_stretch", "must be in [1, 16]");
  if (!(depth_tolerance > 0 && depth_tolerance < 1)) return Fail(error, "depth_tolerance", "must be in (0, 1)");
  if (k < 0 || k > 8) return Fail(error, "k", "must be in [0, 8]");
  if (!(angle_epsilon_deg > 0 && angle_epsilon_deg <= 90)) {
    return Fail(error, "angle_epsilon_deg", "must be in (0, 90]");
  }
  return true;
}

namespace {

// Whether pixel k of `image` becomes a sample (CloudFromDepthImages' test).
bool BecomesSample(const DepthImage& image, size_t k) {
  return (image.flags.empty() || IsDrawable(image.flags[k])) && IsValidDepth(image.depth.data[k]);
}

size_t SampleCount(const DepthImage& image) {
  size_t count = 0;
  for (size_t k = 0; k < image.depth.data.size(); ++k) count += BecomesSample(image, k);
  return count;
}

// Appends the samples of `image`, source `source`, to `cloud`.
void AppendDepthImage(const DepthImage& image, int source, SplatCloud* cloud) {
  const Eigen::Matrix3f world_from_cam = image.cam_from_world.R().transpose().cast<float>();
  const Eigen::Vector3f center = image.cam_from_world.Inverse().translation.cast<float>();
  cloud->source_centers.push_back(center);
  cloud->source_axes.push_back(world_from_cam);
  const std::vector<Eigen::Vector3f> rays = PixelRays(image.camera, image.width(), image.height());
  const float focal = static_cast<float>(std::sqrt(image.camera.FocalX() * image.camera.FocalY()));
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      const size_t k = static_cast<size_t>(y) * image.width() + x;
      if (!BecomesSample(image, k)) continue;
      const float z = image.depth.data[k];
      cloud->positions.push_back(world_from_cam * (rays[k] * z) + center);
      Eigen::Vector3f normal = Eigen::Vector3f::Zero();
      if (!image.normals.Empty()) {
        const Eigen::Vector3f n(image.normals.At(x, y, 0), image.normals.At(x, y, 1), image.normals.At(x, y, 2));
        if (n.squaredNorm() > 0.25f) normal = world_from_cam * n.normalized();
      }
      if (normal.squaredNorm() == 0) normal = world_from_cam * OneSidedNormal(image, rays, x, y);
      cloud->normals.push_back(normal);
      cloud->colors.push_back(image.image.at<cv::Vec3b>(y, x));
      // A sample on the rim of its image's surface (a 4-neighbour without depth or across a depth
      // step) has a pixel that straddles the silhouette: its colour is mixed with what lies
      // behind. Seen from another view the rim is inside the object, so it is kept (it fills
      // what nothing else covers) but weighs little against interior samples of other views.
      bool rim = false;
      for (const auto& [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        rim = rim || !Continuous(image, x, y, x + dx, y + dy);
      }
      cloud->confidence.push_back(std::max(image.Confidence(x, y), 1e-3f) * (rim ? kRimWeight : 1.f));
      cloud->footprint.push_back(kHalfDiagonal * z / focal);
      cloud->source.push_back(source);
    }
  }
}

// A cloud whose per-sample arrays hold `samples` without growing (a vector that grows holds its old
// and its new block at once, and up to twice what it needs after).
SplatCloud ReservedCloud(size_t samples, size_t sources) {
  SplatCloud cloud;
  cloud.positions.reserve(samples);
  cloud.normals.reserve(samples);
  cloud.colors.reserve(samples);
  cloud.confidence.reserve(samples);
  cloud.footprint.reserve(samples);
  cloud.source.reserve(samples);
  cloud.source_centers.reserve(sources);
  cloud.source_axes.reserve(sources);
  return cloud;
}

}  // namespace

SplatCloud CloudFromDepthImages(const std::vector<DepthImage>& images) {
  size_t samples = 0;
  for (const DepthImage& image : images) samples += SampleCount(image);
  SplatCloud cloud = ReservedCloud(samples, images.size());
  for (size_t i = 0; i < images.size(); ++i) AppendDepthImage(images[i], static_cast<int>(i), &cloud);
  return cloud;
}

SplatCloud CloudFromDepthImages(std::vector<DepthImage>&& images) {
  size_t samples = 0;
  for (const DepthImage& image : images) samples += SampleCount(image);
  SplatCloud cloud = ReservedCloud(samples, images.size());
  for (size_t i = 0; i < images.size(); ++i) {
    AppendDepthImage(images[i], static_cast<int>(i), &cloud);
    images[i] = DepthImage();  // its pixels are in the cloud now
  }
  images.clear();
  return cloud;
}

SplatCloud CloudFromSurfels(const PointCloud& surfels, float default_radius) {
  SplatCloud cloud;
  for (size_t i = 0; i < surfels.size(); ++i) {
    if (!surfels.positions[i].allFinite()) continue;
    cloud.positions.push_back(surfels.positions[i]);
    Eigen::Vector3f normal = Eigen::Vector3f::Zero();
    if (i < surfels.normals.size() && surfels.normals[i].allFinite() && surfels.normals[i].squaredNorm() > 0.25f) {
      normal = surfels.normals[i].normalized();
    }
    cloud.normals.push_back(normal);
    const Color3u8 c = i < surfels.colors.size() ? surfels.colors[i] : Color3u8{128, 128, 128};
    cloud.colors.push_back(cv::Vec3b(c[2], c[1], c[0]));
    const float confidence = i < surfels.confidence.size() ? surfels.confidence[i] : 1.f;
    cloud.confidence.push_back(std::isfinite(confidence) ? std::max(confidence, 1e-3f) : 1.f);
    const float radius = i < surfels.radius.size() ? surfels.radius[i] : default_radius;
    cloud.footprint.push_back(std::isfinite(radius) && radius > 0 ? radius : default_radius);
    cloud.source.push_back(-1);
  }
  return cloud;
}

namespace {

// The world axes (a, b) of sample i's footprint {X + s a + t b : s^2 + t^2 < 1}, or false when it
// has no orientation (no normal) and stays a disc facing the viewer.
//
// A depth sample is the source pixel's disc (radius `footprint` facing the source, in world units)
// laid on the tangent plane of its normal n: moving the pixel centre one step along the source's
// image axis e moves the ray r = X_cam / z by e / f and the point on the plane by
//     dX = (z / f) (e - r (n . e) / (n . r)),
// the differential the LDI paper uses for the "proper size" of a splat [S 5.3], kept as a vector
// so that the footprint is the image of the source pixel under the warp, an ellipse: thin where the
// desired view sees the surface edge-on (a silhouette), long where the source does.
// A surfel is its own disc: radius `footprint` in the plane normal to n.
bool FootprintAxes(const SplatCloud& cloud, size_t i, float max_stretch, Eigen::Vector3f* a, Eigen::Vector3f* b) {
  const Eigen::Vector3f& n = cloud.normals[i];
  if (n.squaredNorm() < 0.25f) return false;
  const float footprint = cloud.footprint[i];
  const int source = cloud.source[i];
  if (source < 0 || static_cast<size_t>(source) >= cloud.source_axes.size()) {
    const Eigen::Vector3f t = n.unitOrthogonal();
    *a = footprint * t;
    *b = footprint * n.cross(t).normalized();
    return true;
  }
  const Eigen::Matrix3f& axes = cloud.source_axes[source];  // columns: image x, image y, optical axis
  const Eigen::Vector3f d = cloud.positions[i] - cloud.source_centers[source];
  const float z = axes.col(2).dot(d);
  if (!(z > 0)) return false;
  const Eigen::Vector3f r = d / z;
  // n . r bounded away from 0 (grazing), keeping its sign: stretch at most about max_stretch.
  float nr = n.dot(r);
  const float min_nr = r.norm() / max_stretch;
  if (std::abs(nr) < min_nr) nr = nr < 0 ? -min_nr : min_nr;
  *a = footprint * (axes.col(0) - r * (n.dot(axes.col(0)) / nr));
  *b = footprint * (axes.col(1) - r * (n.dot(axes.col(1)) / nr));
  return true;
}

// Sets s's conic and bounding box from the ellipse's covariance V (pixels^2): points c + J w with
// |w| < 1 have V = J J^T. Its axes are bounded to [min_radius, max_radius]: a minified or edge-on
// footprint still holds a pixel centre, a magnified one does not scallop silhouettes [N 228].
void SetEllipse(float v00, float v01, float v11, float min_radius, float max_radius, Projected* s) {
  const float mean = 0.5f * (v00 + v11), half_diff = 0.5f * (v00 - v11);
  const float spread = std::sqrt(half_diff * half_diff + v01 * v01);
  const float lo = min_radius * min_radius, hi = max_radius * max_radius;
  const float l1 = mean + spread, l2 = mean - spread;
  if (!(l2 >= lo && l1 <= hi)) {
    // Rebuild V from clamped eigenvalues along the same axes (any axes when it is a disc).
    const float c1 = std::clamp(l1, lo, hi), c2 = std::clamp(l2, lo, hi);
    float ex = 1.f, ey = 0.f;  // unit eigenvector of l1
    if (spread > 1e-6f * mean) {
      // (v01, l1 - v00) and (l1 - v11, v01) both solve (V - l1) e = 0; the longer is the stabler.
      const float ax = v01, ay = l1 - v00, bx = l1 - v11, by = v01;
      const bool first = ax * ax + ay * ay >= bx * bx + by * by;
      ex = first ? ax : bx;
      ey = first ? ay : by;
      const float norm = std::sqrt(ex * ex + ey * ey);
      ex /= norm;
      ey /= norm;
    }
    v00 = c1 * ex * ex + c2 * ey * ey;
    v01 = (c1 - c2) * ex * ey;
    v11 = c1 * ey * ey + c2 * ex * ex;
  }
  const float inverse_det = 1.f / (v00 * v11 - v01 * v01);
  s->q00 = v11 * inverse_det;
  s->q01 = -v01 * inverse_det;
  s->q11 = v00 * inverse_det;
  s->half_width = std::sqrt(v00);
  s->radius = std::sqrt(v11);
}

}  // namespace

SplatImage RenderSplats(const SplatCloud& cloud, const Camera& camera, const Rigid3d& cam_from_world,
                        const SplatOptions& options, int exclude_source) {
  const int width = camera.width, height = camera.height;
  SplatImage out;
  out.image = cv::Mat(height, width, CV_8UC3, cv::Scalar::all(0));
  out.coverage = cv::Mat(height, width, CV_8UC1, cv::Scalar::all(0));
  out.depth = DepthMap(width, height, 1, 0.f);
  if (cloud.size() == 0 || width <= 0 || height <= 0) return out;

  const Eigen::Matrix3f rotation = cam_from_world.R().cast<float>();
  const Eigen::Vector3f translation = cam_from_world.translation.cast<float>();
  const Eigen::Vector3f desired_center = cam_from_world.Inverse().translation.cast<float>();
  const float fx = static_cast<float>(camera.FocalX()), fy = static_cast<float>(camera.FocalY());
  const float cx = static_cast<float>(camera.PrincipalX()), cy = static_cast<float>(camera.PrincipalY());
  const float focal = std::sqrt(fx * fy);
  const float radius_scale = static_cast<float>(options.radius_scale);
  const float max_radius = std::max(static_cast<float>(options.max_radius_px), kMinRadius);
  const float max_stretch = static_cast<float>(options.max_stretch);
  const double epsilon = options.angle_epsilon_deg * M_PI / 180.0;
  const float epsilon2 = static_cast<float>(epsilon * epsilon);
  const float epsilon_angle = static_cast<float>(epsilon);
  const int k = options.k;

  // The image is drawn in passes over bands of rows, each holding only the projected samples that
  // reach its rows (48 bytes each): a full-size castle view draws nearly all of its 20 M samples,
  // 985 MB in one pass. A pass projects every sample again (the angle only for those it keeps).
  const int bands = (height + kBandRows - 1) / kBandRows;
  const auto row_range = [&](const Projected& s, int* y0, int* y1) {
    *y0 = std::max(0, static_cast<int>(std::ceil(s.v - s.radius - 0.5f)));
    *y1 = std::min(height - 1, static_cast<int>(std::floor(s.v + s.radius - 0.5f)));
  };
  const size_t pass_bytes = std::max<size_t>(1, options.pass_bytes);
  const int passes = static_cast<int>(
      std::clamp<size_t>((cloud.size() * sizeof(Projected) + pass_bytes - 1) / pass_bytes, 1, static_cast<size_t>(bands)));
  std::vector<size_t> band_covered(bands, 0), band_hits(bands, 0);
  for (int pass = 0; pass < passes; ++pass) {
    const int band0 = static_cast<int>(static_cast<int64_t>(pass) * bands / passes);
    const int band1 = static_cast<int>(static_cast<int64_t>(pass + 1) * bands / passes);
    // 1. Project every sample (parallel), keeping those drawn in this pass's bands: not those behind
    //    the camera, facing away or outside the image. Blocks of samples keep theirs in order,
    //    gathered into `projected` in the cloud's order.
    constexpr size_t kProjectBlock = size_t{1} << 16;
    const size_t blocks = (cloud.size() + kProjectBlock - 1) / kProjectBlock;
    std::vector<std::vector<Projected>> kept(blocks);
    tbb::parallel_for(size_t{0}, blocks, [&](size_t block) {
      for (size_t i = block * kProjectBlock, end = std::min(cloud.size(), (block + 1) * kProjectBlock); i < end; ++i) {
        Projected s;
        if (exclude_source >= 0 && cloud.source[i] == exclude_source) continue;  // leave-one-out
        const Eigen::Vector3f& p = cloud.positions[i];
        const Eigen::Vector3f x = rotation * p + translation;
        if (!(x.z() > 0)) continue;
        const Eigen::Vector3f to_desired = desired_center - p;
        const Eigen::Vector3f& n = cloud.normals[i];
        // A disc (or a depth sample's tangent plane) seen from behind is not drawn; a small margin
        // keeps noisy normals at grazing angles.
        if (n.dot(to_desired) < -0.1f * to_desired.norm()) continue;
        s.u = fx * x.x() / x.z() + cx;
        s.v = fy * x.y() / x.z() + cy;
        s.z = x.z();
        Eigen::Vector3f a, b;
        if (FootprintAxes(cloud, i, max_stretch, &a, &b)) {
          // J = d(u, v)/dX at x times the rotated axes: the ellipse's columns in pixels.
          const float iz = 1.f / x.z();
          const Eigen::Vector3f ra = rotation * a * radius_scale, rb = rotation * b * radius_scale;
          const float ja0 = fx * iz * (ra.x() - x.x() * iz * ra.z()), ja1 = fy * iz * (ra.y() - x.y() * iz * ra.z());
          const float jb0 = fx * iz * (rb.x() - x.x() * iz * rb.z()), jb1 = fy * iz * (rb.y() - x.y() * iz * rb.z());
          SetEllipse(ja0 * ja0 + jb0 * jb0, ja0 * ja1 + jb0 * jb1, ja1 * ja1 + jb1 * jb1, kMinRadius, max_radius, &s);
        } else {
          const float r = radius_scale * focal * cloud.footprint[i] / x.z();
          SetEllipse(r * r, 0.f, r * r, kMinRadius, max_radius, &s);
        }
        if (s.u + s.half_width < 0 || s.v + s.radius < 0 || s.u - s.half_width > width || s.v - s.radius > height ||
            !std::isfinite(s.u) || !std::isfinite(s.v)) {
          continue;
        }
        int y0, y1;
        row_range(s, &y0, &y1);
        if (y0 > y1 || y0 / kBandRows >= band1 || y1 / kBandRows < band0) continue;
        s.angle = 0;
        s.source = cloud.source[i];
        if (s.source >= 0) {
          const Eigen::Vector3f to_source = cloud.source_centers[s.source] - p;
          s.angle = std::atan2(to_source.cross(to_desired).norm(), to_source.dot(to_desired));
        }
        s.confidence = cloud.confidence[i];
        s.sample = static_cast<uint32_t>(i);
        kept[block].push_back(s);
      }
    });
    std::vector<size_t> block_start(blocks + 1, 0);
    for (size_t block = 0; block < blocks; ++block) block_start[block + 1] = block_start[block] + kept[block].size();
    LargeBuffer<Projected> projected(block_start[blocks]);  // uninitialised: each block fills its part
    tbb::parallel_for(size_t{0}, blocks, [&](size_t block) {
      std::copy(kept[block].begin(), kept[block].end(), projected.begin() + static_cast<ptrdiff_t>(block_start[block]));
      std::vector<Projected>().swap(kept[block]);
    });

    // 2. Bin the samples by this pass's bands of rows (counting sort; a splat spanning two bands is
    //    in both); a sample counts as drawn in the pass of its first row.
    std::vector<uint32_t> band_start(bands + 1, 0);
    for (const Projected& s : projected) {
      int y0, y1;
      row_range(s, &y0, &y1);
      for (int b = std::max(band0, y0 / kBandRows); b <= std::min(band1 - 1, y1 / kBandRows); ++b) ++band_start[b + 1];
      out.splats_drawn += y0 / kBandRows >= band0;
    }
    for (int b = 0; b < bands; ++b) band_start[b + 1] += band_start[b];
    std::vector<uint32_t> band_items(band_start[bands]);
    {
      std::vector<uint32_t> fill(band_start.begin(), band_start.end() - 1);
      for (size_t i = 0; i < projected.size(); ++i) {
        const Projected& s = projected[i];
        int y0, y1;
        row_range(s, &y0, &y1);
        for (int b = std::max(band0, y0 / kBandRows); b <= std::min(band1 - 1, y1 / kBandRows); ++b) {
          band_items[fill[b]++] = static_cast<uint32_t>(i);
        }
      }
    }

    // 3. Per band: the front-most falloff depth, then the blend of every sample within the tolerance.
    const float half_tolerance = static_cast<float>(options.depth_tolerance) * 0.5f;
    const float band_tolerance = 1.f + static_cast<float>(options.depth_tolerance);
    tbb::parallel_for(band0, band1, [&](int band) {
      const int row0 = band * kBandRows, row1 = std::min(height, row0 + kBandRows);
      const size_t pixels = static_cast<size_t>(row1 - row0) * width;
      std::vector<float> front(pixels, std::numeric_limits<float>::infinity());
      std::vector<float> sum(4 * pixels, 0.f);  // B, G, R, weight
      // Visits the pixel centres of splat `s` inside this band with (offset, squared normalised radius).
      const auto for_pixels = [&](const Projected& s, auto&& visit) {
        const int y0 = std::max(row0, static_cast<int>(std::ceil(s.v - s.radius - 0.5f)));
        const int y1 = std::min(row1 - 1, static_cast<int>(std::floor(s.v + s.radius - 0.5f)));
        const int x0 = std::max(0, static_cast<int>(std::ceil(s.u - s.half_width - 0.5f)));
        const int x1 = std::min(width - 1, static_cast<int>(std::floor(s.u + s.half_width - 0.5f)));
        for (int y = y0; y <= y1; ++y) {
          const float dy = y + 0.5f - s.v;
          const float row_term = s.q11 * dy * dy, cross = 2.f * s.q01 * dy;
          for (int x = x0; x <= x1; ++x) {
            const float dx = x + 0.5f - s.u;
            const float d2 = (s.q00 * dx + cross) * dx + row_term;
            if (d2 < 1.f) visit(static_cast<size_t>(y - row0) * width + x, d2);
          }
        }
      };
      const uint32_t first = band_start[band], last = band_start[band + 1];
      // With k > 0, a pixel first picks its k nearest sources among every sample that lands on it;
      // only their samples take part in the z test and the blend. Each source's depth map is one
      // consistent surface, so an outlier of a distant view can neither hide nor tint the pixel.
      std::vector<Nearest> nearest(k > 0 ? pixels : 0);
      if (k > 0) {
        for (uint32_t item = first; item < last; ++item) {
          const Projected& s = projected[band_items[item]];
          for_pixels(s, [&](size_t pixel, float) { nearest[pixel].Add(s.source, s.angle, k); });
        }
      }
      const auto counts = [&](const Projected& s, size_t pixel) { return k == 0 || nearest[pixel].Has(s.source); };
      for (uint32_t item = first; item < last; ++item) {
        const Projected& s = projected[band_items[item]];
        for_pixels(s, [&](size_t pixel, float d2) {
          if (counts(s, pixel)) front[pixel] = std::min(front[pixel], s.z * (1.f + half_tolerance * d2));
        });
      }
      const auto in_front = [&](const Projected& s, size_t pixel, float d2) {
        return s.z * (1.f + half_tolerance * d2) <= front[pixel] * band_tolerance;
      };
      for (uint32_t item = first; item < last; ++item) {
        const Projected& s = projected[band_items[item]];
        const cv::Vec3b& color = cloud.colors[s.sample];
        for_pixels(s, [&](size_t pixel, float d2) {
          if (!counts(s, pixel) || !in_front(s, pixel, d2)) return;
          float angle_weight;
          if (k > 0) {
            const Nearest& n = nearest[pixel];
            // ULR [U 124-130]: threshold at the k-th smallest angle (pi when fewer sources see the
            // pixel), weight (1 - angle / threshold) / angle.
            const float threshold = n.count == k ? n.angle[k - 1] : static_cast<float>(M_PI);
            angle_weight = std::max(0.f, 1.f - s.angle / threshold) / std::max(s.angle, epsilon_angle);
            if (n.count == k && angle_weight <= 0 && n.angle[0] == threshold) angle_weight = 1.f;  // all equal
          } else {
            angle_weight = 1.f / (s.angle * s.angle + epsilon2);
          }
          const float w = s.confidence * angle_weight * (1.f - d2);
          if (!(w > 0)) return;
          float* acc = &sum[4 * pixel];
          acc[0] += w * color[0];
          acc[1] += w * color[1];
          acc[2] += w * color[2];
          acc[3] += w;
          ++band_hits[band];
        });
      }
      for (int y = row0; y < row1; ++y) {
        cv::Vec3b* row = out.image.ptr<cv::Vec3b>(y);
        uint8_t* covered = out.coverage.ptr<uint8_t>(y);
        for (int x = 0; x < width; ++x) {
          const size_t pixel = static_cast<size_t>(y - row0) * width + x;
          const float* acc = &sum[4 * pixel];
          if (!(acc[3] > 0)) continue;
          for (int c = 0; c < 3; ++c) row[x][c] = cv::saturate_cast<uint8_t>(acc[c] / acc[3]);
          covered[x] = 255;
          out.depth.At(x, y) = front[pixel];
          ++band_covered[band];
        }
      }
    });
  }
  for (int b = 0; b < bands; ++b) {
    out.covered_pixels += band_covered[b];
    out.pixel_hits += band_hits[b];
  }
  return out;
}

}  // namespace ibmr
