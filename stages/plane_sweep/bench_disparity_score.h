// The benchmarks' disparity score against Middlebury ground truth (bench_stereo_pair,
// bench_process_start): over the pixels with a ground truth (non-zero, stored as disparity *
// scale), the percentages off by more than 1 and 2 pixels, a missing estimate (<= 0 or not finite)
// counted as bad, and the fraction missing.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <opencv2/core.hpp>

namespace ibmr {

struct DisparityScore {
  double bad1 = 0, bad2 = 0, unfilled = 0;
};

inline DisparityScore ScoreDisparity(const cv::Mat& disparity, const cv::Mat& gt, double scale) {
  CV_Assert(disparity.size() == gt.size() && disparity.type() == CV_32FC1 && gt.type() == CV_8UC1);
  DisparityScore s;
  size_t n = 0, bad1 = 0, bad2 = 0, missing = 0;
  for (int y = 0; y < gt.rows; ++y) {
    for (int x = 0; x < gt.cols; ++x) {
      const int g = gt.at<uint8_t>(y, x);
      if (g == 0) continue;
      ++n;
      const float d = disparity.at<float>(y, x);
      if (!(d > 0) || !std::isfinite(d)) {
        ++bad1, ++bad2, ++missing;
        continue;
      }
      const double err = std::fabs(d - g / scale);
      bad1 += err > 1.0;
      bad2 += err > 2.0;
    }
  }
  if (n == 0) return s;
  s.bad1 = 100.0 * bad1 / n;
  s.bad2 = 100.0 * bad2 / n;
  s.unfilled = static_cast<double>(missing) / n;
  return s;
}

}  // namespace ibmr
