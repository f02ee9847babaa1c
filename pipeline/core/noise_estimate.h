// The noise level of a photograph, estimated from the photograph alone (issue 67: a confidence
// that sees the noise of the photos). Immerkaer, "Fast Noise Variance Estimation", CVIU 64(2),
// 1996: the difference of two Laplacians, N = [1 -2 1; -2 4 -2; 1 -2 1], cancels any image locally
// linear in x and y, and applied to zero-mean Gaussian noise of deviation s it leaves noise of
// deviation 6 s; the mean absolute response, times sqrt(pi / 2) / 6, estimates s. Texture and
// edges respond too, so here only the flattest half of the image (by the Sobel gradient's
// magnitude) is used, as homogeneous-region estimators do; the estimate is then a little low on
// pure noise (its own flattest half) and a little high on fine texture, and grows with the noise.
#pragma once

#include <opencv2/core.hpp>

namespace ibmr {

// Noise standard deviation in grey levels (0-255) of an 8-bit grey image; 0 for an image smaller
// than 3 x 3.
double EstimateNoiseSigma(const cv::Mat& gray);

}  // namespace ibmr
