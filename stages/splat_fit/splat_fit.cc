// The splat fit: Adam on the re-synthesis error with density control (see splat_fit.h).
#include "stages/splat_fit/splat_fit.h"

#include "stages/splat_fit/photometric_loss.h"

#include <Eigen/Geometry>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <random>
#include <stdexcept>
#include <unordered_map>

namespace ibmr {

bool SplatFitOptions::Check(std::string* error) const {
  const auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (iterations < 1) return fail("iterations: must be >= 1");
  if (sh_degree < 0 || sh_degree > 3) return fail("sh_degree: must be in [0, 3]");
  if (!(dssim_weight >= 0 && dssim_weight <= 1)) return fail("dssim_weight: must be in [0, 1]");
  if (!(lr_gain >= 0 && lr_gain < 1)) return fail("lr_gain: must be in [0, 1)");
  if (!(lr_background >= 0 && lr_background < 1)) return fail("lr_background: must be in [0, 1)");
  if (sh_every < 1) return fail("sh_every: must be >= 1");
  if (!(coarse_fraction >= 0 && coarse_fraction <= 1)) return fail("coarse_fraction: must be in [0, 1]");
  for (const auto& [key, value] : std::vector<std::pair<const char*, double>>{{"lr_position", lr_position},
                                                                             {"lr_position_final", lr_position_final},
                                                                             {"lr_rotation", lr_rotation},
                                                                             {"lr_scale", lr_scale},
                                                                             {"lr_opacity", lr_opacity},
                                                                             {"lr_sh_dc", lr_sh_dc},
                                                                             {"lr_sh_rest", lr_sh_rest}}) {
    if (!(value >= 0 && value < 10)) return fail(std::string(key) + ": must be in [0, 10)");
  }
  if (densify_every < 1) return fail("densify_every: must be >= 1");
  if (densify_from < 0) return fail("densify_from: must be >= 0");
  if (!(densify_until >= 0 && densify_until <= 1)) return fail("densify_until: must be in [0, 1]");
  if (!(densify_gradient > 0)) return fail("densify_gradient: must be > 0");
  if (!(dense_fraction > 0 && dense_fraction < 1)) return fail("dense_fraction: must be in (0, 1)");
  if (!(prune_opacity >= 0 && prune_opacity < 1)) return fail("prune_opacity: must be in [0, 1)");
  if (!(max_scale_fraction > 0 && max_scale_fraction <= 10)) return fail("max_scale_fraction: must be in (0, 10]");
  if (max_splats < 1) return fail("max_splats: must be >= 1");
  if (seed < 0) return fail("seed: must be >= 0");
  return true;
}

namespace {

// The mean of the views' camera centres (the origin without views).
Eigen::Vector3d CameraCentroid(const std::vector<SplatFitView>& views) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const SplatFitView& view : views) mean += view.camera.Centre().cast<double>();
  return mean / static_cast<double>(std::max<size_t>(1, views.size()));
}

// The `percent` percentile of the splats' distances from `centre` (0 without splats).
double DistancePercentile(const GaussianSplats& splats, const Eigen::Vector3d& centre, size_t percent) {
  std::vector<double> distances;
  for (const Eigen::Vector3f& p : splats.position) distances.push_back((p.cast<double>() - centre).norm());
  if (distances.empty()) return 0;
  const size_t k = distances.size() * percent / 100;
  std::nth_element(distances.begin(), distances.begin() + k, distances.end());
  return distances[k];
}

// Per channel, the sum over the pixels of a (CV_32FC3) times b (CV_32FC3, the same channel, or
// CV_32FC1, for every channel), without the full-frame temporaries cv::sum(a.mul(b)) makes.
Eigen::Vector3d ChannelProductSums(const cv::Mat& a, const cv::Mat& b) {
  const int b_channels = b.channels();
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (int y = 0; y < a.rows; ++y) {
    const float* pa = a.ptr<float>(y);
    const float* pb = b.ptr<float>(y);
    for (int x = 0; x < a.cols; ++x) {
      for (int c = 0; c < 3; ++c) sum[c] += pa[3 * x + c] * pb[b_channels == 3 ? 3 * x + c : x];
    }
  }
  return sum;
}

}  // namespace

double SceneExtent(const std::vector<SplatFitView>& views, const GaussianSplats& splats, double floor) {
  const Eigen::Vector3d mean = CameraCentroid(views);
  double radius = 0;
  for (const SplatFitView& view : views) radius = std::max(radius, (view.camera.Centre().cast<double>() - mean).norm());
  // A forward-facing capture's cameras span a small part of the scene: the splats' own reach from
  // the cameras (the 95th percentile of their distances) bounds it from below.
  const double reach = DistancePercentile(splats, mean, 95);
  return std::max({floor, 1.1 * radius, 1.1 * reach});
}

size_t AddBackdrop(const std::vector<SplatFitView>& views, int pixel_step, double distance_factor, float opacity,
                   GaussianSplats* splats) {
  if (pixel_step < 1) throw std::invalid_argument("backdrop pixel step must be >= 1");
  if (!(distance_factor > 1)) throw std::invalid_argument("backdrop distance factor must be > 1");
  if (splats->size() == 0 || views.empty()) throw std::invalid_argument("no splat or view to place a backdrop behind");
  const Eigen::Vector3d mean = CameraCentroid(views);
  const double radius = distance_factor * DistancePercentile(*splats, mean, 99);
  // Discs already placed, hashed by cells of the spacing (the spacing differs little across views:
  // the same sphere, similar focal lengths).
  std::unordered_map<int64_t, std::vector<Eigen::Vector3f>> placed;
  const auto key = [](const Eigen::Vector3i& c) {
    return (static_cast<int64_t>(c.x() & 0x1FFFFF) << 42) | (static_cast<int64_t>(c.y() & 0x1FFFFF) << 21) | (c.z() & 0x1FFFFF);
  };
  size_t added = 0;
  for (const SplatFitView& view : views) {
    const SplatCamera& camera = view.camera;
    const Eigen::Vector3d centre = camera.Centre().cast<double>();
    const Eigen::Matrix3d world_from_cam = camera.rotation.transpose().cast<double>();
    const int columns = (camera.width + pixel_step - 1) / pixel_step, rows = (camera.height + pixel_step - 1) / pixel_step;
    for (int r = 0; r < rows; ++r) {
      for (int c = 0; c < columns; ++c) {
        const int x0 = c * pixel_step, y0 = r * pixel_step;
        const int x1 = std::min(camera.width, x0 + pixel_step), y1 = std::min(camera.height, y0 + pixel_step);
        const Eigen::Vector3d ray = (world_from_cam * Eigen::Vector3d((0.5 * (x0 + x1) - camera.cx) / camera.fx,
                                                                      (0.5 * (y0 + y1) - camera.cy) / camera.fy, 1.0))
                                        .normalized();
        // |centre + t ray - mean| = radius, the far root (the cameras are inside the sphere).
        const Eigen::Vector3d o = centre - mean;
        const double b = o.dot(ray), disc = b * b - (o.squaredNorm() - radius * radius);
        if (disc < 0) continue;
        const double t = -b + std::sqrt(disc);
        if (!(t > 0)) continue;
        const Eigen::Vector3f point = (centre + t * ray).cast<float>();
        const float spacing = static_cast<float>(pixel_step * t / camera.fx);
        const Eigen::Vector3i cell = (point / spacing).array().floor().cast<int>();
        bool near = false;
        for (int dz = -1; dz <= 1 && !near; ++dz) {
          for (int dy = -1; dy <= 1 && !near; ++dy) {
            for (int dx = -1; dx <= 1 && !near; ++dx) {
              const auto found = placed.find(key(cell + Eigen::Vector3i(dx, dy, dz)));
              if (found == placed.end()) continue;
              for (const Eigen::Vector3f& q : found->second) near |= (q - point).norm() < 0.5f * spacing;
            }
          }
        }
        if (near) continue;
        placed[key(cell)].push_back(point);
        const cv::Scalar colour = cv::mean(view.image(cv::Rect(x0, y0, x1 - x0, y1 - y0)));
        const Eigen::Vector3f inward = (mean.cast<float>() - point).normalized();
        splats->Add(point, RotationWithNormal(inward), Eigen::Vector2f::Constant(std::log(0.6f * spacing)), opacity,
                    Eigen::Vector3f(colour[0], colour[1], colour[2]));
        ++added;
      }
    }
  }
  return added;
}

void RaiseShDegree(int degree, GaussianSplats* splats) {
  if (degree <= splats->sh_degree) return;
  const int old_k = splats->ShCount();
  const int new_k = (degree + 1) * (degree + 1);
  std::vector<float> sh(splats->size() * new_k * 3, 0.0f);
  for (size_t i = 0; i < splats->size(); ++i) {
    std::copy(splats->sh.begin() + i * old_k * 3, splats->sh.begin() + (i + 1) * old_k * 3, sh.begin() + i * new_k * 3);
  }
  splats->sh = std::move(sh);
  splats->sh_degree = degree;
}

namespace {

float Sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

// Adam (Kingma & Ba 2015) over one flat array of parameters.
struct Adam {
  std::vector<float> m, v;
  void Resize(size_t n) {
    m.assign(n, 0.0f);
    v.assign(n, 0.0f);
  }
  // One step on `x` with gradient `g` (both n floats), step size `lr`, at step `t` (1-based). With
  // `period` > 0, only the first `head` floats of every `period` take `lr`, the others `rest_lr`
  // (the SH array: each splat's DC coefficients, then its higher ones).
  void Step(float* x, const float* g, size_t n, float lr, int t, size_t period = 0, size_t head = 0, float rest_lr = 0) {
    constexpr float kBeta1 = 0.9f, kBeta2 = 0.999f, kEps = 1e-15f;
    const float c1 = 1.0f - std::pow(kBeta1, static_cast<float>(t));
    const float c2 = 1.0f - std::pow(kBeta2, static_cast<float>(t));
    const float correction = std::sqrt(c2) / c1;
    const float head_rate = lr * correction, rest_rate = rest_lr * correction;
    float* const first = m.data();
    float* const second = v.data();
    // Floats [begin, end) at one rate: a plain loop, which the compiler makes vector code (the
    // file is built without errno for sqrt).
    auto update = [&](size_t begin, size_t end, float rate) {
      for (size_t i = begin; i < end; ++i) {
        first[i] = kBeta1 * first[i] + (1.0f - kBeta1) * g[i];
        second[i] = kBeta2 * second[i] + (1.0f - kBeta2) * g[i] * g[i];
        x[i] -= rate * first[i] / (std::sqrt(second[i]) + kEps);
      }
    };
    if (period == 0) {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1 << 14), [&](const tbb::blocked_range<size_t>& range) {
        update(range.begin(), range.end(), head_rate);
      });
      return;
    }
    // Per splat: its first `head` floats, then the rest of its `period`.
    const size_t rows = (n + period - 1) / period;
    tbb::parallel_for(tbb::blocked_range<size_t>(0, rows, 1024), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t r = range.begin(); r != range.end(); ++r) {
        const size_t begin = r * period, split = std::min(n, begin + head), end = std::min(n, begin + period);
        update(begin, split, head_rate);
        update(split, end, rest_rate);
      }
    });
  }
  // Keeps the state of the splats that remain, per `origin` (index before the pass or -1: zero),
  // each splat `width` floats wide.
  void Remap(const std::vector<int>& origin, size_t width) {
    std::vector<float> new_m(origin.size() * width, 0.0f), new_v(origin.size() * width, 0.0f);
    for (size_t i = 0; i < origin.size(); ++i) {
      if (origin[i] < 0) continue;
      std::copy_n(m.begin() + origin[i] * width, width, new_m.begin() + i * width);
      std::copy_n(v.begin() + origin[i] * width, width, new_v.begin() + i * width);
    }
    m = std::move(new_m);
    v = std::move(new_v);
  }
};

struct Optimiser {
  Adam position, rotation, scale, opacity, sh;
  void Resize(const GaussianSplats& splats) {
    position.Resize(splats.size() * 3);
    rotation.Resize(splats.size() * 4);
    scale.Resize(splats.size() * 2);
    opacity.Resize(splats.size());
    sh.Resize(splats.sh.size());
  }
};

// The view at half resolution: the photo area-averaged, the camera scaled (pixel centres at +0.5
// keep their meaning).
SplatFitView HalfSize(const SplatFitView& view) {
  SplatFitView half = view;
  cv::resize(view.image, half.image, cv::Size(view.image.cols / 2, view.image.rows / 2), 0, 0, cv::INTER_AREA);
  const float sx = static_cast<float>(half.image.cols) / view.image.cols;
  const float sy = static_cast<float>(half.image.rows) / view.image.rows;
  half.camera.width = half.image.cols;
  half.camera.height = half.image.rows;
  half.camera.fx *= sx;
  half.camera.fy *= sy;
  half.camera.cx *= sx;
  half.camera.cy *= sy;
  return half;
}

}  // namespace

DensityCounts ControlDensity(const std::vector<float>& mean_screen_gradient, double extent, const SplatFitOptions& options,
                             GaussianSplats* splats, std::vector<int>* origin) {
  const size_t n = splats->size();
  const int k3 = splats->ShCount() * 3;
  DensityCounts counts;
  // Which to grow: above the threshold, the strongest first while the cap allows.
  std::vector<size_t> grow;
  for (size_t i = 0; i < n; ++i) {
    if (mean_screen_gradient[i] >= options.densify_gradient) grow.push_back(i);
  }
  std::sort(grow.begin(), grow.end(), [&](size_t a, size_t b) { return mean_screen_gradient[a] > mean_screen_gradient[b]; });
  const size_t room = options.max_splats > static_cast<int>(n) ? options.max_splats - n : 0;
  if (grow.size() > room) grow.resize(room);
  std::vector<uint8_t> action(n, 0);  // 1 clone, 2 split
  for (size_t i : grow) {
    const float radius = std::exp(splats->log_scale[i].maxCoeff());
    action[i] = radius > options.dense_fraction * extent ? 2 : 1;
  }
  GaussianSplats out;
  out.sh_degree = splats->sh_degree;
  origin->clear();
  const auto copy = [&](size_t i, int from) {
    out.position.push_back(splats->position[i]);
    out.rotation.push_back(splats->rotation[i]);
    out.log_scale.push_back(splats->log_scale[i]);
    out.opacity_logit.push_back(splats->opacity_logit[i]);
    out.sh.insert(out.sh.end(), splats->Sh(i), splats->Sh(i) + k3);
    origin->push_back(from);
  };
  for (size_t i = 0; i < n; ++i) {
    const float opacity = Sigmoid(splats->opacity_logit[i]);
    const float radius = std::exp(splats->log_scale[i].maxCoeff());
    if (opacity < options.prune_opacity || radius > options.max_scale_fraction * extent) {
      ++counts.pruned;
      continue;
    }
    if (action[i] == 2) {
      // Two discs along the longer axis at +-0.8 sigma, that axis's sigma times 0.6: the footprint's
      // mean and variance are kept (0.6^2 + 0.8^2 = 1), so the image changes little until the
      // gradient moves them apart (3DGS draws the two centres at random and divides both radii by
      // 1.6, which loses a third of the footprint).
      ++counts.splits;
      const Eigen::Matrix3f r = RotationMatrix(splats->rotation[i]);
      const int axis = splats->log_scale[i][0] >= splats->log_scale[i][1] ? 0 : 1;
      const float sigma = std::exp(splats->log_scale[i][axis]);
      for (const float side : {-1.0f, 1.0f}) {
        copy(i, -1);
        out.position.back() += r.col(axis) * (side * 0.8f * sigma);
        out.log_scale.back()[axis] += std::log(0.6f);
      }
      continue;
    }
    copy(i, static_cast<int>(i));
    if (action[i] == 1) {
      ++counts.clones;
      copy(i, -1);
    }
  }
  *splats = std::move(out);
  return counts;
}

SplatFitResult FitSplats(const std::vector<SplatFitView>& views, const Eigen::Vector3f& background,
                         const SplatFitOptions& options, GaussianSplats* splats, ProgressReporter* progress) {
  std::string error;
  if (!options.Check(&error)) throw std::invalid_argument(error);
  if (views.empty()) throw std::invalid_argument("no training view to fit the splats to");
  if (splats->size() == 0) throw std::invalid_argument("no splat to start from");
  NullProgress null_progress;
  if (!progress) progress = &null_progress;
  RaiseShDegree(options.sh_degree, splats);
  SplatFitResult result;
  result.extent = SceneExtent(views, *splats);
  std::vector<SplatFitView> half;
  const int coarse_steps = static_cast<int>(std::lround(options.coarse_fraction * options.iterations));
  if (coarse_steps > 0) {
    half.resize(views.size());
    tbb::parallel_for(size_t{0}, views.size(), [&](size_t i) { half[i] = HalfSize(views[i]); });
  }
  Optimiser adam;
  adam.Resize(*splats);
  std::vector<float> screen_sum(splats->size(), 0.0f);
  std::vector<int> screen_count(splats->size(), 0);
  std::mt19937_64 rng(static_cast<uint64_t>(options.seed));
  std::vector<size_t> order;
  SplatFrame frame;
  SplatGradients gradients;
  cv::Mat d_image, gained;
  PhotometricScratch loss_scratch;  // the loss's images, kept from step to step
  // Per-view log gains (options.view_gains) and their Adam state: 3 floats a view.
  // Each view's Adam counts its own steps (a view's gain moves only when it is drawn).
  std::vector<float> log_gain(options.view_gains ? views.size() * 3 : 0, 0.0f), d_log_gain(3, 0.0f);
  std::vector<Adam> gain_adam(options.view_gains ? views.size() : 0);
  std::vector<int> gain_steps(gain_adam.size(), 0);
  for (Adam& a : gain_adam) a.Resize(3);
  // The background drawn over, fitted (options.fit_background) with its own Adam.
  Eigen::Vector3f fitted_background = background;
  Eigen::Vector3f d_background = Eigen::Vector3f::Zero();
  Adam background_adam;
  background_adam.Resize(3);
  double window_l1 = 0, window_se = 0;
  int window = 0;
  int advanced = 0;  // steps reported to `progress`
  const int densify_until = static_cast<int>(options.densify_until * options.iterations);
  using Clock = std::chrono::steady_clock;
  progress->Begin("splat fit", options.iterations);
  for (int step = 1; step <= options.iterations; ++step) {
    if (order.empty()) {
      order.resize(views.size());
      std::iota(order.begin(), order.end(), 0);
      std::shuffle(order.begin(), order.end(), rng);
    }
    const size_t index = order.back();
    order.pop_back();
    const SplatFitView& view = step <= coarse_steps ? half[index] : views[index];
    SplatRasterOptions raster;
    raster.background = fitted_background;
    raster.sh_degree = std::min(options.sh_degree, (step - 1) / options.sh_every);
    auto start = Clock::now();
    RenderSplats(*splats, view.camera, raster, &frame);
    result.forward_seconds += std::chrono::duration<double>(Clock::now() - start).count();
    result.megapixel_steps += view.image.total() / 1e6;
    result.mean_splats += static_cast<double>(splats->size()) / options.iterations;
    // (1 - lambda) L1 + lambda D-SSIM and its gradient (photometric_loss.h), of the drawn image
    // times the view's gains where they are fitted: d loss / d drawn = gain * d loss / d gained,
    // d loss / d log gain = sum over the pixels of d loss / d gained * gained.
    const cv::Mat* drawn = &frame.image;
    Eigen::Vector3f gain = Eigen::Vector3f::Ones();
    if (options.view_gains) {
      for (int c = 0; c < 3; ++c) gain[c] = std::exp(log_gain[index * 3 + c]);
      cv::multiply(frame.image, cv::Scalar(gain[0], gain[1], gain[2]), gained);
      drawn = &gained;
    }
    const PhotometricLoss loss = PhotometricLossAndGradient(*drawn, view.image, options.dssim_weight, &d_image, &loss_scratch);
    if (options.view_gains) {
      const Eigen::Vector3d d_gain = ChannelProductSums(d_image, gained);
      for (int c = 0; c < 3; ++c) d_log_gain[c] = static_cast<float>(d_gain[c]);
      cv::multiply(d_image, cv::Scalar(gain[0], gain[1], gain[2]), d_image);
    }
    if (options.fit_background) {
      // image = splats + transmittance * background: d loss / d background = sum of d_image * T.
      d_background = ChannelProductSums(d_image, frame.transmittance).cast<float>();
    }
    window_l1 += loss.l1;
    window_se += loss.se;
    ++window;
    start = Clock::now();
    gradients.Reset(*splats);
    BackwardSplats(*splats, view.camera, frame, d_image, &gradients);
    result.backward_seconds += std::chrono::duration<double>(Clock::now() - start).count();
    for (size_t i = 0; i < splats->size(); ++i) {
      if (!frame.visible[i]) continue;
      screen_sum[i] += gradients.screen[i];
      ++screen_count[i];
    }
    // Adam, the position's step decaying exponentially from lr_position to lr_position_final.
    const double t = static_cast<double>(step - 1) / std::max(1, options.iterations - 1);
    const float lr_position = static_cast<float>(
        result.extent * std::exp((1 - t) * std::log(options.lr_position) + t * std::log(options.lr_position_final)));
    const size_t n = splats->size();
    adam.position.Step(splats->position[0].data(), gradients.position[0].data(), n * 3, lr_position, step);
    adam.rotation.Step(splats->rotation[0].data(), gradients.rotation[0].data(), n * 4, static_cast<float>(options.lr_rotation), step);
    adam.scale.Step(splats->log_scale[0].data(), gradients.log_scale[0].data(), n * 2, static_cast<float>(options.lr_scale), step);
    adam.opacity.Step(splats->opacity_logit.data(), gradients.opacity_logit.data(), n, static_cast<float>(options.lr_opacity), step);
    // SH: the DC coefficients (the first 3 of each splat's) at their step, the rest at theirs.
    adam.sh.Step(splats->sh.data(), gradients.sh.data(), splats->sh.size(), static_cast<float>(options.lr_sh_dc), step,
                 splats->ShCount() * 3, 3, static_cast<float>(options.lr_sh_rest));
    if (options.fit_background) {
      background_adam.Step(fitted_background.data(), d_background.data(), 3, static_cast<float>(options.lr_background), step);
      fitted_background = fitted_background.cwiseMax(0.0f).cwiseMin(1.0f);
    }
    if (options.view_gains) {
      gain_adam[index].Step(&log_gain[index * 3], d_log_gain.data(), 3, static_cast<float>(options.lr_gain), ++gain_steps[index]);
      // Gains and colours trade against each other: the views' mean log gain is held at 0.
      for (int c = 0; c < 3; ++c) {
        float mean = 0;
        for (size_t v = 0; v < views.size(); ++v) mean += log_gain[v * 3 + c] / views.size();
        for (size_t v = 0; v < views.size(); ++v) log_gain[v * 3 + c] -= mean;
      }
    }
    // Density control.
    if (step >= options.densify_from && step <= densify_until && step % options.densify_every == 0) {
      std::vector<float> mean(splats->size(), 0.0f);
      for (size_t i = 0; i < splats->size(); ++i) mean[i] = screen_count[i] > 0 ? screen_sum[i] / screen_count[i] : 0.0f;
      std::vector<int> origin;
      const DensityCounts counts =
          ControlDensity(mean, result.extent, options, splats, &origin);
      result.splits += counts.splits;
      result.clones += counts.clones;
      result.pruned += counts.pruned;
      adam.position.Remap(origin, 3);
      adam.rotation.Remap(origin, 4);
      adam.scale.Remap(origin, 2);
      adam.opacity.Remap(origin, 1);
      adam.sh.Remap(origin, splats->ShCount() * 3);
      screen_sum.assign(splats->size(), 0.0f);
      screen_count.assign(splats->size(), 0);
    }
    if (step % 50 == 0 || step == options.iterations) {
      SplatFitPoint point;
      point.iteration = step;
      point.l1 = window_l1 / window;
      const double mse = window_se / window;
      point.psnr = mse > 0 ? 10 * std::log10(1.0 / mse) : 100.0;
      point.splats = splats->size();
      result.curve.push_back(point);
      window_l1 = window_se = 0;
      window = 0;
      progress->Advance(step - advanced, "L1 " + std::to_string(point.l1).substr(0, 6) + ", " + std::to_string(point.splats) + " splats");
      advanced = step;
    }
  }
  progress->End();
  result.background = fitted_background;
  for (size_t v = 0; v < log_gain.size() / 3; ++v) {
    result.view_gains.emplace_back(std::exp(log_gain[v * 3]), std::exp(log_gain[v * 3 + 1]), std::exp(log_gain[v * 3 + 2]));
  }
  if (const std::string problem = splats->Validate(); !problem.empty()) {
    throw std::runtime_error("the splat fit diverged: " + problem + "; lower the step sizes (splat_fit.lr_*)");
  }
  return result;
}

}  // namespace ibmr
