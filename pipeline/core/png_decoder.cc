// PNG decoding with libpng, as OpenCV's imread does it (see png_decoder.h).
#include "pipeline/core/png_decoder.h"

#include <png.h>

#include <csetjmp>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <vector>

namespace ibmr {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "16-bit samples are swapped to the host order as on x86");

constexpr unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

// Where libpng reads from: the file's bytes in memory.
struct Source {
  const std::string* bytes;
  size_t position;
};

void ReadFromSource(png_structp png, png_bytep out, png_size_t length) {
  Source* source = static_cast<Source*>(png_get_io_ptr(png));
  if (length > source->bytes->size() - source->position) png_error(png, "truncated");
  std::memcpy(out, source->bytes->data() + source->position, length);
  source->position += length;
}

// libpng's messages are not printed: a file it refuses goes to OpenCV, which reports it.
void OnError(png_structp png, png_const_charp) { png_longjmp(png, 1); }
void OnWarning(png_structp, png_const_charp) {}

// Owns libpng's read and info structures.
struct PngReader {
  png_structp png = nullptr;
  png_infop info = nullptr;
  png_infop end = nullptr;
  PngReader() {
    png = png_create_read_struct(PNG_LIBPNG_VER_STRING, nullptr, OnError, OnWarning);
    if (png) {
      info = png_create_info_struct(png);
      end = png_create_info_struct(png);
    }
  }
  ~PngReader() {
    if (png) png_destroy_read_struct(&png, info ? &info : nullptr, end ? &end : nullptr);
  }
  bool Ready() const { return png && info && end; }
};

// One of OpenCV's image size limits: the environment's value when it sets one, else the default.
uint64_t LimitFromEnvironment(const char* name, uint64_t fallback) {
  const char* value = std::getenv(name);
  if (value == nullptr || *value == '\0') return fallback;
  char* end = nullptr;
  const unsigned long long parsed = std::strtoull(value, &end, 10);
  return end != nullptr && *end == '\0' ? parsed : fallback;
}

// The Mat type imread allocates for a PNG header in `mode` (OpenCV's PngDecoder::readHeader, then
// imread's flag rules: IMREAD_COLOR forces 8-bit, 3 channels).
int MatType(png_structp png, png_infop info, int bit_depth, int color_type, PngReadMode mode) {
  int channels = 1;
  if (color_type == PNG_COLOR_TYPE_RGB || color_type == PNG_COLOR_TYPE_PALETTE) {
    png_bytep trans = nullptr;
    int num_trans = 0;
    png_color_16p trans_values = nullptr;
    png_get_tRNS(png, info, &trans, &num_trans, &trans_values);
    channels = num_trans > 0 ? 4 : 3;
  } else if (color_type == PNG_COLOR_TYPE_GRAY_ALPHA || color_type == PNG_COLOR_TYPE_RGB_ALPHA) {
    channels = 4;
  }
  if (mode == PngReadMode::kColor) return CV_8UC3;
  return CV_MAKETYPE(bit_depth == 16 ? CV_16U : CV_8U, channels);
}

// Everything between setjmp and a longjmp lives in `reader` and `image` (owned by the caller), so
// that no destructor is skipped; returns false on a libpng error.
bool DecodeInto(PngReader& reader, Source* source, PngReadMode mode, cv::Mat* image, std::vector<png_bytep>* rows) {
  png_structp png = reader.png;
  png_infop info = reader.info;
  if (setjmp(png_jmpbuf(png))) return false;
  png_set_read_fn(png, source, ReadFromSource);
  png_read_info(png, info);
  png_uint_32 width = 0, height = 0;
  int bit_depth = 0, color_type = 0;
  png_get_IHDR(png, info, &width, &height, &bit_depth, &color_type, nullptr, nullptr, nullptr);
  // imread's limits (validateInputImageSize, with its environment overrides): larger images are
  // OpenCV's to refuse.
  if (width == 0 || height == 0 || width > LimitFromEnvironment("OPENCV_IO_MAX_IMAGE_WIDTH", uint64_t{1} << 20) ||
      height > LimitFromEnvironment("OPENCV_IO_MAX_IMAGE_HEIGHT", uint64_t{1} << 20) ||
      static_cast<uint64_t>(width) * height > LimitFromEnvironment("OPENCV_IO_MAX_IMAGE_PIXELS", uint64_t{1} << 30)) {
    return false;
  }
  image->create(static_cast<int>(height), static_cast<int>(width), MatType(png, info, bit_depth, color_type, mode));
  // OpenCV's transforms, in its order (PngDecoder::readData).
  const bool color = image->channels() > 1;
  if (image->depth() == CV_8U && bit_depth == 16) {
    png_set_strip_16(png);
  } else {
    png_set_swap(png);  // little-endian host (asserted above)
  }
  if (image->channels() < 4) {
    png_set_strip_alpha(png);
  } else {
    png_set_tRNS_to_alpha(png);
  }
  if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
  if ((color_type & PNG_COLOR_MASK_COLOR) == 0 && bit_depth < 8) png_set_expand_gray_1_2_4_to_8(png);
  if ((color_type & PNG_COLOR_MASK_COLOR) && color) {
    png_set_bgr(png);
  } else if (color) {
    png_set_gray_to_rgb(png);
  } else {
    png_set_rgb_to_gray(png, 1, 0.299, 0.587);
  }
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  // The transformed rows must be what the Mat holds (a combination OpenCV would misread is left to it).
  if (png_get_rowbytes(png, info) != image->cols * image->elemSize()) return false;
  rows->resize(height);
  for (png_uint_32 y = 0; y < height; ++y) (*rows)[y] = image->ptr<png_byte>(static_cast<int>(y));
  png_read_image(png, rows->data());
  png_read_end(png, reader.end);
  return true;
}

}  // namespace

bool LooksLikePng(const std::string& bytes) {
  return bytes.size() >= sizeof(kSignature) && std::memcmp(bytes.data(), kSignature, sizeof(kSignature)) == 0;
}

bool DecodePng(const std::string& bytes, PngReadMode mode, cv::Mat* image) {
  image->release();
  if (!LooksLikePng(bytes)) return false;
  PngReader reader;
  if (!reader.Ready()) return false;
  Source source{&bytes, 0};
  std::vector<png_bytep> rows;
  cv::Mat decoded;
  try {
    if (!DecodeInto(reader, &source, mode, &decoded, &rows)) return false;
  } catch (const std::exception&) {  // the image's allocation: OpenCV reports it in its words
    return false;
  }
  *image = decoded;
  return true;
}

}  // namespace ibmr
