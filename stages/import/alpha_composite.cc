// Alpha compositing of imported photos (see alpha_composite.h).
#include "stages/import/alpha_composite.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace ibmr {

namespace {

template <typename T>
void Composite(const cv::Mat& image, const cv::Vec3b& background, bool premultiplied, AlphaComposite* out) {
  const int channels = image.channels();
  const double scale = sizeof(T) == 1 ? 1.0 : 1.0 / 257.0;  // samples to [0, 255]
  const double full = sizeof(T) == 1 ? 255.0 : 65535.0;
  for (int y = 0; y < image.rows; ++y) {
    const T* in = image.ptr<T>(y);
    cv::Vec3b* bgr = out->bgr.ptr<cv::Vec3b>(y);
    uint8_t* alpha = out->alpha.ptr<uint8_t>(y);
    for (int x = 0; x < image.cols; ++x, in += channels) {
      const T a_raw = in[channels - 1];
      const double a = a_raw / full;
      alpha[x] = static_cast<uint8_t>(std::lround(a_raw * scale));
      for (int c = 0; c < 3; ++c) {
        const double colour = (channels == 4 ? in[c] : in[0]) * scale;
        const double value = (premultiplied ? colour : colour * a) + background[c] * (1.0 - a);
        bgr[x][c] = static_cast<uint8_t>(std::clamp(std::lround(value), 0L, 255L));
      }
    }
  }
}

}  // namespace

AlphaComposite CompositeOverBackground(const cv::Mat& image, const cv::Vec3b& background_bgr, bool premultiplied) {
  if (!HasAlpha(image) || (image.depth() != CV_8U && image.depth() != CV_16U)) {
    throw std::invalid_argument("expected an 8- or 16-bit image with an alpha channel (grey+alpha or BGRA), got " +
                                std::to_string(image.channels()) + " channels of " +
                                std::to_string(8 * static_cast<int>(image.elemSize1())) + " bits");
  }
  AlphaComposite out;
  out.bgr.create(image.size(), CV_8UC3);
  out.alpha.create(image.size(), CV_8UC1);
  if (image.depth() == CV_8U) {
    Composite<uint8_t>(image, background_bgr, premultiplied, &out);
  } else {
    Composite<uint16_t>(image, background_bgr, premultiplied, &out);
  }
  return out;
}

}  // namespace ibmr
