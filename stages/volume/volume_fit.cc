// Phase 2 of the volume stage: the objective, its analytic gradient through the compositing and
// the bilinear reads, and the Adam / gradient steps (volume.h; seed 000 lines 5597-5604).
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "stages/volume/volume.h"

namespace ibmr {

namespace {

// A slot: the sample's B, G, R, alpha (replaced by dE/d of each in the backward pass), its position
// x, y in the plane (x NaN: no sample), the transmittance in front of it, and one float of padding
// (two slots per cache line).
constexpr size_t kSlot = 8;
constexpr float kSmoothEpsilon = 0.01f;

// rho(r) = sqrt(r^2 + e^2) - e and its derivative.
inline float Robust(float r, float e) { return std::sqrt(r * r + e * e) - e; }
inline float RobustDerivative(float r, float e) { return r / std::sqrt(r * r + e * e); }

// The data term of one view, added to `*loss` (not normalised); with `gradient`, 1/N times its
// gradient added. Rows of a band in parallel composite each pixel front to back and then walk its
// samples back to front for their derivatives; then the planes in parallel scatter the derivatives
// through the bilinear footprints (each plane its own slice of the gradient: no two threads write
// one cell, and each cell's sum is taken in pixel order whatever the threads).
//
// Within a row the planes are the outer loop and the pixels the inner one: a pass reads one plane's
// rows and writes one plane's slots, in order, so the hardware's prefetching follows it. With the
// pixels outermost, each pixel read 32 planes' cells and wrote 32 slots far apart; on 2 cores that
// order spent two thirds of the fit waiting for memory (perf, hard forward scene, 1202 x 877 x 32).
// The arithmetic and its order per pixel are the same in both.
void ViewDataTerm(const PlaneVolume& volume, const LevelView& view, const VolumeOptions& options, double inverse_n,
                  double* loss, float* gradient, std::vector<float>* scratch) {
  const int w = view.camera.width, h = view.camera.height, planes = volume.Planes();
  const VolumeRays rays(volume, view.camera, view.cam_from_world);
  const float e = static_cast<float>(options.robust_epsilon);
  const int band_rows = std::clamp(static_cast<int>(kVolumeBandFloats / (static_cast<size_t>(w) * planes * kSlot)), 1, h);
  const size_t band_pixels = static_cast<size_t>(band_rows) * w;
  // slots[(k * band_pixels + p) * kSlot]: plane k's sample at pixel p of the band.
  std::vector<float>& slots = *scratch;  // reused across views: no fresh pages per view
  if (gradient != nullptr && slots.size() < band_pixels * planes * kSlot) slots.resize(band_pixels * planes * kSlot);
  std::vector<double> row_loss(h, 0.0);
  for (int band = 0; band < h; band += band_rows) {
    const int rows_here = std::min(band_rows, h - band);
    tbb::parallel_for(tbb::blocked_range<int>(band, band + rows_here), [&](const tbb::blocked_range<int>& range) {
      // One row's state, reused by the task's rows.
      std::vector<VolumeRays::Ray> ray(w);
      std::vector<uint8_t> covered(w);  // the ray reaches the far plane inside the volume: data here
      std::vector<float> t(w), colour(static_cast<size_t>(w) * 3), g(static_cast<size_t>(w) * 3),
          behind(static_cast<size_t>(w) * 3);
      for (int y = range.begin(); y < range.end(); ++y) {
        const float* photo = view.image.ptr<float>(y);
        float* row_slots = gradient != nullptr ? slots.data() + static_cast<size_t>(y - band) * w * kSlot : nullptr;
        for (int x = 0; x < w; ++x) {
          ray[x] = rays.RayAt(x + 0.5, y + 0.5);
          covered[x] = rays.ReachesFarPlane(ray[x]) ? 1 : 0;
          t[x] = 1.f;
        }
        std::fill(colour.begin(), colour.end(), 0.f);
        // Front to back: the i-th plane along each pixel's ray, while light still passes.
        for (int i = 0; i < planes; ++i) {
          for (int x = 0; x < w; ++x) {
            const int k = rays.PlaneAt(ray[x], i);
            float* slot = row_slots != nullptr ? row_slots + (k * band_pixels + x) * kSlot : nullptr;
            RaySample sample;
            if (!covered[x] || t[x] <= kOpaqueTransmittance || !rays.On(ray[x], k, &sample) || !sample.inside) {
              if (slot != nullptr) slot[4] = NAN;
              continue;
            }
            float cell[4];
            SampleCell(volume.Plane(k), Footprint(volume.Width(), volume.Height(), sample.x, sample.y), cell);
            const float weight = cell[3] * t[x];
            for (int ch = 0; ch < 3; ++ch) colour[3 * x + ch] += weight * cell[ch];
            if (slot != nullptr) {
              for (int ch = 0; ch < 4; ++ch) slot[ch] = cell[ch];
              slot[4] = sample.x;
              slot[5] = sample.y;
              slot[6] = t[x];
            }
            t[x] *= 1.f - cell[3];
          }
        }
        for (int x = 0; x < w; ++x) {
          if (!covered[x]) continue;  // outside the volume's field of view: no data
          double pixel_loss = 0;
          for (int ch = 0; ch < 3; ++ch) {
            const float r = colour[3 * x + ch] - photo[3 * x + ch];
            pixel_loss += Robust(r, e);
            g[3 * x + ch] = static_cast<float>(RobustDerivative(r, e) * inverse_n);
          }
          row_loss[y] += pixel_loss;
        }
        if (row_slots == nullptr) continue;
        // Back to front: each sample's derivatives from the composite of the samples behind it.
        std::fill(behind.begin(), behind.end(), 0.f);
        for (int i = planes - 1; i >= 0; --i) {
          for (int x = 0; x < w; ++x) {
            if (!covered[x]) continue;
            float* slot = row_slots + (rays.PlaneAt(ray[x], i) * band_pixels + x) * kSlot;
            if (std::isnan(slot[4])) continue;
            const float a = slot[3], ti = slot[6];
            float d_alpha = 0;
            for (int ch = 0; ch < 3; ++ch) {
              const float c = slot[ch];
              slot[ch] = g[3 * x + ch] * a * ti;
              d_alpha += g[3 * x + ch] * (c - behind[3 * x + ch]);
              behind[3 * x + ch] = c * a + (1.f - a) * behind[3 * x + ch];
            }
            slot[3] = d_alpha * ti;
          }
        }
      }
    });
    if (gradient == nullptr) continue;
    const size_t pixels_here = static_cast<size_t>(rows_here) * w;
    tbb::parallel_for(0, planes, [&](int k) {
      float* plane_gradient = gradient + k * volume.PlaneFloats();
      for (size_t p = 0; p < pixels_here; ++p) {
        const float* in = &slots[(k * band_pixels + p) * kSlot];
        if (std::isnan(in[4])) continue;
        ScatterCell(plane_gradient, Footprint(volume.Width(), volume.Height(), in[4], in[5]), in);
      }
    });
  }
  for (int y = 0; y < h; ++y) *loss += row_loss[y];
}

// rho and rho' of the differences d[j] = next[j] - here[j], j < n: rho into `value`, `weight`
// times rho' into `derivative`. Plain loops over arrays with one square root shared by both: the
// compiler makes them vector code.
void RobustDifferences(const float* here, const float* next, size_t n, float weight, float* value, float* derivative) {
  for (size_t j = 0; j < n; ++j) {
    const float d = next[j] - here[j];
    const float root = std::sqrt(d * d + kSmoothEpsilon * kSmoothEpsilon);
    value[j] = root - kSmoothEpsilon;
    derivative[j] = weight * (d / root);
  }
}

// Smoothness and opacity prior over the cells (normalised by the cells per plane), with their
// gradient added; planes in parallel, summed in plane order. Row by row: the differences to the
// right neighbour, then to the neighbour below, each a vector loop over the row's floats.
double Regularizers(const PlaneVolume& volume, const VolumeOptions& options, float* gradient) {
  const int w = volume.Width(), h = volume.Height(), planes = volume.Planes();
  const size_t row_floats = static_cast<size_t>(w) * 4;
  const double inverse_m = 1.0 / (static_cast<double>(w) * h);
  const float smooth = static_cast<float>(options.smoothness * inverse_m);
  const float prior = static_cast<float>(options.opacity_prior * inverse_m);
  std::vector<double> plane_sum(planes, 0.0);
  tbb::parallel_for(0, planes, [&](int k) {
    const float* cells = volume.Plane(k);
    float* grad = gradient != nullptr ? gradient + k * volume.PlaneFloats() : nullptr;
    std::vector<float> value(row_floats), derivative(row_floats);
    double sum_smooth = 0, sum_prior = 0;
    // Adds rho over `n` differences to the sum and, with a gradient, rho' to the later cell and
    // minus rho' to the earlier one.
    auto add = [&](size_t here, size_t next, size_t n) {
      RobustDifferences(cells + here, cells + next, n, smooth, value.data(), derivative.data());
      for (size_t j = 0; j < n; ++j) sum_smooth += value[j];
      if (grad == nullptr || smooth <= 0) return;
      for (size_t j = 0; j < n; ++j) grad[next + j] += derivative[j];
      for (size_t j = 0; j < n; ++j) grad[here + j] -= derivative[j];
    };
    for (int y = 0; y < h; ++y) {
      const size_t row = static_cast<size_t>(y) * row_floats;
      if (w > 1) add(row, row + 4, row_floats - 4);
      if (y + 1 < h) add(row, row + row_floats, row_floats);
      for (size_t i = row + 3; i < row + row_floats; i += 4) {
        const float a = cells[i];
        sum_prior += a * (1.f - a);
        if (grad != nullptr) grad[i] += prior * (1.f - 2.f * a);
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
    // Two loops rather than a test per cell, so that each is vector code.
    float* values = volume->cells.data();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, cells, 1 << 16), [&](const tbb::blocked_range<size_t>& range) {
      if (adam) {
        for (size_t i = range.begin(); i < range.end(); ++i) {
          const float g = gradient[i];
          first[i] = kBeta1 * first[i] + (1.f - kBeta1) * g;
          second[i] = kBeta2 * second[i] + (1.f - kBeta2) * g * g;
          const float delta = step * (first[i] / correction1) / (std::sqrt(second[i] / correction2) + kAdamEpsilon);
          values[i] = std::min(std::max(values[i] - delta, 0.f), 1.f);
        }
      } else {
        for (size_t i = range.begin(); i < range.end(); ++i) {
          values[i] = std::min(std::max(values[i] - step * gradient[i], 0.f), 1.f);
        }
      }
    });
    PinFarPlane(volume, nullptr);
    if (progress != nullptr) progress->Advance(1);
  }
}

}  // namespace ibmr
