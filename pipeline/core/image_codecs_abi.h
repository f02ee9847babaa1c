// The build facts that image_codecs.cc and its module (image_codecs_module.cc) must share to pass
// std::string, cv::Mat and std::vector to each other: OpenCV's version, the pointer size and the C++
// library's string ABI, as one string each side compiles in.
#pragma once

#include <opencv2/core/version.hpp>

#define IBMR_CODECS_ABI_STR2(x) #x
#define IBMR_CODECS_ABI_STR(x) IBMR_CODECS_ABI_STR2(x)
#define IBMR_CODECS_ABI "opencv " CV_VERSION " pointer " IBMR_CODECS_ABI_STR(__SIZEOF_POINTER__) " cxx11abi " IBMR_CODECS_ABI_STR(_GLIBCXX_USE_CXX11_ABI)
