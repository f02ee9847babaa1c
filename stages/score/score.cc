// Held-out-view scoring metrics (seed 000 lines 5906-5920, prediction error): PSNR, SSIM,
// coverage, masked variants, gain correction, nearest-camera angle. See score.h.
#include "stages/score/score.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace ibmr {

namespace {

constexpr double kMaxPsnr = 100.0;

double Psnr(double sum_squared, size_t samples) {
  if (samples == 0) return 0;
  const double mse = sum_squared / samples;
  if (mse <= 0) return kMaxPsnr;
  return std::min(kMaxPsnr, 10.0 * std::log10(255.0 * 255.0 / mse));
}

// Per-pixel SSIM (mean over the channels), CV_64FC1: Wang et al.'s index with an 11x11 Gaussian
// window (sigma 1.5) over each channel's means, variances and covariance. The products and the
// index are computed pixel by pixel in one pass each, into the working images `s` (SsimBuffers):
// on full-size photos (1600 x 1202) the matrix expressions this replaces allocated about twenty
// fresh 15 MB matrices a channel, whose page faults took most of the score stage's time.
// The blurs run in float on the values less 128 (variances and covariance do not change with the
// shift; the means get it back): OpenCV's float filters are vectorised, its double ones are not,
// and the blurs were most of the SSIM's time. The shift keeps the squares at most 2^14 so that
// E[a^2] - E[a]^2 loses little to rounding: against the double computation the index moves by at
// most 2e-6 in templeRing's scores (14 models, 6 views), 5e-6 in the tests' bright, flat images
// (measured, not a bound: a single pixel of a flat, saturated window can move by a few 1e-5).
// `reference`: the photo `a8`'s blurred values and squares, PrepareSsimReference(a8), or null
// to blur them here.
constexpr double kSsimSigma = 1.5;
const cv::Size kSsimWindow(11, 11);

// Channel c of an 8-bit image less kSsimShift, and its squares, as floats.
constexpr float kSsimShift = 128.f;
void ChannelAndSquare(const cv::Mat& image8, int c, cv::Mat* values, cv::Mat* squares) {
  const int channels = image8.channels();
  values->create(image8.size(), CV_32F);
  squares->create(image8.size(), CV_32F);
  for (int y = 0; y < image8.rows; ++y) {
    const uint8_t* p = image8.ptr<uint8_t>(y) + c;
    float *v = values->ptr<float>(y), *sq = squares->ptr<float>(y);
    for (int x = 0; x < image8.cols; ++x) {
      v[x] = p[x * channels] - kSsimShift;
      sq[x] = v[x] * v[x];
    }
  }
}

cv::Mat SsimMap(const cv::Mat& a8, const cv::Mat& b8, SsimBuffers& s, const SsimReference* reference) {
  const double c1 = (0.01 * 255) * (0.01 * 255), c2 = (0.03 * 255) * (0.03 * 255);
  const int channels = a8.channels(), rows = a8.rows, cols = a8.cols;
  const double share = 1.0 / channels;
  s.ab.create(a8.size(), CV_32F);  // ChannelAndSquare makes the others (a's not at all with a reference)
  cv::Mat mean(a8.size(), CV_64F, cv::Scalar(0));
  for (int c = 0; c < channels; ++c) {
    // a's statistics from the reference when there is one (the same blurs of the same values).
    if (reference == nullptr) {
      ChannelAndSquare(a8, c, &s.a, &s.aa);
      cv::GaussianBlur(s.a, s.mu_a, kSsimWindow, kSsimSigma);
      cv::GaussianBlur(s.aa, s.blur_aa, kSsimWindow, kSsimSigma);
    }
    ChannelAndSquare(b8, c, &s.b, &s.bb);
    for (int y = 0; y < rows; ++y) {
      const uint8_t* pa = a8.ptr<uint8_t>(y) + c;
      const float* b = s.b.ptr<float>(y);
      float* ab = s.ab.ptr<float>(y);
      for (int x = 0; x < cols; ++x) ab[x] = (pa[x * channels] - kSsimShift) * b[x];
    }
    cv::GaussianBlur(s.b, s.mu_b, kSsimWindow, kSsimSigma);
    cv::GaussianBlur(s.bb, s.blur_bb, kSsimWindow, kSsimSigma);
    cv::GaussianBlur(s.ab, s.blur_ab, kSsimWindow, kSsimSigma);
    const cv::Mat& mu_a_map = reference ? reference->mean[c] : s.mu_a;
    const cv::Mat& blur_aa_map = reference ? reference->mean_square[c] : s.blur_aa;
    for (int y = 0; y < rows; ++y) {
      const float *mu_a = mu_a_map.ptr<float>(y), *mu_b = s.mu_b.ptr<float>(y);
      const float *blur_aa = blur_aa_map.ptr<float>(y), *blur_bb = s.blur_bb.ptr<float>(y), *blur_ab = s.blur_ab.ptr<float>(y);
      double* out = mean.ptr<double>(y);
      for (int x = 0; x < cols; ++x) {
        // Variances and covariance of the shifted values (the same as of the values), means unshifted.
        const double ma = mu_a[x], mb = mu_b[x];
        const double var_a = blur_aa[x] - ma * ma, var_b = blur_bb[x] - mb * mb, cov = blur_ab[x] - ma * mb;
        const double mean_a = ma + kSsimShift, mean_b = mb + kSsimShift;
        const double numerator = (2 * mean_a * mean_b + c1) * (2 * cov + c2);
        const double denominator = (mean_a * mean_a + mean_b * mean_b + c1) * (var_a + var_b + c2);
        out[x] += (denominator != 0 ? numerator / denominator : 0.0) * share;
      }
    }
  }
  return mean;
}

MaskedScore Accumulate(const cv::Mat& real, const cv::Mat& rendered, const cv::Mat& ssim, const cv::Mat& counted,
                       const cv::Mat& ssim_counted, size_t denominator_pixels) {
  MaskedScore score;
  double sum_squared = 0, sum_ssim = 0;
  size_t ssim_pixels = 0;
  for (int y = 0; y < real.rows; ++y) {
    const uint8_t* r = real.ptr<uint8_t>(y);
    const uint8_t* g = rendered.ptr<uint8_t>(y);
    const uint8_t* m = counted.ptr<uint8_t>(y);
    const uint8_t* s = ssim_counted.ptr<uint8_t>(y);
    for (int x = 0; x < real.cols; ++x) {
      if (!m[x]) continue;
      ++score.pixels;
      for (int c = 0; c < 3; ++c) {
        const double d = static_cast<double>(r[3 * x + c]) - g[3 * x + c];
        sum_squared += d * d;
      }
      if (s[x]) {
        sum_ssim += ssim.at<double>(y, x);
        ++ssim_pixels;
      }
    }
  }
  score.psnr = Psnr(sum_squared, 3 * score.pixels);
  score.ssim = ssim_pixels ? sum_ssim / ssim_pixels : 0.0;
  score.coverage = denominator_pixels ? static_cast<double>(score.pixels) / denominator_pixels : 0.0;
  return score;
}

// Pixels of `counted` whose 11x11 SSIM window lies inside `counted`; `counted` itself when none.
cv::Mat SsimSupport(const cv::Mat& counted) {
  cv::Mat eroded;
  cv::erode(counted, eroded, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(11, 11)), cv::Point(-1, -1), 1,
            cv::BORDER_CONSTANT, cv::Scalar(0));
  return cv::countNonZero(eroded) > 0 ? eroded : counted;
}

}  // namespace

bool ScoreOptions::Check(std::string* error) const {
  if (!(near_angle_deg >= 0 && near_angle_deg < 180)) {
    *error = "near_angle_deg: must be in [0, 180), got " + std::to_string(near_angle_deg);
    return false;
  }
  if (photo_threshold < -1 || photo_threshold > 255) {
    *error = "photo_threshold: must be in [-1, 255], got " + std::to_string(photo_threshold);
    return false;
  }
  if (error_gain < 1 || error_gain > 64) {
    *error = "error_gain: must be in [1, 64], got " + std::to_string(error_gain);
    return false;
  }
  return true;
}

bool MeanOfFinitePoints(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d* mean) {
  const size_t count = std::count_if(points.begin(), points.end(), [](const Eigen::Vector3d& p) { return p.allFinite(); });
  if (count == 0) return false;
  // Summed as p / count, as before finite points were counted apart: the same centre to the bit.
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : points) {
    if (p.allFinite()) sum += p / static_cast<double>(count);
  }
  *mean = sum;
  return true;
}

SsimReference PrepareSsimReference(const cv::Mat& real) {
  if (real.type() != CV_8UC3) throw std::invalid_argument("PrepareSsimReference: the photo must be CV_8UC3");
  SsimReference reference;
  reference.channels = 3;
  cv::Mat values, squares;
  for (int c = 0; c < reference.channels; ++c) {
    ChannelAndSquare(real, c, &values, &squares);
    cv::GaussianBlur(values, reference.mean[c], kSsimWindow, kSsimSigma);
    cv::GaussianBlur(squares, reference.mean_square[c], kSsimWindow, kSsimSigma);
  }
  return reference;
}

ImageScore ScoreImage(const cv::Mat& real, const cv::Mat& rendered_in, const cv::Mat& coverage, const cv::Mat& mask,
                      const ScoreOptions& options, SsimBuffers* buffers, const SsimReference* reference) {
  SsimBuffers own;
  SsimBuffers& working = buffers != nullptr ? *buffers : own;
  if (real.type() != CV_8UC3 || rendered_in.type() != CV_8UC3 || coverage.type() != CV_8UC1 ||
      real.size() != rendered_in.size() || real.size() != coverage.size() ||
      (!mask.empty() && (mask.type() != CV_8UC1 || mask.size() != real.size()))) {
    throw std::invalid_argument("ScoreImage: images must be CV_8UC3 (real, render) and CV_8UC1 (coverage, mask) of one size");
  }
  if (reference != nullptr && !reference->Matches(real)) {
    throw std::invalid_argument("ScoreImage: the SSIM reference was prepared from an image of another size");
  }
  ImageScore score;
  cv::Mat rendered = rendered_in.clone();
  if (options.gain_correction) {
    double num[3] = {0, 0, 0}, den[3] = {0, 0, 0};
    for (int y = 0; y < real.rows; ++y) {
      const uint8_t* r = real.ptr<uint8_t>(y);
      const uint8_t* g = rendered.ptr<uint8_t>(y);
      const uint8_t* m = coverage.ptr<uint8_t>(y);
      for (int x = 0; x < real.cols; ++x) {
        if (!m[x]) continue;
        for (int c = 0; c < 3; ++c) {
          num[c] += static_cast<double>(r[3 * x + c]) * g[3 * x + c];
          den[c] += static_cast<double>(g[3 * x + c]) * g[3 * x + c];
        }
      }
    }
    for (int c = 0; c < 3; ++c) score.gains[c] = den[c] > 0 ? num[c] / den[c] : 1.0;
    for (int y = 0; y < real.rows; ++y) {
      uint8_t* g = rendered.ptr<uint8_t>(y);
      for (int x = 0; x < real.cols; ++x) {
        for (int c = 0; c < 3; ++c) g[3 * x + c] = cv::saturate_cast<uint8_t>(g[3 * x + c] * score.gains[c]);
      }
    }
  }
  const cv::Mat covered = coverage > 0;
  const cv::Mat ssim = SsimMap(real, rendered, working, reference);
  score.all = Accumulate(real, rendered, ssim, covered, SsimSupport(covered), static_cast<size_t>(real.total()));
  if (!mask.empty()) {
    score.has_mask = true;
    const cv::Mat foreground = mask > 0;
    const cv::Mat counted = covered & foreground;
    score.mask = Accumulate(real, rendered, ssim, counted, SsimSupport(counted),
                            static_cast<size_t>(cv::countNonZero(foreground)));
  }
  cv::Mat brightest;
  cv::Mat channels[3];
  cv::split(real, channels);
  cv::max(channels[0], channels[1], brightest);
  cv::max(brightest, channels[2], brightest);
  const cv::Mat lit = brightest > options.photo_threshold;
  cv::Mat black_holes = cv::Mat::zeros(rendered.size(), rendered.type());
  rendered.copyTo(black_holes, covered);
  // Renders are already black where uncovered (render.h): the SSIM map is then the one above.
  const bool same = cv::norm(black_holes, rendered, cv::NORM_INF) == 0;
  score.photo = Accumulate(real, black_holes, same ? ssim : SsimMap(real, black_holes, working, reference), lit, SsimSupport(lit),
                           static_cast<size_t>(cv::countNonZero(lit)));
  score.photo.coverage = score.photo.pixels ? static_cast<double>(cv::countNonZero(lit & covered)) / score.photo.pixels : 0.0;
  return score;
}

cv::Mat SideBySide(const cv::Mat& real, const cv::Mat& rendered, const cv::Mat& coverage, int error_gain) {
  cv::Mat error;
  cv::absdiff(real, rendered, error);
  error *= error_gain;
  error.setTo(cv::Scalar(64, 0, 0), coverage == 0);
  cv::Mat out;
  cv::hconcat(std::vector<cv::Mat>{real, rendered, error}, out);
  return out;
}

double NearestCameraAngleDeg(const Eigen::Vector3d& center, const std::vector<Eigen::Vector3d>& others,
                             const Eigen::Vector3d& scene_center, int* nearest) {
  *nearest = -1;
  double best = 180.0;
  const Eigen::Vector3d a = center - scene_center;
  for (size_t i = 0; i < others.size(); ++i) {
    const Eigen::Vector3d b = others[i] - scene_center;
    const double angle = std::atan2(a.cross(b).norm(), a.dot(b)) * 180.0 / M_PI;
    if (angle < best || *nearest < 0) {
      best = angle;
      *nearest = static_cast<int>(i);
    }
  }
  return best;
}

}  // namespace ibmr
