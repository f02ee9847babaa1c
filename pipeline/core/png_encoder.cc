// PNG encoding with libdeflate, the bytes laid out by hand (see png_encoder.h). A PNG file is the
// 8-byte signature and chunks, each: data length (4 bytes, big-endian), type (4 ASCII letters),
// data, CRC-32 of type and data. IHDR's 13 bytes: width, height (4 each), bit depth, colour type,
// compression (0), filter method (0), interlace (0). IDAT chunks hold, concatenated, one zlib stream
// of the filtered rows: per row a filter-type byte, then the row's bytes.
#include "pipeline/core/png_encoder.h"

#include <libdeflate.h>

#include <algorithm>
#include <cstdint>
#include <memory>
#include <new>
#include <vector>

namespace ibmr {
namespace {

constexpr char kSignature[8] = {'\x89', 'P', 'N', 'G', '\r', '\n', '\x1a', '\n'};
// The zlib stream is cut into IDAT chunks of at most this many bytes: far below the format's
// 2^31 - 1, and a streaming reader gets data before the whole file is in.
constexpr size_t kIdatBytes = size_t{1} << 20;
constexpr unsigned char kSubFilter = 1;

void AppendBigEndian32(uint32_t value, std::string* out) {
  const char bytes[4] = {static_cast<char>(value >> 24), static_cast<char>(value >> 16), static_cast<char>(value >> 8),
                         static_cast<char>(value)};
  out->append(bytes, 4);
}

void AppendChunk(const char (&type)[5], const void* data, size_t size, std::string* out) {
  AppendBigEndian32(static_cast<uint32_t>(size), out);
  const size_t type_at = out->size();
  out->append(type, 4);
  if (size > 0) out->append(static_cast<const char*>(data), size);
  AppendBigEndian32(libdeflate_crc32(0, out->data() + type_at, 4 + size), out);
}

// One row's samples as the file stores them: B, G, R(, A) reordered to R, G, B(, A), 16-bit
// samples big-endian (the high byte first, whatever the host's order).
template <typename Sample, int kChannels>
void ToFileOrder(const Sample* row, int cols, unsigned char* out) {
  constexpr int kOrder[4] = {kChannels == 1 ? 0 : 2, 1, 0, 3};
  for (int x = 0; x < cols; ++x, row += kChannels) {
    for (int c = 0; c < kChannels; ++c) {
      const Sample sample = row[kOrder[c]];
      if constexpr (sizeof(Sample) == 2) *out++ = static_cast<unsigned char>(sample >> 8);
      *out++ = static_cast<unsigned char>(sample);
    }
  }
}

void RowToFileOrder(const cv::Mat& image, int y, unsigned char* out) {
  switch (image.type()) {
    case CV_8UC1: return ToFileOrder<uint8_t, 1>(image.ptr<uint8_t>(y), image.cols, out);
    case CV_8UC3: return ToFileOrder<uint8_t, 3>(image.ptr<uint8_t>(y), image.cols, out);
    case CV_8UC4: return ToFileOrder<uint8_t, 4>(image.ptr<uint8_t>(y), image.cols, out);
    case CV_16UC1: return ToFileOrder<uint16_t, 1>(image.ptr<uint16_t>(y), image.cols, out);
    case CV_16UC3: return ToFileOrder<uint16_t, 3>(image.ptr<uint16_t>(y), image.cols, out);
    case CV_16UC4: return ToFileOrder<uint16_t, 4>(image.ptr<uint16_t>(y), image.cols, out);
  }
}

// PNG's SUB filter (type 1): each byte minus the byte one pixel (`pixel_bytes`) to its left, the
// first pixel's bytes as they are. What OpenCV's imwrite uses by default: cheap, and it turns smooth
// gradients into runs of small numbers that deflate codes shortly.
void SubFilter(const unsigned char* row, size_t size, size_t pixel_bytes, unsigned char* out) {
  const size_t first = std::min(pixel_bytes, size);
  std::copy(row, row + first, out);
  for (size_t i = first; i < size; ++i) out[i] = static_cast<unsigned char>(row[i] - row[i - pixel_bytes]);
}

// Bytes left uninitialised: every one is written before it is read (a zero-filled vector of an
// atlas page's size costs its page faults twice).
using Bytes = std::unique_ptr<unsigned char[]>;

// The image data before compression: each row, file-ordered and SUB-filtered, after its filter
// byte; `size` set to its length.
Bytes FilteredRows(const cv::Mat& image, size_t* size) {
  const size_t pixel_bytes = image.elemSize();
  const size_t row_bytes = pixel_bytes * image.cols;
  *size = (1 + row_bytes) * image.rows;
  Bytes filtered(new unsigned char[*size]);
  std::vector<unsigned char> row(row_bytes);
  for (int y = 0; y < image.rows; ++y) {
    unsigned char* out = filtered.get() + (1 + row_bytes) * y;
    out[0] = kSubFilter;
    RowToFileOrder(image, y, row.data());
    SubFilter(row.data(), row_bytes, pixel_bytes, out + 1);
  }
  return filtered;
}

}  // namespace

bool CanEncodePng(const cv::Mat& image) {
  const int channels = image.channels();
  return !image.empty() && image.dims == 2 && (image.depth() == CV_8U || image.depth() == CV_16U) &&
         (channels == 1 || channels == 3 || channels == 4);
}

bool EncodePng(const cv::Mat& image, std::string* bytes, int level) {
  bytes->clear();
  if (!CanEncodePng(image)) return false;
  const std::unique_ptr<libdeflate_compressor, decltype(&libdeflate_free_compressor)> compressor(
      libdeflate_alloc_compressor(level), libdeflate_free_compressor);
  if (!compressor) return false;  // out of memory, or a level outside 0-12
  Bytes zlib;
  size_t zlib_size = 0;
  try {
    size_t filtered_size = 0;
    const Bytes filtered = FilteredRows(image, &filtered_size);
    const size_t bound = libdeflate_zlib_compress_bound(compressor.get(), filtered_size);
    zlib.reset(new unsigned char[bound]);
    zlib_size = libdeflate_zlib_compress(compressor.get(), filtered.get(), filtered_size, zlib.get(), bound);
  } catch (const std::bad_alloc&) {  // an image too large for memory: OpenCV reports it in its words
    return false;
  }
  if (zlib_size == 0) return false;  // more than the bound: never, by libdeflate's contract

  const int channels = image.channels();
  const unsigned char color_type = channels == 1 ? 0 : channels == 3 ? 2 : 6;  // grey, RGB, RGBA
  std::string header;
  AppendBigEndian32(static_cast<uint32_t>(image.cols), &header);
  AppendBigEndian32(static_cast<uint32_t>(image.rows), &header);
  header += static_cast<char>(image.depth() == CV_16U ? 16 : 8);
  header += static_cast<char>(color_type);
  header.append(3, '\0');  // deflate compression, adaptive filtering (per-row type), no interlacing

  const size_t chunks = zlib_size / kIdatBytes + 1;
  bytes->reserve(sizeof(kSignature) + (12 + header.size()) + 12 * chunks + zlib_size + 12);
  bytes->append(kSignature, sizeof(kSignature));
  AppendChunk("IHDR", header.data(), header.size(), bytes);
  for (size_t at = 0; at < zlib_size; at += kIdatBytes) {
    AppendChunk("IDAT", zlib.get() + at, std::min(kIdatBytes, zlib_size - at), bytes);
  }
  AppendChunk("IEND", nullptr, 0, bytes);
  return true;
}

}  // namespace ibmr
