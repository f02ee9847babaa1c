// How the report page embeds binary data: base64 text, and images as data URIs (JPEG for photos
// and texture pages, PNG where the alpha channel matters), scaled down to a size limit.
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace ibmr {

// Base64 (RFC 4648, with '=' padding) of `size` bytes.
std::string Base64(const void* data, size_t size);

// `image` scaled down (area interpolation, aspect kept) so that it is at most `max_width` wide
// and `max_height` high; returned as it is when it fits.
cv::Mat ShrinkToFit(const cv::Mat& image, int max_width, int max_height);

// "data:image/jpeg;base64,..." of an 8-bit BGR (or grey) image at `quality` in [1, 100].
std::string JpegDataUri(const cv::Mat& image, int quality);
// "data:image/png;base64,..." of an 8-bit BGR, BGRA or grey image.
std::string PngDataUri(const cv::Mat& image);

}  // namespace ibmr
