// The splat fit's photometric loss: L1 and D-SSIM (see photometric_loss.h).
#include "stages/splat_fit/photometric_loss.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <cmath>
#include <functional>
#include <opencv2/imgproc.hpp>

namespace ibmr {

namespace {

constexpr double kC1 = 0.01 * 0.01, kC2 = 0.03 * 0.03;

// The SSIM window: 11x11 Gaussian, sigma 1.5, zero outside the image (its own adjoint).
void Window(const cv::Mat& in, cv::Mat* out) {
  cv::GaussianBlur(in, *out, cv::Size(11, 11), 1.5, 1.5, cv::BORDER_CONSTANT);
}

}  // namespace

PhotometricLoss PhotometricLossAndGradient(const cv::Mat& render, const cv::Mat& photo, double dssim_weight,
                                           cv::Mat* d_render, PhotometricScratch* scratch) {
  CV_Assert(render.type() == CV_32FC3 && photo.type() == CV_32FC3 && render.size() == photo.size());
  d_render->create(render.size(), CV_32FC3);
  const double n = 3.0 * static_cast<double>(render.total());
  const float l1_scale = static_cast<float>((1.0 - dssim_weight) / n);
  struct Sums {
    double l1 = 0, se = 0;
  };
  // L1: d / d pixel = sign(render - photo) (1 - lambda) / n.
  // Deterministic: the same split and join order every run (the fit's bytes do not depend on the
  // threads' timing).
  const Sums sums = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<int>(0, render.rows, 16), Sums(),
      [&](const tbb::blocked_range<int>& rows, Sums s) {
        for (int y = rows.begin(); y != rows.end(); ++y) {
          const cv::Vec3f* r = render.ptr<cv::Vec3f>(y);
          const cv::Vec3f* p = photo.ptr<cv::Vec3f>(y);
          cv::Vec3f* d = d_render->ptr<cv::Vec3f>(y);
          for (int x = 0; x < render.cols; ++x) {
            for (int c = 0; c < 3; ++c) {
              const float e = r[x][c] - p[x][c];
              d[x][c] = e > 0 ? l1_scale : e < 0 ? -l1_scale : 0.0f;
              s.l1 += std::abs(e);
              s.se += e * e;
            }
          }
        }
        return s;
      },
      [](Sums a, const Sums& b) {
        a.l1 += b.l1;
        a.se += b.se;
        return a;
      });
  PhotometricLoss out;
  out.l1 = sums.l1 / n;
  out.se = sums.se / n;
  out.loss = (1.0 - dssim_weight) * out.l1;
  if (dssim_weight <= 0) return out;

  // SSIM's moments, its map, and the three maps its gradient is made of.
  PhotometricScratch own;
  PhotometricScratch& m = scratch != nullptr ? *scratch : own;
  cv::Mat &mu_x = m.mu_x, &mu_y = m.mu_y, &xx = m.xx, &yy = m.yy, &xy = m.xy;
  Window(render, &mu_x);
  Window(photo, &mu_y);
  cv::multiply(render, render, m.product);
  Window(m.product, &xx);
  cv::multiply(photo, photo, m.product);
  Window(m.product, &yy);
  cv::multiply(render, photo, m.product);
  Window(m.product, &xy);
  m.alpha.create(render.size(), CV_32FC3);
  m.beta.create(render.size(), CV_32FC3);
  m.gamma.create(render.size(), CV_32FC3);
  cv::Mat &alpha = m.alpha, &beta = m.beta, &gamma = m.gamma;
  const double ssim_sum = tbb::parallel_deterministic_reduce(
      tbb::blocked_range<int>(0, render.rows, 16), 0.0,
      [&](const tbb::blocked_range<int>& rows, double ssim_sum) {
        for (int y = rows.begin(); y != rows.end(); ++y) {
          const cv::Vec3f *mx = mu_x.ptr<cv::Vec3f>(y), *my = mu_y.ptr<cv::Vec3f>(y), *sxx = xx.ptr<cv::Vec3f>(y),
                          *syy = yy.ptr<cv::Vec3f>(y), *sxy = xy.ptr<cv::Vec3f>(y);
          cv::Vec3f *a = alpha.ptr<cv::Vec3f>(y), *b = beta.ptr<cv::Vec3f>(y), *g = gamma.ptr<cv::Vec3f>(y);
          for (int x = 0; x < render.cols; ++x) {
            for (int c = 0; c < 3; ++c) {
              const double ux = mx[x][c], uy = my[x][c];
              const double vx = sxx[x][c] - ux * ux, vy = syy[x][c] - uy * uy, cxy = sxy[x][c] - ux * uy;
              const double a1 = 2 * ux * uy + kC1, a2 = 2 * cxy + kC2, b1 = ux * ux + uy * uy + kC1, b2 = vx + vy + kC2;
              const double s = a1 * a2 / (b1 * b2);
              ssim_sum += s;
              a[x][c] = static_cast<float>(s * (2 * uy / a1 - 2 * ux / b1 - 2 * uy / a2 + 2 * ux / b2));
              b[x][c] = static_cast<float>(2 * s / a2);
              g[x][c] = static_cast<float>(-2 * s / b2);
            }
          }
        }
        return ssim_sum;
      },
      std::plus<double>());
  out.ssim = ssim_sum / n;
  out.loss += dssim_weight * (1.0 - out.ssim);
  cv::Mat &ga = m.g_alpha, &gb = m.g_beta, &gg = m.g_gamma;
  Window(alpha, &ga);
  Window(beta, &gb);
  Window(gamma, &gg);
  // d lambda (1 - mean S) / d x_q = -lambda / n (G*alpha + y_q G*beta + x_q G*gamma).
  const float ssim_scale = static_cast<float>(-dssim_weight / n);
  tbb::parallel_for(tbb::blocked_range<int>(0, render.rows), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y != rows.end(); ++y) {
      const cv::Vec3f *r = render.ptr<cv::Vec3f>(y), *p = photo.ptr<cv::Vec3f>(y);
      const cv::Vec3f *a = ga.ptr<cv::Vec3f>(y), *b = gb.ptr<cv::Vec3f>(y), *g = gg.ptr<cv::Vec3f>(y);
      cv::Vec3f* d = d_render->ptr<cv::Vec3f>(y);
      for (int x = 0; x < render.cols; ++x) {
        for (int c = 0; c < 3; ++c) d[x][c] += ssim_scale * (a[x][c] + p[x][c] * b[x][c] + r[x][c] * g[x][c]);
      }
    }
  });
  return out;
}

}  // namespace ibmr
