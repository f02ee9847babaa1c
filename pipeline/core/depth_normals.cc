// Pixel rays and normals from depth maps (see depth_normals.h).
#include "pipeline/core/depth_normals.h"

#include <cmath>

namespace ibmr {

std::vector<Eigen::Vector3f> PixelRays(const Camera& camera, int width, int height) {
  std::vector<Eigen::Vector3f> rays(static_cast<size_t>(width) * height);
  const double sx = static_cast<double>(camera.width) / width, sy = static_cast<double>(camera.height) / height;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      rays[static_cast<size_t>(y) * width + x] =
          camera.CamFromImg(Eigen::Vector2d((x + 0.5) * sx, (y + 0.5) * sy)).cast<float>();
    }
  }
  return rays;
}

FloatMap NormalsFromDepth(const Camera& camera, const DepthMap& depth, float max_relative_jump) {
  const int w = depth.width, h = depth.height;
  FloatMap normals(w, h, 3, 0.f);
  const std::vector<Eigen::Vector3f> rays = PixelRays(camera, w, h);
  auto point = [&](int x, int y) { return rays[static_cast<size_t>(y) * w + x] * depth.At(x, y); };
  auto usable = [&](int x, int y, float d) {
    const float e = depth.At(x, y);
    return IsValidDepth(e) && std::abs(e - d) <= max_relative_jump * d;
  };
  for (int y = 1; y + 1 < h; ++y) {
    for (int x = 1; x + 1 < w; ++x) {
      const float d = depth.At(x, y);
      if (!IsValidDepth(d) || !usable(x - 1, y, d) || !usable(x + 1, y, d) || !usable(x, y - 1, d) ||
          !usable(x, y + 1, d)) {
        continue;
      }
      Eigen::Vector3f n = (point(x + 1, y) - point(x - 1, y)).cross(point(x, y + 1) - point(x, y - 1));
      const float norm = n.norm();
      if (!(norm > 0)) continue;
      n /= norm;
      if (n.dot(rays[static_cast<size_t>(y) * w + x]) > 0) n = -n;  // face the camera
      for (int c = 0; c < 3; ++c) normals.At(x, y, c) = n[c];
    }
  }
  return normals;
}

}  // namespace ibmr
