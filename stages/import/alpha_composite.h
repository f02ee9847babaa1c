// Photos with an alpha channel (NeRF's Blender layout: RGBA PNGs of an object on a transparent
// background) made into what every later stage reads: the colour composited over a known
// background, as NeRF's loader does (rgb * a + background * (1 - a)), and the alpha kept apart
// (the silhouettes' source, silhouettes mode alpha).
//
// PNG stores straight (not premultiplied) alpha (PNG specification, 12.8 "Alpha channel
// creation"), and the Blender layout's files are PNGs written that way; `premultiplied` is for
// files whose colour was already multiplied by alpha (composite: colour + background * (1 - a)).
// 8- and 16-bit samples alike: 16-bit values are scaled by 1/257 (65535 -> 255) and rounded, so
// that an alpha of 8 or 16 bits above one half maps to 128..255 and one at or below it to 0..127:
// the mask "alpha > 0.5" is "alpha8 >= 128" for both.
#pragma once

#include <opencv2/core.hpp>

namespace ibmr {

struct AlphaComposite {
  cv::Mat bgr;    // CV_8UC3: the colour over the background
  cv::Mat alpha;  // CV_8UC1: the alpha, 255 opaque
};

// `image` as decoded unchanged: CV_8U or CV_16U with 4 channels (BGRA) or 2 (grey, alpha).
// Throws std::invalid_argument for other layouts (the caller names the file).
AlphaComposite CompositeOverBackground(const cv::Mat& image, const cv::Vec3b& background_bgr, bool premultiplied);

// True when the decoded image carries an alpha channel (2 or 4 channels).
inline bool HasAlpha(const cv::Mat& image) { return image.channels() == 2 || image.channels() == 4; }

}  // namespace ibmr
