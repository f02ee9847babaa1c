// What an import knows about a capture beyond its cameras, for the stages after it:
//   splits.json      {"<image name>": "train" | "val" | "test", ...}: the split each image came
//                    from (NeRF's Blender layout, nerfstudio's *_filenames lists). The runner's
//                    holdout policy `split: test` holds out that split's images.
//   background.json  {"bgr": [b, g, r], "source": "..."}: the colour the photos' transparent pixels
//                    were composited on (import.alpha: composite). Render fills every model's holes
//                    with it (render.background: capture), as the composited photos show it.
// Both sit at the workspace root (undistort and sfm keep image names, so they hold for every model
// folder); import always writes them ({} and {"bgr": null} when the capture has no such thing), so
// that they are its declared outputs. A workspace without them (made by synth) has neither.
#pragma once

#include <map>
#include <optional>
#include <opencv2/core.hpp>
#include <string>

#include "pipeline/core/workspace.h"

namespace ibmr {

inline constexpr const char* kSplitsFile = "splits.json";
inline constexpr const char* kBackgroundFile = "background.json";
// alpha/<image name>.png: the photos' alpha (8 bits, 255 opaque) where they had one; the source of
// silhouettes mode alpha (mask: alpha > 0.5).
inline constexpr const char* kAlphaFolder = "alpha";

// True when the capture brought alpha: alpha/ holds a file (import makes the folder for every
// capture; it fills it where photos had alpha).
bool CaptureHasAlpha(const Workspace& workspace);

using ImageSplits = std::map<std::string, std::string>;  // image name -> split name

// Empty when the workspace has no splits.json; IoError naming the file when it is not a map of
// names to split names.
ImageSplits ReadImageSplits(const Workspace& workspace);
// Writes splits.json (atomically); {} for no splits.
void WriteImageSplits(const Workspace& workspace, const ImageSplits& splits);

struct CaptureBackground {
  cv::Vec3b bgr{255, 255, 255};
  std::string source;  // what set it ("import.background white", ...)
};

// nullopt when the workspace has no background.json; IoError naming the file when it is malformed.
std::optional<CaptureBackground> ReadCaptureBackground(const Workspace& workspace);
// Writes background.json (atomically); {"bgr": null} for nullopt.
void WriteCaptureBackground(const Workspace& workspace, const std::optional<CaptureBackground>& background);

// "white" -> (255, 255, 255), "black" -> (0, 0, 0), "[r, g, b]" or "r,g,b" or "r g b" with
// integers in [0, 255] -> BGR. False with `error` set ("expected white, black or [r, g, b] ...").
bool ParseBackgroundColor(const std::string& text, cv::Vec3b* bgr, std::string* error);

}  // namespace ibmr
