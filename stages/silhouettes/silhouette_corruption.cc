// Wrong silhouettes on purpose (see silhouette_corruption.h).
#include "stages/silhouettes/silhouette_corruption.h"

#include <opencv2/imgproc.hpp>

#include <cmath>
#include <functional>
#include <random>
#include <vector>

namespace ibmr {

bool SilhouetteCorruptionFromName(const std::string& name, SilhouetteCorruption* corruption) {
  if (name == "none") *corruption = SilhouetteCorruption::kNone;
  else if (name == "erode") *corruption = SilhouetteCorruption::kErode;
  else if (name == "dilate") *corruption = SilhouetteCorruption::kDilate;
  else if (name == "holes") *corruption = SilhouetteCorruption::kHoles;
  else return false;
  return true;
}

void CorruptSilhouette(SilhouetteCorruption corruption, double strength, const std::string& view, cv::Mat* mask) {
  if (corruption == SilhouetteCorruption::kNone || strength <= 0 || mask->empty()) return;
  const double diagonal = std::hypot(mask->cols, mask->rows);
  if (corruption == SilhouetteCorruption::kErode || corruption == SilhouetteCorruption::kDilate) {
    const int radius = static_cast<int>(std::lround(strength * 0.025 * diagonal));
    if (radius < 1) return;
    const cv::Mat disc = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * radius + 1, 2 * radius + 1));
    if (corruption == SilhouetteCorruption::kErode) cv::erode(*mask, *mask, disc);
    else cv::dilate(*mask, *mask, disc);
    return;
  }
  const int holes = static_cast<int>(std::lround(strength * 6));
  const int radius = std::max(1, static_cast<int>(std::lround(0.02 * diagonal)));
  std::vector<cv::Point> foreground;
  cv::findNonZero(*mask, foreground);
  if (foreground.empty()) return;
  std::mt19937 rng(static_cast<uint32_t>(std::hash<std::string>{}(view)));
  std::uniform_int_distribution<size_t> pick(0, foreground.size() - 1);
  for (int k = 0; k < holes; ++k) cv::circle(*mask, foreground[pick(rng)], radius, cv::Scalar(0), cv::FILLED);
}

}  // namespace ibmr
