// Multiple depth images: flags, skin detection and tile merging (seed 004 sections 4.3-4.6). See
// depth_images.h.
#include "stages/render/depth_images.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "pipeline/core/depth_normals.h"

namespace ibmr {

namespace {

bool Fail(std::string* error, const std::string& key, const std::string& what) {
  *error = key + ": " + what;
  return false;
}

// World-from-camera and camera-from-world constants of one image, for projecting points quickly.
struct Projector {
  Eigen::Matrix3f rotation;      // camera from world
  Eigen::Vector3f translation;
  Eigen::Matrix3f world_rotation;  // world from camera
  Eigen::Vector3f center;
  float fx, fy, cx, cy;
  int width, height;

  explicit Projector(const DepthImage& image)
      : rotation(image.cam_from_world.R().cast<float>()),
        translation(image.cam_from_world.translation.cast<float>()),
        world_rotation(rotation.transpose()),
        center(-(world_rotation * translation)),
        fx(static_cast<float>(image.camera.FocalX())),
        fy(static_cast<float>(image.camera.FocalY())),
        cx(static_cast<float>(image.camera.PrincipalX())),
        cy(static_cast<float>(image.camera.PrincipalY())),
        width(image.width()),
        height(image.height()) {}

  Eigen::Vector3f World(const Eigen::Vector3f& ray, float z) const { return world_rotation * (ray * z) + center; }
  // Pixel index of the projection of `point` and its depth; false behind the camera or outside.
  bool Project(const Eigen::Vector3f& point, int* x, int* y, float* z) const {
    const Eigen::Vector3f p = rotation * point + translation;
    if (!(p.z() > 0)) return false;
    const float u = fx * p.x() / p.z() + cx, v = fy * p.y() / p.z() + cy;
    if (!(u >= 0 && v >= 0 && u < width && v < height)) return false;
    *x = static_cast<int>(u);
    *y = static_cast<int>(v);
    *z = p.z();
    return true;
  }
};

// True when some interior point of the segment p-q lies in front of `other`'s depth by more than
// `tolerance` * z: the segment crosses space that image saw empty.
bool CrossesFreeSpace(const Eigen::Vector3f& p, const Eigen::Vector3f& q, const Projector& other,
                      const DepthMap& other_depth, float tolerance) {
  for (const float t : {0.25f, 0.5f, 0.75f}) {
    int x, y;
    float z;
    if (!other.Project(p + t * (q - p), &x, &y, &z)) continue;
    const float seen = other_depth.At(x, y);
    if (IsValidDepth(seen) && z < seen * (1.f - tolerance)) return true;
  }
  return false;
}

}  // namespace

bool DepthImageOptions::Check(std::string* error) const {
  if (!(min_confidence >= 0 && min_confidence <= 1)) return Fail(error, "min_confidence", "must be in [0, 1]");
  if (!(skin_tolerance > 0 && skin_tolerance < 1)) return Fail(error, "skin_tolerance", "must be in (0, 1)");
  if (skin_views < 0 || skin_views > 64) return Fail(error, "skin_views", "must be in [0, 64]");
  if (free_space_views < 0 || free_space_views > 64) return Fail(error, "free_space_views", "must be in [0, 64]");
  if (color_tolerance < 0 || color_tolerance > 255) return Fail(error, "color_tolerance", "must be in [0, 255]");
  if (!(merge_tolerance > 0 && merge_tolerance < 1)) return Fail(error, "merge_tolerance", "must be in (0, 1)");
  if (merge_views < 1 || merge_views > 64) return Fail(error, "merge_views", "must be in [1, 64]");
  if (tile_size < 4 || tile_size > 256) return Fail(error, "tile_size", "must be in [4, 256]");
  return true;
}

void FlagSamples(DepthImage* image, double min_confidence) {
  image->flags.assign(static_cast<size_t>(image->width()) * image->height(), 0);
  for (int y = 0; y < image->height(); ++y) {
    for (int x = 0; x < image->width(); ++x) {
      uint8_t& flag = image->flags[static_cast<size_t>(y) * image->width() + x];
      if (!IsValidDepth(image->depth.At(x, y))) {
        flag = kSampleInvalid;
      } else if (image->Confidence(x, y) < min_confidence) {
        flag = kSampleLowConfidence;
      }
    }
  }
}

std::vector<std::vector<int>> NearestImages(const std::vector<DepthImage>& images, int count) {
  std::vector<Eigen::Vector3d> directions;
  for (const DepthImage& image : images) directions.push_back(image.cam_from_world.rotation.conjugate() * Eigen::Vector3d::UnitZ());
  std::vector<std::vector<int>> nearest(images.size());
  for (size_t i = 0; i < images.size(); ++i) {
    std::vector<int> others;
    for (size_t j = 0; j < images.size(); ++j) {
      if (j != i) others.push_back(static_cast<int>(j));
    }
    const auto cosine = [&](int j) { return directions[i].dot(directions[j]); };
    std::stable_sort(others.begin(), others.end(), [&](int a, int b) { return cosine(a) > cosine(b); });
    others.resize(std::min<size_t>(others.size(), std::max(count, 0)));
    nearest[i] = others;
  }
  return nearest;
}

size_t DetectSkins(std::vector<DepthImage>* images, const DepthImageOptions& options, size_t* outliers) {
  if (outliers) *outliers = 0;
  if (options.skin_views == 0 || images->size() < 2) return 0;
  const std::vector<std::vector<int>> nearest = NearestImages(*images, options.skin_views);
  std::vector<Projector> projectors;
  for (const DepthImage& image : *images) projectors.emplace_back(image);
  std::vector<size_t> found(images->size(), 0), violating(images->size(), 0);
  const float tolerance = static_cast<float>(options.skin_tolerance);
  // Flags are written only into image i's own array, and the skin test reads only depth: the
  // images are independent and run in parallel.
  tbb::parallel_for(size_t{0}, images->size(), [&](size_t i) {
    DepthImage& a = (*images)[i];
    const Projector& pa = projectors[i];
    const std::vector<Eigen::Vector3f> rays = PixelRays(a.camera, a.width(), a.height());
    const auto valid = [&](int x, int y) { return !(a.flags[static_cast<size_t>(y) * a.width() + x] & kSampleInvalid); };
    const auto test = [&](int x0, int y0, int x1, int y1) {
      const float z0 = a.depth.At(x0, y0), z1 = a.depth.At(x1, y1);
      // Neighbours within the tolerance of each other lie on one surface band: no free space between.
      if (std::abs(z0 - z1) <= tolerance * std::min(z0, z1)) return;
      const Eigen::Vector3f p = pa.World(rays[static_cast<size_t>(y0) * a.width() + x0], z0);
      const Eigen::Vector3f q = pa.World(rays[static_cast<size_t>(y1) * a.width() + x1], z1);
      for (const int j : nearest[i]) {
        if (CrossesFreeSpace(p, q, projectors[j], (*images)[j].depth, tolerance)) {
          a.flags[static_cast<size_t>(y0) * a.width() + x0] |= kSampleSkin;
          a.flags[static_cast<size_t>(y1) * a.width() + x1] |= kSampleSkin;
          ++found[i];
          return;
        }
      }
    };
    // Outliers first, from the depth alone (flags of other images are not read).
    if (options.free_space_views > 0 || options.color_tolerance > 0) {
      for (int y = 0; y < a.height(); ++y) {
        for (int x = 0; x < a.width(); ++x) {
          if (!valid(x, y)) continue;
          const Eigen::Vector3f p = pa.World(rays[static_cast<size_t>(y) * a.width() + x], a.depth.At(x, y));
          const cv::Vec3b color = a.image.at<cv::Vec3b>(y, x);
          int violations = 0, same_surface = 0, disagree = 0;
          for (const int j : nearest[i]) {
            int bx, by;
            float z;
            if (!projectors[j].Project(p, &bx, &by, &z)) continue;
            const DepthImage& b = (*images)[j];
            const float seen = b.depth.At(bx, by);
            if (!IsValidDepth(seen)) continue;
            violations += z < seen * (1.f - tolerance);
            if (std::abs(z - seen) > tolerance * z) continue;
            ++same_surface;
            const cv::Vec3b other = b.image.at<cv::Vec3b>(by, bx);
            int difference = 0;
            for (int c = 0; c < 3; ++c) difference = std::max(difference, std::abs(color[c] - other[c]));
            disagree += difference > options.color_tolerance;
          }
          uint8_t& flag = a.flags[static_cast<size_t>(y) * a.width() + x];
          if (options.free_space_views > 0 && violations >= options.free_space_views) {
            flag |= kSampleFreeSpace;
            ++violating[i];
          } else if (options.color_tolerance > 0 && same_surface > 0 && 2 * disagree > same_surface) {
            flag |= kSampleInconsistent;
            ++violating[i];
          }
        }
      }
    }
    for (int y = 0; y < a.height(); ++y) {
      for (int x = 0; x < a.width(); ++x) {
        if (!valid(x, y)) continue;
        if (x + 1 < a.width() && valid(x + 1, y)) test(x, y, x + 1, y);
        if (y + 1 < a.height() && valid(x, y + 1)) test(x, y, x, y + 1);
      }
    }
  });
  if (outliers) *outliers = std::accumulate(violating.begin(), violating.end(), size_t{0});
  return std::accumulate(found.begin(), found.end(), size_t{0});
}

float SampleQuality(const DepthImage& image, int x, int y) {
  const uint8_t flag = image.flags.empty() ? 0 : image.flags[static_cast<size_t>(y) * image.width() + x];
  if (!IsDrawable(flag)) return 0.f;
  const float z = image.depth.At(x, y);
  if (!IsValidDepth(z)) return 0.f;
  float cosine = 0.25f;  // unknown normal (a silhouette or a lone sample): a poor sample
  if (!image.normals.Empty()) {
    const Eigen::Vector3f n(image.normals.At(x, y, 0), image.normals.At(x, y, 1), image.normals.At(x, y, 2));
    if (n.squaredNorm() > 0.25f) {
      const Eigen::Vector3d ray = image.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)).normalized();
      cosine = std::abs(n.normalized().dot(ray.cast<float>()));
    }
  }
  return image.Confidence(x, y) * cosine / (z * z);
}

size_t MergeTiles(std::vector<DepthImage>* images, const DepthImageOptions& options) {
  if (!options.merge || images->size() < 2) return 0;
  std::vector<std::vector<float>> quality(images->size());
  tbb::parallel_for(size_t{0}, images->size(), [&](size_t i) {
    const DepthImage& image = (*images)[i];
    quality[i].assign(static_cast<size_t>(image.width()) * image.height(), 0.f);
    for (int y = 0; y < image.height(); ++y) {
      for (int x = 0; x < image.width(); ++x) quality[i][static_cast<size_t>(y) * image.width() + x] = SampleQuality(image, x, y);
    }
  });
  // Tiles ranked by quality [N 161-163].
  struct Tile {
    double rank;
    int image, x0, y0;
  };
  std::vector<Tile> tiles;
  const int size = options.tile_size;
  for (size_t i = 0; i < images->size(); ++i) {
    const DepthImage& image = (*images)[i];
    for (int y0 = 0; y0 < image.height(); y0 += size) {
      for (int x0 = 0; x0 < image.width(); x0 += size) {
        double sum = 0;
        int valid = 0, drawable = 0, flagged = 0;
        for (int y = y0; y < std::min(y0 + size, image.height()); ++y) {
          for (int x = x0; x < std::min(x0 + size, image.width()); ++x) {
            const size_t k = static_cast<size_t>(y) * image.width() + x;
            const uint8_t flag = image.flags[k];
            if (flag & kSampleInvalid) continue;
            ++valid;
            if (flag & (kSampleSkin | kSampleLowConfidence)) ++flagged;
            if (IsDrawable(flag)) {
              ++drawable;
              sum += quality[i][k];
            }
          }
        }
        if (drawable == 0) continue;
        tiles.push_back({sum / drawable * (1.0 - static_cast<double>(flagged) / valid), static_cast<int>(i), x0, y0});
      }
    }
  }
  std::stable_sort(tiles.begin(), tiles.end(), [](const Tile& a, const Tile& b) { return a.rank < b.rank; });
  const std::vector<std::vector<int>> nearest = NearestImages(*images, options.merge_views);
  std::vector<Projector> projectors;
  for (const DepthImage& image : *images) projectors.emplace_back(image);
  std::vector<std::vector<Eigen::Vector3f>> rays(images->size());
  for (size_t i = 0; i < images->size(); ++i) {
    rays[i] = PixelRays((*images)[i].camera, (*images)[i].width(), (*images)[i].height());
  }
  const float tolerance = static_cast<float>(options.merge_tolerance);
  size_t culled = 0;
  // Worst tile first [N 166]. Within one tile the decisions read only other images' flags, so the
  // tile's rows run in parallel; tiles run in rank order, which makes the result deterministic.
  for (const Tile& tile : tiles) {
    DepthImage& a = (*images)[tile.image];
    const Projector& pa = projectors[tile.image];
    const int y_end = std::min(tile.y0 + size, a.height()), x_end = std::min(tile.x0 + size, a.width());
    std::vector<size_t> row_culled(static_cast<size_t>(y_end - tile.y0), 0);
    tbb::parallel_for(tile.y0, y_end, [&](int y) {
      for (int x = tile.x0; x < x_end; ++x) {
        const size_t k = static_cast<size_t>(y) * a.width() + x;
        if (!IsDrawable(a.flags[k])) continue;
        const float q = quality[tile.image][k];
        const Eigen::Vector3f p = pa.World(rays[tile.image][k], a.depth.At(x, y));
        for (const int j : nearest[tile.image]) {
          int bx, by;
          float z;
          if (!projectors[j].Project(p, &bx, &by, &z)) continue;
          const DepthImage& b = (*images)[j];
          const size_t kb = static_cast<size_t>(by) * b.width() + bx;
          if (!IsDrawable(b.flags[kb]) || std::abs(z - b.depth.data[kb]) > tolerance * z) continue;
          const float qb = quality[j][kb];
          if (qb > q || (qb == q && j < tile.image)) {  // a strict order: the best sample survives
            a.flags[k] |= kSampleMerged;
            ++row_culled[y - tile.y0];
            break;
          }
        }
      }
    });
    culled += std::accumulate(row_culled.begin(), row_culled.end(), size_t{0});
  }
  return culled;
}

DepthImage DownsampleDepthImage(const DepthImage& image, int factor) {
  if (factor <= 1) return image;
  const int width = image.width() / factor, height = image.height() / factor;
  DepthImage out;
  out.name = image.name;
  out.cam_from_world = image.cam_from_world;
  // The blocks tile the image cropped to a multiple of factor (a crop keeps the intrinsics), so
  // the scale is exactly 1 / factor: block centres land on the new pixel centres.
  Camera cropped = image.camera;
  cropped.width = width * factor;
  cropped.height = height * factor;
  out.camera = cropped.Scaled(1.0 / factor);
  out.depth = DepthMap(width, height, 1, 0.f);
  out.image = cv::Mat(height, width, CV_8UC3, cv::Scalar::all(0));
  if (!image.confidence.Empty()) out.confidence = FloatMap(width, height, 1, 0.f);
  if (!image.normals.Empty()) out.normals = FloatMap(width, height, 3, 0.f);
  std::vector<float> depths;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      depths.clear();
      for (int j = 0; j < factor; ++j) {
        for (int i = 0; i < factor; ++i) {
          const float z = image.depth.At(x * factor + i, y * factor + j);
          if (IsValidDepth(z)) depths.push_back(z);
        }
      }
      if (2 * depths.size() < static_cast<size_t>(factor * factor)) continue;
      std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
      const float median = depths[depths.size() / 2];
      double bgr[3] = {0, 0, 0}, confidence = 0;
      int count = 0, nearest_x = 0, nearest_y = 0;
      float nearest = std::numeric_limits<float>::infinity();
      for (int j = 0; j < factor; ++j) {
        for (int i = 0; i < factor; ++i) {
          const int sx = x * factor + i, sy = y * factor + j;
          const float z = image.depth.At(sx, sy);
          if (!IsValidDepth(z)) continue;
          confidence += image.Confidence(sx, sy);
          if (std::abs(z - median) > 0.05f * median) continue;
          const cv::Vec3b& c = image.image.at<cv::Vec3b>(sy, sx);
          for (int k = 0; k < 3; ++k) bgr[k] += c[k];
          ++count;
          if (std::abs(z - median) < nearest) {
            nearest = std::abs(z - median);
            nearest_x = sx;
            nearest_y = sy;
          }
        }
      }
      out.depth.At(x, y) = median;
      for (int k = 0; k < 3; ++k) out.image.at<cv::Vec3b>(y, x)[k] = cv::saturate_cast<uint8_t>(bgr[k] / count);
      if (!out.confidence.Empty()) out.confidence.At(x, y) = static_cast<float>(confidence / depths.size());
      if (!out.normals.Empty()) {
        for (int k = 0; k < 3; ++k) out.normals.At(x, y, k) = image.normals.At(nearest_x, nearest_y, k);
      }
    }
  }
  return out;
}

}  // namespace ibmr
