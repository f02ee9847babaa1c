// OpenCV's image codecs (cv::imread, cv::imwrite, cv::imencode, cv::imdecode), loaded the first
// time an image is read or written instead of when the program starts.
//
// Why: Debian's libopencv_imgcodecs brings GDAL and its chain, 140 shared libraries with 67k
// symbol relocations and static initialisers (GDCM's DICOM dictionaries among them). Linked into
// ibmr, the dynamic loader spent about two thirds of every start on them, before `ibmr --help`,
// `ibmr status` or a Snakemake rule did anything. They live in a module of their own
// (libibmr_image_codecs.so, image_codecs_module.cc) that the first call here opens with dlopen;
// what never touches an image never loads them. Nothing of ibmr itself links imgcodecs (tests,
// benchmarks and their OpenCV peers do).
//
// Each function behaves as the OpenCV function it names (same flags and parameters; a
// cv::Exception from the codec passes through). The module is found at the path the build wrote
// into this library, else beside the running executable; IBMR_IMAGE_CODECS (a path) overrides
// both. Failing to load it throws IoError saying what to build.
#pragma once

#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace ibmr {

cv::Mat DecodeImageFile(const std::string& path, int flags);  // cv::imread
bool EncodeImageFile(const std::string& path, const cv::Mat& image, const std::vector<int>& params = {});  // cv::imwrite
bool EncodeImage(const std::string& extension, const cv::Mat& image, std::vector<uchar>* bytes,
                 const std::vector<int>& params = {});  // cv::imencode
cv::Mat DecodeImage(const std::vector<uchar>& bytes, int flags);  // cv::imdecode

}  // namespace ibmr
