// PNG files decoded with libpng directly, to the same pixels OpenCV's imread gives: the same
// libpng transforms in the same order as OpenCV's PNG decoder (imgcodecs' grfmt_png.cpp, single
// images), for the two ways ibmr reads images (image_io.h: colour, and unchanged). Why not through
// OpenCV: its image codecs are a module of their own (image_codecs.h) whose libraries (GDAL and
// about 140 more) take ~47 ms to load, which a process that only reads PNGs (`ibmr stereo-pair`,
// issue 58) now skips. Anything this decoder does not read (a file libpng refuses, a size imread
// would refuse) is left to OpenCV, which then decodes it or names the error as before.
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace ibmr {

enum class PngReadMode {
  kColor,      // cv::IMREAD_COLOR (orientation ignored): 8-bit BGR whatever the file holds
  kUnchanged,  // cv::IMREAD_UNCHANGED: the file's channels (grey, BGR, BGRA) and depth (8 or 16 bit)
};

// True when `bytes` start with the PNG signature.
bool LooksLikePng(const std::string& bytes);

// Decodes the PNG in `bytes` into `image` as imread would with the mode's flags. False, with
// `image` left empty, for anything libpng reports as an error or imread would refuse by size
// (sides above 2^20 or more than 2^30 pixels): the caller then asks OpenCV.
bool DecodePng(const std::string& bytes, PngReadMode mode, cv::Mat* image);

}  // namespace ibmr
