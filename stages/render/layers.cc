// Renderer `layers` (layers.h).
#include "stages/render/layers.h"

#include <algorithm>
#include <cmath>

namespace ibmr {

namespace {
Eigen::Vector3d CentreOf(const Rigid3d& cam_from_world) { return -(cam_from_world.R().transpose() * cam_from_world.translation); }
}  // namespace

LayersRenderer::LayersRenderer(std::vector<LayerSet> sets, int references, const Eigen::Vector3d& scene_centre)
    : sets_(std::move(sets)), references_(std::max(1, references)), centre_(scene_centre) {}

LayersRenderer::LayersRenderer(std::vector<LayerSet> headers, std::vector<std::string> folders, int references,
                               const Eigen::Vector3d& scene_centre)
    : sets_(std::move(headers)), folders_(std::move(folders)), references_(std::max(1, references)), centre_(scene_centre) {}

size_t LayersRenderer::Layers() const {
  size_t count = 0;
  for (const LayerSet& set : sets_) count += set.layers.size();
  return count;
}

bool LayersRenderer::HasSet(const std::string& image) const {
  return std::any_of(sets_.begin(), sets_.end(), [&](const LayerSet& set) { return set.image == image; });
}

RenderResult LayersRenderer::Render(const Camera& camera, const Rigid3d& cam_from_world,
                                    const std::string& exclude_image) const {
  const Eigen::Vector3d desired = (centre_ - CentreOf(cam_from_world)).normalized();
  std::vector<std::pair<double, size_t>> nearest;
  for (size_t i = 0; i < sets_.size(); ++i) {
    if (!exclude_image.empty() && sets_[i].image == exclude_image) continue;
    const Eigen::Vector3d ray = (centre_ - CentreOf(sets_[i].cam_from_world)).normalized();
    nearest.emplace_back(std::acos(std::clamp(ray.dot(desired), -1.0, 1.0)), i);
  }
  std::sort(nearest.begin(), nearest.end());
  if (static_cast<int>(nearest.size()) > references_) nearest.resize(references_);
  const int width = camera.width, height = camera.height;
  cv::Mat weighted(height, width, CV_32FC3, cv::Scalar::all(0));  // sum of w * premultiplied colour
  cv::Mat weights(height, width, CV_32F, cv::Scalar::all(0));     // sum of w * alpha
  cv::Mat alpha(height, width, CV_32F, cv::Scalar::all(0));       // largest alpha
  const double soft = 0.5 * M_PI / 180.0;
  CompositeScratch scratch;  // the references' drawings share their buffers
  for (const auto& [angle, i] : nearest) {
    const float w = static_cast<float>(1.0 / ((angle + soft) * (angle + soft)));
    // Each composited row goes into the blend at once.
    auto blend = [&](int y, const cv::Vec3f* c, const float* a) {
      cv::Vec3f* acc = weighted.ptr<cv::Vec3f>(y);
      float* wsum = weights.ptr<float>(y);
      float* amax = alpha.ptr<float>(y);
      for (int x = 0; x < width; ++x) {
        if (a[x] <= 0) continue;
        acc[x] += w * c[x];
        wsum[x] += w * a[x];
        amax[x] = std::max(amax[x], a[x]);
      }
    };
    if (folders_.empty()) {
      CompositeLayerRows(sets_[i], camera, cam_from_world, kLayerMaxDepthStep, &scratch, blend);
    } else {
      CompositeLayerRows(ReadLayerSet(folders_[i]), camera, cam_from_world, kLayerMaxDepthStep, &scratch, blend);
    }
  }
  RenderResult result;
  result.image = cv::Mat(height, width, CV_8UC3, cv::Scalar::all(0));
  result.coverage = cv::Mat(height, width, CV_8UC1, cv::Scalar::all(0));
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      if (alpha.at<float>(y, x) < 0.5f || !(weights.at<float>(y, x) > 0)) continue;
      const cv::Vec3f colour = weighted.at<cv::Vec3f>(y, x) / weights.at<float>(y, x);  // not premultiplied
      result.image.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uint8_t>(colour[0]), cv::saturate_cast<uint8_t>(colour[1]),
                                                   cv::saturate_cast<uint8_t>(colour[2]));
      result.coverage.at<uint8_t>(y, x) = 255;
      ++result.covered_pixels;
    }
  }
  return result;
}

}  // namespace ibmr
