// Base64 and image data URIs for the report page (see report_encoding.h).
#include "pipeline/runner/report_encoding.h"

#include <opencv2/imgcodecs.hpp>  // the flags; the codecs through image_codecs.h
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <vector>

#include "pipeline/core/image_codecs.h"

namespace ibmr {

std::string Base64(const void* data, size_t size) {
  static const char* const kAlphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const auto* bytes = static_cast<const unsigned char*>(data);
  std::string out;
  out.reserve((size + 2) / 3 * 4);
  for (size_t i = 0; i < size; i += 3) {
    const uint32_t chunk = (static_cast<uint32_t>(bytes[i]) << 16) |
                           (i + 1 < size ? static_cast<uint32_t>(bytes[i + 1]) << 8 : 0u) |
                           (i + 2 < size ? static_cast<uint32_t>(bytes[i + 2]) : 0u);
    out += kAlphabet[(chunk >> 18) & 63];
    out += kAlphabet[(chunk >> 12) & 63];
    out += i + 1 < size ? kAlphabet[(chunk >> 6) & 63] : '=';
    out += i + 2 < size ? kAlphabet[chunk & 63] : '=';
  }
  return out;
}

cv::Mat ShrinkToFit(const cv::Mat& image, int max_width, int max_height) {
  if (image.cols <= max_width && image.rows <= max_height) return image;
  const double scale = std::min(static_cast<double>(max_width) / image.cols, static_cast<double>(max_height) / image.rows);
  cv::Mat out;
  cv::resize(image, out, cv::Size(std::max(1, static_cast<int>(image.cols * scale)), std::max(1, static_cast<int>(image.rows * scale))),
             0, 0, cv::INTER_AREA);
  return out;
}

std::string JpegDataUri(const cv::Mat& image, int quality) {
  std::vector<uchar> bytes;
  EncodeImage(".jpg", image, &bytes, {cv::IMWRITE_JPEG_QUALITY, quality});
  return "data:image/jpeg;base64," + Base64(bytes.data(), bytes.size());
}

std::string PngDataUri(const cv::Mat& image) {
  std::vector<uchar> bytes;
  EncodeImage(".png", image, &bytes);
  return "data:image/png;base64," + Base64(bytes.data(), bytes.size());
}

}  // namespace ibmr
