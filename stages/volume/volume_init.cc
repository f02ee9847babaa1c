// Phase 1 of the volume stage (volume.h; seed 000 lines 5548-5557 and 5576-5596, slides 3700-3780):
// a plane sweep from the virtual camera gives each cell the mean colour of the training views'
// samples and a vote from the variance of those samples; the votes become opacities; then the
// samples are weighted by each view's visibility of the cell and the statistics recomputed.
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/plane_homography.h"
#include "stages/volume/volume.h"

namespace ibmr {

namespace {

// Per plane and cell: the weighted sums of the samples' colours, squared colours and weights.
struct SweepStatistics {
  int width = 0, height = 0, planes = 0;
  std::vector<float> sum;     // [k][cell][3]
  std::vector<float> sum_sq;  // [k][cell]: sum over channels of the squared colour
  std::vector<float> weight;  // [k][cell]
};

// Bilinear read of a float image (c channels) at index coordinates, which must be inside.
inline void ReadBilinear(const cv::Mat& image, int channels, float x, float y, float* out) {
  const int x0 = std::min(static_cast<int>(x), image.cols - 2), y0 = std::min(static_cast<int>(y), image.rows - 2);
  const float fx = x - x0, fy = y - y0;
  const float* r0 = image.ptr<float>(y0) + x0 * channels;
  const float* r1 = image.ptr<float>(y0 + 1) + x0 * channels;
  for (int c = 0; c < channels; ++c) {
    out[c] = (1 - fy) * ((1 - fx) * r0[c] + fx * r0[channels + c]) + fy * ((1 - fx) * r1[c] + fx * r1[channels + c]);
  }
}

// Adds every view's samples of every cell, weighted by the view's transmittance in front of the
// cell when `visibility` (the current opacities seen from the view), else by 1.
SweepStatistics Accumulate(const std::vector<LevelView>& views, const PlaneVolume& volume, bool visibility) {
  SweepStatistics stats;
  stats.width = volume.Width();
  stats.height = volume.Height();
  stats.planes = volume.Planes();
  const size_t cells = static_cast<size_t>(stats.width) * stats.height;
  stats.sum.assign(cells * stats.planes * 3, 0.f);
  stats.sum_sq.assign(cells * stats.planes, 0.f);
  stats.weight.assign(cells * stats.planes, 0.f);
  std::vector<double> inverse_depths;
  for (const double z : volume.depths) inverse_depths.push_back(1.0 / z);
  // Each pixel's ray once per view (the planes then only step along it); one buffer for every view.
  std::vector<VolumeRays::Ray> view_rays;
  for (const LevelView& view : views) {
    const int vw = view.camera.width, vh = view.camera.height;
    const std::vector<Eigen::Matrix3d> homographies =
        PlaneHomographies(volume.camera, volume.cam_from_world, view.camera, view.cam_from_world, inverse_depths);
    cv::Mat transmittance(vh, vw, CV_32F, cv::Scalar(1.f));
    const VolumeRays rays(volume, view.camera, view.cam_from_world);
    if (visibility) {
      view_rays.resize(static_cast<size_t>(vw) * vh);
      tbb::parallel_for(0, vh, [&](int y) {
        for (int x = 0; x < vw; ++x) view_rays[static_cast<size_t>(y) * vw + x] = rays.RayAt(x + 0.5, y + 0.5);
      });
    }
    // Front to back as the view sees the planes (its centre in front of the nearest one).
    for (int k = 0; k < stats.planes; ++k) {
      const Eigen::Matrix3d& hk = homographies[k];
      tbb::parallel_for(0, stats.height, [&](int y) {
        for (int x = 0; x < stats.width; ++x) {
          const Eigen::Vector3d q = hk * Eigen::Vector3d(x + 0.5, y + 0.5, 1.0);
          if (!(q.z() > 0)) continue;
          const float u = static_cast<float>(q.x() / q.z() - 0.5), v = static_cast<float>(q.y() / q.z() - 0.5);
          if (!(u >= 0 && v >= 0 && u <= vw - 1 && v <= vh - 1)) continue;
          float colour[3], seen = 1.f;
          ReadBilinear(view.image, 3, u, v, colour);
          if (visibility) ReadBilinear(transmittance, 1, u, v, &seen);
          const size_t cell = (static_cast<size_t>(k) * stats.height + y) * stats.width + x;
          for (int c = 0; c < 3; ++c) stats.sum[cell * 3 + c] += seen * colour[c];
          stats.sum_sq[cell] += seen * (colour[0] * colour[0] + colour[1] * colour[1] + colour[2] * colour[2]);
          stats.weight[cell] += seen;
        }
      });
      if (!visibility) continue;
      const float* plane = volume.Plane(k);
      tbb::parallel_for(0, vh, [&](int y) {
        float* t = transmittance.ptr<float>(y);
        const VolumeRays::Ray* row_rays = view_rays.data() + static_cast<size_t>(y) * vw;
        for (int x = 0; x < vw; ++x) {
          RaySample s;
          if (!rays.On(row_rays[x], k, &s) || !s.inside) continue;
          float cell[4];
          SampleCell(plane, Footprint(volume.Width(), volume.Height(), s.x, s.y), cell);
          t[x] *= 1.f - cell[3];
        }
      });
    }
  }
  return stats;
}

// Colours and opacities from the statistics: the mean colour; a cost per cell, the variance of
// the samples (mean over channels) in a box window, the largest where fewer than two views sample
// the cell; votes over each pixel's planes from the costs; opacities front to back whose
// composite weights a_k T_k are the votes.
void VotesToVolume(const SweepStatistics& stats, const VolumeOptions& options, PlaneVolume* volume) {
  const int w = stats.width, h = stats.height, planes = stats.planes;
  const size_t cells = static_cast<size_t>(w) * h;
  std::vector<cv::Mat> cost(planes);
  tbb::parallel_for(0, planes, [&](int k) {
    cv::Mat variance(h, w, CV_32F);
    float* plane = volume->Plane(k);
    for (size_t i = 0; i < cells; ++i) {
      const size_t cell = k * cells + i;
      const float n = stats.weight[cell];
      float mean[3] = {0.5f, 0.5f, 0.5f};
      if (n > 1e-3f) {
        for (int c = 0; c < 3; ++c) mean[c] = stats.sum[cell * 3 + c] / n;
      }
      for (int c = 0; c < 3; ++c) plane[i * 4 + c] = std::clamp(mean[c], 0.f, 1.f);
      const float spread = n > 1e-3f ? stats.sum_sq[cell] / n - (mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2]) : 0.f;
      variance.at<float>(static_cast<int>(i)) = n >= 1.5f ? std::max(0.f, spread) / 3.f : 1.f;
    }
    if (options.window_radius > 0) {
      const int side = 2 * options.window_radius + 1;
      cv::boxFilter(variance, cost[k], CV_32F, cv::Size(side, side), cv::Point(-1, -1), true, cv::BORDER_REPLICATE);
    } else {
      cost[k] = variance;
    }
  });
  const float temperature = static_cast<float>(options.vote_temperature);
  tbb::parallel_for(0, h, [&](int y) {
    std::vector<float> votes(planes);
    for (int x = 0; x < w; ++x) {
      const int i = y * w + x;
      float least = cost[0].at<float>(i);
      int winner = 0;
      for (int k = 1; k < planes; ++k) {
        if (cost[k].at<float>(i) < least) least = cost[k].at<float>(i), winner = k;
      }
      float total = 0;
      for (int k = 0; k < planes; ++k) {
        votes[k] = temperature > 0 ? std::exp(-(cost[k].at<float>(i) - least) / temperature) : (k == winner ? 1.f : 0.f);
        total += votes[k];
      }
      float before = 0;  // votes of the planes in front
      for (int k = 0; k < planes; ++k) {
        const float vote = votes[k] / total;
        const float alpha = before < 1.f - 1e-6f ? std::clamp(vote / (1.f - before), 0.f, 1.f) : 0.f;
        volume->Plane(k)[static_cast<size_t>(i) * 4 + 3] = k == planes - 1 ? 1.f : alpha;
        before += vote;
      }
    }
  });
}

}  // namespace

void InitializeVolume(const std::vector<LevelView>& views, const VolumeOptions& options, PlaneVolume* volume) {
  VotesToVolume(Accumulate(views, *volume, /*visibility=*/false), options, volume);
  for (int round = 0; round < options.visibility_rounds; ++round) {
    VotesToVolume(Accumulate(views, *volume, /*visibility=*/true), options, volume);
  }
}

}  // namespace ibmr
