// Silhouette extraction: threshold or background difference, morphology, connected components,
// hole filling (seed 000 lines 4136-4200, footnote 2; Middlebury dino recipe). See silhouettes.h.
#include "stages/silhouettes/silhouettes.h"

#include <algorithm>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <vector>

namespace ibmr {

namespace {

// Per-pixel maximum over channels, CV_8UC1.
cv::Mat MaxOverChannels(const cv::Mat& image) {
  if (image.channels() == 1) return image.clone();
  std::vector<cv::Mat> channels;
  cv::split(image, channels);
  cv::Mat result = channels[0].clone();
  for (size_t c = 1; c < channels.size(); ++c) cv::max(result, channels[c], result);
  return result;
}

cv::Mat Disc(int radius) {
  return cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * radius + 1, 2 * radius + 1));
}

// Keeps the largest `max_components` components of >= `min_px` pixels; returns how many were found.
int KeepLargestComponents(int max_components, int min_px, cv::Mat* mask, int* kept) {
  cv::Mat labels, stats, centroids;
  const int count = cv::connectedComponentsWithStats(*mask, labels, stats, centroids, 8, CV_32S) - 1;
  std::vector<int> order;
  for (int label = 1; label <= count; ++label) {
    if (stats.at<int>(label, cv::CC_STAT_AREA) >= min_px) order.push_back(label);
  }
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return stats.at<int>(a, cv::CC_STAT_AREA) > stats.at<int>(b, cv::CC_STAT_AREA);
  });
  if (max_components > 0 && static_cast<int>(order.size()) > max_components) order.resize(max_components);
  std::vector<uint8_t> keep(count + 1, 0);
  for (int label : order) keep[label] = 255;
  for (int r = 0; r < mask->rows; ++r) {
    const int* label_row = labels.ptr<int>(r);
    uint8_t* row = mask->ptr<uint8_t>(r);
    for (int c = 0; c < mask->cols; ++c) row[c] = keep[label_row[c]];
  }
  *kept = static_cast<int>(order.size());
  return count;
}

// Fills background components that do not touch the border and have at most `max_px` pixels
// (-1: any size). Returns the number filled.
int FillHoles(int max_px, cv::Mat* mask) {
  if (max_px == 0) return 0;
  cv::Mat background = (*mask == 0);
  cv::Mat labels, stats, centroids;
  const int count = cv::connectedComponentsWithStats(background, labels, stats, centroids, 4, CV_32S) - 1;
  std::vector<uint8_t> fill(count + 1, 0);
  int filled = 0;
  for (int label = 1; label <= count; ++label) {
    const int x = stats.at<int>(label, cv::CC_STAT_LEFT), y = stats.at<int>(label, cv::CC_STAT_TOP);
    const int w = stats.at<int>(label, cv::CC_STAT_WIDTH), h = stats.at<int>(label, cv::CC_STAT_HEIGHT);
    const bool border = x == 0 || y == 0 || x + w == mask->cols || y + h == mask->rows;
    if (border || (max_px > 0 && stats.at<int>(label, cv::CC_STAT_AREA) > max_px)) continue;
    fill[label] = 1;
    ++filled;
  }
  if (filled == 0) return 0;
  for (int r = 0; r < mask->rows; ++r) {
    const int* label_row = labels.ptr<int>(r);
    uint8_t* row = mask->ptr<uint8_t>(r);
    for (int c = 0; c < mask->cols; ++c) {
      if (fill[label_row[c]]) row[c] = 255;
    }
  }
  return filled;
}

}  // namespace

bool SilhouetteOptions::Check(std::string* error) const {
  if (!(threshold >= 0.0 && threshold < 1.0)) {
    *error = "threshold: must be in [0, 1), got " + std::to_string(threshold);
  } else if (dilate_px < 0 || dilate_px > 200) {
    *error = "dilate_px: must be in [0, 200], got " + std::to_string(dilate_px);
  } else if (erode_px < 0 || erode_px > 200) {
    *error = "erode_px: must be in [0, 200], got " + std::to_string(erode_px);
  } else if (max_components < 0) {
    *error = "max_components: must be >= 0 (0 keeps all), got " + std::to_string(max_components);
  } else if (min_component_px < 0) {
    *error = "min_component_px: must be >= 0, got " + std::to_string(min_component_px);
  } else if (max_hole_px < -1) {
    *error = "max_hole_px: must be -1 (fill all), 0 (none) or a pixel count, got " + std::to_string(max_hole_px);
  } else {
    return true;
  }
  return false;
}

SilhouetteReport DescribeMask(const cv::Mat& mask) {
  SilhouetteReport report;
  if (mask.empty()) return report;
  const int foreground = cv::countNonZero(mask);
  report.foreground_fraction = static_cast<double>(foreground) / mask.total();
  cv::Mat labels;
  report.components_kept = foreground > 0 ? cv::connectedComponents(mask, labels, 8, CV_32S) - 1 : 0;
  report.components_found = report.components_kept;
  const int last_row = mask.rows - 1, last_col = mask.cols - 1;
  report.touches_border = cv::countNonZero(mask.row(0)) > 0 || cv::countNonZero(mask.row(last_row)) > 0 ||
                          cv::countNonZero(mask.col(0)) > 0 || cv::countNonZero(mask.col(last_col)) > 0;
  return report;
}

SilhouetteResult ExtractSilhouette(const cv::Mat& image, const cv::Mat& background, const SilhouetteOptions& options) {
  if (image.empty()) throw std::invalid_argument("the image is empty");
  if (image.depth() != CV_8U) throw std::invalid_argument("expected an 8-bit image");
  SilhouetteResult result;
  const int level = static_cast<int>(options.threshold * 255.0);  // foreground: value > level
  if (options.mode == SilhouetteMode::kUserMask) {
    result.mask = MaxOverChannels(image) > 127;
    result.report = DescribeMask(result.mask);
    return result;
  }
  if (options.mode == SilhouetteMode::kBackground) {
    if (background.size() != image.size() || background.type() != image.type()) {
      throw std::invalid_argument("the background image is " + std::to_string(background.cols) + "x" +
                                  std::to_string(background.rows) + " with " + std::to_string(background.channels()) +
                                  " channels, the image " + std::to_string(image.cols) + "x" +
                                  std::to_string(image.rows) + " with " + std::to_string(image.channels()));
    }
    cv::Mat difference;
    cv::absdiff(image, background, difference);
    result.mask = MaxOverChannels(difference) > level;
  } else {
    result.mask = MaxOverChannels(image) > level;
  }
  if (options.dilate_px > 0) cv::dilate(result.mask, result.mask, Disc(options.dilate_px));
  if (options.erode_px > 0) cv::erode(result.mask, result.mask, Disc(options.erode_px));
  int kept = 0;
  const int found = KeepLargestComponents(options.max_components, options.min_component_px, &result.mask, &kept);
  const int holes = FillHoles(options.max_hole_px, &result.mask);
  result.report = DescribeMask(result.mask);
  result.report.components_found = found;
  result.report.holes_filled = holes;
  return result;
}

}  // namespace ibmr
