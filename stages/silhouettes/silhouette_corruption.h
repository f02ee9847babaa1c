// Wrong silhouettes on purpose, for the stability matrix: the training masks eroded, dilated or
// punched with holes, with a strength in [0, 1], so that carving (and everything the hull bounds)
// can be measured where its input is wrong. Test-data degradation (no seed section); the held-out
// views' masks, used only for scoring, are never corrupted.
//
//   erode, dilate  a disc of radius strength * 2.5% of the image diagonal
//   holes          round(strength * 6) discs of radius 2% of the diagonal punched into the
//                  foreground, placed by a hash of the view name (deterministic)
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace ibmr {

enum class SilhouetteCorruption { kNone, kErode, kDilate, kHoles };

// "none", "erode", "dilate", "holes" -> the enum; false for an unknown name.
bool SilhouetteCorruptionFromName(const std::string& name, SilhouetteCorruption* corruption);

// `mask` (CV_8UC1, 255 foreground) corrupted in place; `view` seeds where holes go.
void CorruptSilhouette(SilhouetteCorruption corruption, double strength, const std::string& view, cv::Mat* mask);

}  // namespace ibmr
