// Steps 2 and 3 of the two-view layered method (layered_pair.h), and step 5's refit: the layers'
// disparity planes d = a x + b y + c, found by sequential RANSAC on the valid pixels of the initial
// disparity (MSAC score, the three samples near each other, least-squares refits on the inliers),
// each refined by robust least squares (Ceres, Cauchy loss) on its inliers; optionally re-fitted the
// same way to the pixels a label assignment gave it. Internal to the layered_stereo stage: callers
// use layered_pair.h.
//
// Follows seed 000, lines 5625-5811 (Szeliski, BMVC'99, section 4 "Layered representations":
// layers with an explicit plane equation) and lines 3798-3846 (slides "Layered Stereo": a plane
// per sprite), after Baker, Szeliski & Anandan, "A layered approach to stereo reconstruction",
// CVPR 1998.
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "stages/layered_stereo/layered_pair.h"

namespace ibmr {
namespace layered_internal {

// Steps 2 and 3 on the valid pixels of `initial`: sequential RANSAC (the plane with the best score,
// refitted by least squares to its inliers, takes them; again on the rest, until max_layers planes
// or too few points), then each plane refined robustly. Planes largest first.
std::vector<DisparityPlane> FindPlanes(const cv::Mat& initial, const LayeredPairOptions& options);

// Step 5: each plane re-fitted (robustly) to the disparities of the pixels assigned to it, whose
// residual lies inside the searched range (at its ends the plane is off, not the pixel).
void RefitPlanes(const cv::Mat& labels, const std::vector<float>& disparity, const std::vector<uint8_t>& hole,
                 const LayeredPairOptions& options, std::vector<DisparityPlane>* planes);

// Pixels without an initial disparity: below 0.5 (a winner at the searched range's end), NaN or
// infinite (see ValidPoints in disparity_planes.cc).
std::vector<uint8_t> Holes(const cv::Mat& initial);

}  // namespace layered_internal
}  // namespace ibmr
