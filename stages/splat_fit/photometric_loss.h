// The splat fit's photometric loss and its gradient with respect to the rendered image: L1, plus,
// with weight `dssim_weight` (lambda), the structural term of Kerbl et al., "3D Gaussian Splatting"
// (SIGGRAPH 2023) §7: (1 - lambda) L1 + lambda (1 - SSIM), 3DGS's lambda 0.2. SSIM is Wang et al.'s
// (IEEE TIP 2004) with an 11x11 Gaussian window of sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, per channel,
// averaged over pixels and channels; the window is zero outside the image, as 3DGS's convolution
// pads (so that the gradient is the same convolution applied back, exactly).
//
// Gradient of the mean SSIM: with mu, sigma^2, sigma_xy the windowed moments at pixel p, A1 =
// 2 mu_x mu_y + C1, A2 = 2 sigma_xy + C2, B1 = mu_x^2 + mu_y^2 + C1, B2 = sigma_x^2 + sigma_y^2 +
// C2 and S = A1 A2 / (B1 B2), dS_p / dx_q = G(p - q) (alpha_p + beta_p y_q + gamma_p x_q) with
// alpha = S (2 mu_y / A1 - 2 mu_x / B1 - 2 mu_y / A2 + 2 mu_x / B2), beta = 2 S / A2, gamma =
// -2 S / B2; summed over p that is G * alpha + y (G * beta) + x (G * gamma).
#pragma once

#include <opencv2/core.hpp>

namespace ibmr {

struct PhotometricLoss {
  double l1 = 0;    // mean absolute error over pixels and channels
  double se = 0;    // mean squared error
  double ssim = 1;  // mean SSIM (1 when dssim_weight is 0: not computed)
  double loss = 0;  // (1 - lambda) l1 + lambda (1 - ssim)
};

// The structural term's images (moments, products, the gradient's maps: 12 of the image's size),
// kept by a caller that evaluates the loss step after step: fresh ones each step (14 with the
// products) were 128 MB of new pages per step at 1008x756, zeroed by the kernel (6% of a fit's time).
struct PhotometricScratch {
  cv::Mat mu_x, mu_y, xx, yy, xy, product, alpha, beta, gamma, g_alpha, g_beta, g_gamma;
};

// `render` and `photo`: CV_32FC3 of one size, values in [0, 1]. Writes d loss / d render into
// `d_render` (CV_32FC3, reallocated only when its size differs). dssim_weight in [0, 1].
// `scratch` (optional) keeps the intermediate images from one call to the next.
PhotometricLoss PhotometricLossAndGradient(const cv::Mat& render, const cv::Mat& photo, double dssim_weight,
                                           cv::Mat* d_render, PhotometricScratch* scratch = nullptr);

}  // namespace ibmr
