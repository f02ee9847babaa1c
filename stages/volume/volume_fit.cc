// Phase 2 of the volume stage: the objective, its analytic gradient through the compositing and
// the bilinear reads, and the Adam / gradient steps (volume.h; seed 000 lines 5597-5604).
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "stages/volume/volume.h"

namespace ibmr {

namespace {

// Gradient buffers hold this many floats per band of training rows at most (a band's per-plane
// coefficients: 4 derivatives and the cell position per plane and pixel).
constexpr size_t kBandFloats = size_t{1} << 22;
constexpr float kSmoothEpsilon = 0.01f;

// rho(r) = sqrt(r^2 + e^2) - e and its derivative.
inline float Robust(float r, float e) { return std::sqrt(r * r + e * e) - e; }
inline float RobustDerivative(float r, float e) { return r / std::sqrt(r * r + e * e); }

// The data term of one view, added to `*loss` (not normalised); with `gradient`, 1/N times its
// gradient added. Rows of a band in parallel compute each pixel's composite and its derivatives
// per plane; then the planes in parallel scatter them through the bilinear footprints (each plane
// its own slice of the gradient: no two threads write one cell).
void ViewDataTerm(const PlaneVolume& volume, const LevelView& view, const VolumeOptions& options, double inverse_n,
                  double* loss, float* gradient, std::vector<float>* scratch) {
  const int w = view.camera.width, h = view.camera.height, planes = volume.Planes();
  const VolumeRays rays(volume, view.camera, view.cam_from_world);
  const float e = static_cast<float>(options.robust_epsilon);
  const int band_rows = std::clamp(static_cast<int>(kBandFloats / (static_cast<size_t>(w) * planes * 6)), 1, h);
  const size_t band_pixels = static_cast<size_t>(band_rows) * w;
  // coef[(k * band_pixels + p) * 6 + {0..3}]: dE/d(B, G, R, alpha) of plane k's sample at pixel p;
  // {4, 5}: the sample's position (x NaN: no sample).
  std::vector<float>& coef = *scratch;  // reused across views: no fresh pages per view
  if (gradient != nullptr && coef.size() < band_pixels * planes * 6) coef.resize(band_pixels * planes * 6);
  std::vector<double> row_loss(h, 0.0);
  for (int band = 0; band < h; band += band_rows) {
    const int rows_here = std::min(band_rows, h - band);
    tbb::parallel_for(tbb::blocked_range<int>(band, band + rows_here), [&](const tbb::blocked_range<int>& range) {
      std::vector<RaySample> samples(planes);
      std::vector<float> cells(static_cast<size_t>(planes) * 4), transmittance(planes);
      std::vector<CellFootprint> footprints(planes);
      std::vector<uint8_t> written(planes);
      for (int y = range.begin(); y < range.end(); ++y) {
        const float* photo = view.image.ptr<float>(y);
        for (int x = 0; x < w; ++x) {
          const size_t p = static_cast<size_t>(y - band) * w + x;
          const VolumeRays::Ray ray = rays.RayAt(x + 0.5, y + 0.5);
          int used = 0;  // samples composited: the ray stops where the transmittance is ~0
          if (rays.ReachesFarPlane(ray)) {  // else outside the volume's field of view: no data
            float t = 1.f;
            for (int i = 0; i < planes && t > kOpaqueTransmittance; ++i) {
              if (!rays.On(ray, rays.PlaneAt(ray, i), &samples[used]) || !samples[used].inside) continue;
              transmittance[used] = t;
              footprints[used] = Footprint(volume.Width(), volume.Height(), samples[used].x, samples[used].y);
              float* cell = &cells[static_cast<size_t>(used) * 4];
              SampleCell(volume.Plane(samples[used].plane), footprints[used], cell);
              t *= 1.f - cell[3];
              ++used;
            }
          }
          if (gradient != nullptr) {  // planes without a sample here scatter nothing
            std::fill(written.begin(), written.end(), 0);
            for (int i = 0; i < used; ++i) written[samples[i].plane] = 1;
            for (int k = 0; k < planes; ++k) {
              if (!written[k]) coef[(k * band_pixels + p) * 6 + 4] = NAN;
            }
          }
          if (used == 0) continue;
          float c[3] = {0, 0, 0};
          for (int i = 0; i < used; ++i) {
            const float* cell = &cells[static_cast<size_t>(i) * 4];
            const float weight = cell[3] * transmittance[i];
            for (int ch = 0; ch < 3; ++ch) c[ch] += weight * cell[ch];
          }
          float g[3];
          double pixel_loss = 0;
          for (int ch = 0; ch < 3; ++ch) {
            const float r = c[ch] - photo[3 * x + ch];
            pixel_loss += Robust(r, e);
            g[ch] = static_cast<float>(RobustDerivative(r, e) * inverse_n);
          }
          row_loss[y] += pixel_loss;
          if (gradient == nullptr) continue;
          float behind[3] = {0, 0, 0};  // the composite of the planes behind sample i
          for (int i = used - 1; i >= 0; --i) {
            const float* cell = &cells[static_cast<size_t>(i) * 4];
            const float a = cell[3], ti = transmittance[i];
            float* out = &coef[(samples[i].plane * band_pixels + p) * 6];
            float d_alpha = 0;
            for (int ch = 0; ch < 3; ++ch) {
              out[ch] = g[ch] * a * ti;
              d_alpha += g[ch] * (cell[ch] - behind[ch]);
              behind[ch] = cell[ch] * a + (1.f - a) * behind[ch];
            }
            out[3] = d_alpha * ti;
            out[4] = samples[i].x;
            out[5] = samples[i].y;
          }
        }
      }
    });
    if (gradient == nullptr) continue;
    const size_t pixels_here = static_cast<size_t>(rows_here) * w;
    tbb::parallel_for(0, planes, [&](int k) {
      float* plane_gradient = gradient + k * volume.PlaneFloats();
      for (size_t p = 0; p < pixels_here; ++p) {
        const float* in = &coef[(k * band_pixels + p) * 6];
        if (std::isnan(in[4])) continue;
        ScatterCell(plane_gradient, Footprint(volume.Width(), volume.Height(), in[4], in[5]), in);
      }
    });
  }
  for (int y = 0; y < h; ++y) *loss += row_loss[y];
}

// Smoothness and opacity prior over the cells (normalised by the cells per plane), with their
// gradient added; planes in parallel, summed in plane order.
double Regularizers(const PlaneVolume& volume, const VolumeOptions& options, float* gradient) {
  const int w = volume.Width(), h = volume.Height(), planes = volume.Planes();
  const double inverse_m = 1.0 / (static_cast<double>(w) * h);
  const float smooth = static_cast<float>(options.smoothness * inverse_m);
  const float prior = static_cast<float>(options.opacity_prior * inverse_m);
  std::vector<double> plane_sum(planes, 0.0);
  tbb::parallel_for(0, planes, [&](int k) {
    const float* cells = volume.Plane(k);
    float* grad = gradient != nullptr ? gradient + k * volume.PlaneFloats() : nullptr;
    double sum_smooth = 0, sum_prior = 0;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = (static_cast<size_t>(y) * w + x) * 4;
        for (int dir = 0; dir < 2; ++dir) {
          if ((dir == 0 && x + 1 >= w) || (dir == 1 && y + 1 >= h)) continue;
          const size_t j = dir == 0 ? i + 4 : i + static_cast<size_t>(w) * 4;
          for (int ch = 0; ch < 4; ++ch) {
            const float d = cells[j + ch] - cells[i + ch];
            sum_smooth += Robust(d, kSmoothEpsilon);
            if (grad != nullptr && smooth > 0) {
              const float gd = smooth * RobustDerivative(d, kSmoothEpsilon);
              grad[j + ch] += gd;
              grad[i + ch] -= gd;
            }
          }
        }
        const float a = cells[i + 3];
        sum_prior += a * (1.f - a);
        if (grad != nullptr) grad[i + 3] += prior * (1.f - 2.f * a);
      }
    }
    plane_sum[k] = options.smoothness * inverse_m * sum_smooth + options.opacity_prior * inverse_m * sum_prior;
  });
  double total = 0;
  for (const double s : plane_sum) total += s;
  return total;
}

// Keeps the farthest plane opaque: its opacity is not a parameter.
void PinFarPlane(PlaneVolume* volume, std::vector<float>* gradient) {
  const int far_plane = volume->Planes() - 1;
  float* cells = volume->Plane(far_plane);
  for (size_t i = 3; i < volume->PlaneFloats(); i += 4) cells[i] = 1.f;
  if (gradient != nullptr) {
    float* grad = gradient->data() + far_plane * volume->PlaneFloats();
    for (size_t i = 3; i < volume->PlaneFloats(); i += 4) grad[i] = 0.f;
  }
}

}  // namespace

double VolumeObjective(const PlaneVolume& volume, const std::vector<LevelView>& views, const VolumeOptions& options,
                       std::vector<float>* gradient, double* data, std::vector<float>* scratch) {
  std::vector<float> own_scratch;
  if (scratch == nullptr) scratch = &own_scratch;
  size_t total = 0;  // N: the views' pixels
  for (const LevelView& view : views) total += static_cast<size_t>(view.camera.width) * view.camera.height;
  const double inverse_n = 1.0 / std::max<size_t>(1, total);
  if (gradient != nullptr) gradient->assign(volume.cells.size(), 0.f);
  double loss = 0;
  for (const LevelView& view : views) {
    ViewDataTerm(volume, view, options, inverse_n, &loss, gradient != nullptr ? gradient->data() : nullptr, scratch);
  }
  const double data_term = loss * inverse_n;
  if (data != nullptr) *data = data_term;
  return data_term + Regularizers(volume, options, gradient != nullptr ? gradient->data() : nullptr);
}

void RefineVolume(const std::vector<LevelView>& views, const VolumeOptions& options, int level, int iterations,
                  PlaneVolume* volume, std::vector<VolumeCurvePoint>* curve, ProgressReporter* progress) {
  PinFarPlane(volume, nullptr);
  std::vector<float> gradient, first, second, scratch;  // scratch: the data term's bands, reused by every step
  const bool adam = options.optimizer == VolumeOptimizer::kAdam;
  if (adam) {
    first.assign(volume->cells.size(), 0.f);
    second.assign(volume->cells.size(), 0.f);
  }
  constexpr float kBeta1 = 0.9f, kBeta2 = 0.99f, kAdamEpsilon = 1e-8f;
  // Each step sees views_per_step of the views (all with 0), taken in turn.
  const size_t batch = options.views_per_step > 0 ? std::min<size_t>(options.views_per_step, views.size()) : views.size();
  std::vector<LevelView> batch_views(batch);
  for (int it = 0; it <= iterations; ++it) {
    const bool last = it == iterations;
    double data = 0;
    if (last) {  // the curve ends with the objective over every view
      const double objective = VolumeObjective(*volume, views, options, nullptr, &data, &scratch);
      curve->push_back({level, it, objective, data});
      break;
    }
    for (size_t j = 0; j < batch; ++j) batch_views[j] = views[(static_cast<size_t>(it) * batch + j) % views.size()];
    const double objective = VolumeObjective(*volume, batch_views, options, &gradient, &data, &scratch);
    curve->push_back({level, it, objective, data});
    // The step falls geometrically to a tenth over the level's steps.
    const float step = static_cast<float>(options.learning_rate * std::pow(0.1, static_cast<double>(it) / iterations));
    PinFarPlane(volume, &gradient);
    const float correction1 = 1.f - std::pow(kBeta1, static_cast<float>(it + 1));
    const float correction2 = 1.f - std::pow(kBeta2, static_cast<float>(it + 1));
    const size_t cells = volume->cells.size();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, cells, 1 << 16), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t i = range.begin(); i < range.end(); ++i) {
        const float g = gradient[i];
        float delta;
        if (adam) {
          first[i] = kBeta1 * first[i] + (1.f - kBeta1) * g;
          second[i] = kBeta2 * second[i] + (1.f - kBeta2) * g * g;
          delta = step * (first[i] / correction1) / (std::sqrt(second[i] / correction2) + kAdamEpsilon);
        } else {
          delta = step * g;
        }
        volume->cells[i] = std::clamp(volume->cells[i] - delta, 0.f, 1.f);
      }
    });
    PinFarPlane(volume, nullptr);
    if (progress != nullptr) progress->Advance(1);
  }
}

}  // namespace ibmr
