// The noise estimate against synthetic noise of known deviation, on a smooth image (a ramp and a
// soft blob) and on a textured one: it follows the noise, and a clean image reads near 0.
#include "pipeline/core/noise_estimate.h"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

namespace ibmr {
namespace {

cv::Mat Smooth(int w, int h) {
  cv::Mat image(h, w, CV_32F);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double dx = x - w / 2.0, dy = y - h / 2.0;
      image.at<float>(y, x) = static_cast<float>(60 + 0.3 * x + 0.2 * y + 60 * std::exp(-(dx * dx + dy * dy) / 4000.0));
    }
  }
  return image;
}

cv::Mat Textured(int w, int h) {
  cv::Mat noise(h, w, CV_32F), texture;
  cv::RNG rng(3);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 255);
  cv::GaussianBlur(noise, texture, cv::Size(0, 0), 3);  // blobs a few pixels wide
  cv::normalize(texture, texture, 40, 210, cv::NORM_MINMAX);
  return texture;
}

cv::Mat WithNoise(const cv::Mat& clean, double sigma, int seed) {
  cv::Mat noise(clean.size(), CV_32F), noisy;
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::NORMAL, 0, sigma);
  cv::Mat sum = clean + noise;
  sum.convertTo(noisy, CV_8U);  // rounded and clipped as a photo stores it
  return noisy;
}

TEST(NoiseEstimate, FollowsTheNoiseOfASmoothImage) {
  const cv::Mat clean = Smooth(320, 240);
  EXPECT_LT(EstimateNoiseSigma(WithNoise(clean, 0, 1)), 0.5);  // rounding alone
  for (const double sigma : {2.0, 5.0, 10.0, 20.0}) {
    const double estimate = EstimateNoiseSigma(WithNoise(clean, sigma, 7));
    EXPECT_NEAR(estimate, sigma, 0.25 * sigma) << "sigma " << sigma;
  }
}

TEST(NoiseEstimate, GrowsWithTheNoiseOfATexturedImage) {
  const cv::Mat clean = Textured(320, 240);
  double previous = EstimateNoiseSigma(WithNoise(clean, 0, 1));
  EXPECT_LT(previous, 2.0);  // texture a few pixels wide reads as little noise
  for (const double sigma : {4.0, 8.0, 16.0}) {
    const double estimate = EstimateNoiseSigma(WithNoise(clean, sigma, 7));
    EXPECT_GT(estimate, previous) << "sigma " << sigma;
    EXPECT_NEAR(estimate, sigma, 0.35 * sigma) << "sigma " << sigma;
    previous = estimate;
  }
  EXPECT_EQ(EstimateNoiseSigma(cv::Mat(2, 2, CV_8U, cv::Scalar(9))), 0.0);
}

}  // namespace
}  // namespace ibmr
