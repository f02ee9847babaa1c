// Image files through OpenCV, with errors that name the file and atomic writes. Images are
// cv::Mat in OpenCV's BGR order; 8-bit unless stated. PFM holds float disparity/depth maps.
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace ibmr {

// Reads a colour image as CV_8UC3 (grey files are expanded). Throws IoError naming the file.
cv::Mat ReadImageColor(const std::string& path);
// Reads an image keeping its depth and channel count (e.g. 16-bit PNG). Throws IoError.
cv::Mat ReadImageUnchanged(const std::string& path);
// Writes any image OpenCV can encode for the extension, atomically. Throws IoError. A .png is
// encoded by EncodePngBytes.
void WriteImage(const std::string& path, const cv::Mat& image);
// `image` as the bytes of a PNG file: png_encoder.h's encoder for the types it writes (8/16-bit
// grey, BGR, BGRA), OpenCV's for the others. Throws IoError with the reason (the caller names
// the file).
std::string EncodePngBytes(const cv::Mat& image);
// Portable float map (PFM, 1 channel, bottom-to-top rows as the format requires).
cv::Mat ReadPfm(const std::string& path);  // CV_32FC1, top row first
void WritePfm(const std::string& path, const cv::Mat& image);  // CV_32FC1, atomic

}  // namespace ibmr
