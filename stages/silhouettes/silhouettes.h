// Foreground silhouettes of an object photographed against a known background: the input of
// octree carving. Follows seed 000, Szeliski's "Rapid octree construction" section 2 (lines
// 4136-4200): silhouettes "extracted from imagery by first acquiring an image of a blank
// turntable, and then doing simple pixel differencing", with footnote 2 "to close up small holes
// in the silhouette, we use a combination of morphological operations and connected components";
// and the Middlebury dino recipe (threshold 0.19, dilate 10, erode 7; datasets README.txt).
//
// Three modes:
//  * kThreshold: foreground where max(R, G, B) / 255 > threshold (a dark background).
//  * kBackground: foreground where max over channels |image - background| / 255 > threshold.
//  * kUserMask: a mask supplied by the user, binarised at 127 (no post-processing).
// Threshold and background modes then dilate by `dilate_px`, erode by `erode_px` (discs), keep the
// `max_components` largest 8-connected components (and only those of >= `min_component_px`
// pixels), and fill holes (background components not connected to the image border) of at most
// `max_hole_px` pixels (-1: every hole).
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace ibmr {

enum class SilhouetteMode { kThreshold, kBackground, kUserMask };

struct SilhouetteOptions {
  SilhouetteMode mode = SilhouetteMode::kThreshold;
  double threshold = 0.19;     // intensity (or difference) in [0, 1] of full scale, in [0, 1)
  int dilate_px = 10;          // radius of the dilation disc in pixels, in [0, 200]
  int erode_px = 7;            // radius of the erosion disc in pixels (after dilation), in [0, 200]
  int max_components = 1;      // largest components kept, >= 1; 0 keeps them all
  int min_component_px = 0;    // components smaller than this (pixels) are dropped, >= 0
  int max_hole_px = -1;        // holes of at most this many pixels are filled; -1: all, 0: none

  // Returns false and sets `error` (starting with the YAML key) when a value is out of range.
  bool Check(std::string* error) const;
};

// What a mask looks like, for masks/report.json.
struct SilhouetteReport {
  double foreground_fraction = 0.0;  // foreground pixels / all pixels
  int components_found = 0;          // 8-connected components before filtering (threshold modes)
  int components_kept = 0;           // components in the final mask
  int holes_filled = 0;              // holes closed by the hole filling
  bool touches_border = false;       // a foreground pixel lies on the image border: the object may
                                     // extend out of view, so carving must treat outside as unknown
};

struct SilhouetteResult {
  cv::Mat mask;  // CV_8UC1, 0 background, 255 foreground, same size as the image
  SilhouetteReport report;
};

// Extracts the silhouette of `image` (CV_8UC3 BGR or CV_8UC1). `background` is required (same size
// and type) in kBackground mode and ignored otherwise; in kUserMask mode `image` is the user mask.
// Throws std::invalid_argument when the sizes or types do not fit (the adapter names the file).
SilhouetteResult ExtractSilhouette(const cv::Mat& image, const cv::Mat& background, const SilhouetteOptions& options);

// Foreground fraction, component count and border contact of a 0/255 mask.
SilhouetteReport DescribeMask(const cv::Mat& mask);

}  // namespace ibmr
