// Noise estimation (see noise_estimate.h).
#include "pipeline/core/noise_estimate.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <vector>

namespace ibmr {

double EstimateNoiseSigma(const cv::Mat& gray) {
  if (gray.empty() || gray.rows < 3 || gray.cols < 3) return 0;
  cv::Mat f;
  gray.convertTo(f, CV_32F);
  const cv::Mat kernel = (cv::Mat_<float>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1);
  cv::Mat response, gx, gy;
  cv::filter2D(f, response, CV_32F, kernel, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  cv::Sobel(f, gx, CV_32F, 1, 0, 3, 1, 0, cv::BORDER_REFLECT);
  cv::Sobel(f, gy, CV_32F, 0, 1, 3, 1, 0, cv::BORDER_REFLECT);
  // The interior pixels' gradient magnitudes, and the flattest half of them.
  std::vector<std::pair<float, float>> samples;  // (gradient, |response|)
  samples.reserve(static_cast<size_t>(f.rows - 2) * (f.cols - 2));
  for (int y = 1; y < f.rows - 1; ++y) {
    const float *r = response.ptr<float>(y), *x_row = gx.ptr<float>(y), *y_row = gy.ptr<float>(y);
    for (int x = 1; x < f.cols - 1; ++x) samples.emplace_back(x_row[x] * x_row[x] + y_row[x] * y_row[x], std::abs(r[x]));
  }
  const size_t half = std::max<size_t>(1, samples.size() / 2);
  std::nth_element(samples.begin(), samples.begin() + static_cast<long>(half - 1), samples.end());
  double sum = 0;
  for (size_t i = 0; i < half; ++i) sum += samples[i].second;
  return std::sqrt(M_PI / 2) / 6 * sum / static_cast<double>(half);
}

}  // namespace ibmr
