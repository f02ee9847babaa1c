// The codecs module behind image_codecs.h: OpenCV's imgcodecs functions as C entry points, built
// as libibmr_image_codecs.so and opened with dlopen on the first image read or write (why: see
// image_codecs.h). The only code of the project that links opencv_imgcodecs (tests aside).
#include <opencv2/imgcodecs.hpp>

#include "pipeline/core/image_codecs_abi.h"
#include <string>
#include <vector>

extern "C" {

// What the objects passed across were built with; the loader compares it with its own (a module of
// another build, OpenCV or C++ library would exchange std::string, cv::Mat and std::vector of a
// different layout).
const char* ibmr_codecs_abi() { return IBMR_CODECS_ABI; }

// Each entry point's signature is the one image_codecs.cc looks up; keep them in step.
void ibmr_codecs_imread(const std::string* path, int flags, cv::Mat* out) { *out = cv::imread(*path, flags); }

bool ibmr_codecs_imwrite(const std::string* path, const cv::Mat* image, const std::vector<int>* params) {
  return cv::imwrite(*path, *image, *params);
}

bool ibmr_codecs_imencode(const std::string* extension, const cv::Mat* image, std::vector<uchar>* bytes,
                          const std::vector<int>* params) {
  return cv::imencode(*extension, *image, *bytes, *params);
}

void ibmr_codecs_imdecode(const std::vector<uchar>* bytes, int flags, cv::Mat* out) { *out = cv::imdecode(*bytes, flags); }

}  // extern "C"
