// Image reading and writing through OpenCV with errors that name the file, atomic writes via a
// temporary that keeps the extension (so OpenCV picks the codec), and the PFM float format
// (header "Pf\nW H\nSCALE\n", negative scale = little-endian, rows stored bottom to top). PNGs
// are read with libpng (png_decoder.h) and written with libdeflate (png_encoder.h) where they can be.
#include "pipeline/core/image_io.h"

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <cctype>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/image_codecs.h"
#include "pipeline/core/png_decoder.h"
#include "pipeline/core/png_encoder.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "PFM I/O assumes a little-endian host");

// What a JPEG (its first frame header) or PNG (IHDR) header declares, from the file's first bytes,
// with the most pixels a byte of such a file can hold: Huffman-coded JPEG about 512 (a flat
// progressive image), arithmetic-coded JPEG and PNG far more (PNG: about 8,300 for 1-bit grey at
// deflate's best); the limits below leave a margin. All zero for other formats or a short header.
struct DeclaredSize {
  uint64_t width = 0, height = 0, max_pixels_per_byte = 0;
};

DeclaredSize ReadDeclaredSize(const std::string& head) {
  const auto byte = [&head](size_t i) { return static_cast<uint64_t>(static_cast<unsigned char>(head[i])); };
  const auto be16 = [&byte](size_t i) { return byte(i) << 8 | byte(i + 1); };
  const auto be32 = [&be16](size_t i) { return be16(i) << 16 | be16(i + 2); };
  if (head.size() >= 24 && head.compare(0, 8, "\x89PNG\r\n\x1a\n") == 0 && head.compare(12, 4, "IHDR") == 0) {
    return {be32(16), be32(20), 16384};
  }
  if (head.size() < 4 || byte(0) != 0xff || byte(1) != 0xd8) return {};
  size_t pos = 2;
  while (pos + 4 <= head.size() && byte(pos) == 0xff) {
    const uint64_t marker = byte(pos + 1);
    if (marker == 0xff) {  // fill byte
      ++pos;
      continue;
    }
    if (marker == 0x01 || (marker >= 0xd0 && marker <= 0xd8)) {  // no length
      pos += 2;
      continue;
    }
    if (marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc) {  // SOFn
      if (pos + 9 > head.size()) return {};
      return {be16(pos + 7), be16(pos + 5), marker >= 0xc9 ? 16384u : 1024u};
    }
    if (marker == 0xda || marker == 0xd9) break;  // scan data or the end before any frame header
    pos += 2 + be16(pos + 2);
  }
  return {};
}

// Reads with OpenCV, telling a missing file apart from one OpenCV cannot decode.
cv::Mat ReadWithFlags(const std::string& path, int flags) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw IoError("cannot read image " + path + ": " +
                  (std::filesystem::exists(path, ec) ? "not a regular file" : "no such file"));
  }
  // A few hundred bytes of JPEG or PNG can declare a billion pixels, which OpenCV allocates before
  // it finds the data missing (found by fuzzing): a claim no file of that size can hold means a
  // truncated or forged file, refused unread.
  // PNGs decode with libpng here, to imread's pixels, without loading OpenCV's codecs
  // (png_decoder.h), in the two modes ibmr reads; what it does not read goes on to OpenCV.
  const bool png_mode = flags == cv::IMREAD_UNCHANGED || flags == (cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
  bool png = false;
  std::string bytes(65536, '\0');  // the head, and the whole file for a PNG read here
  {
    std::ifstream in(path, std::ios::binary);
    in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    bytes.resize(static_cast<size_t>(in.gcount()));
    const DeclaredSize declared = ReadDeclaredSize(bytes);
    const uint64_t file_size = std::filesystem::file_size(path, ec);
    if (!ec && declared.width * declared.height > declared.max_pixels_per_byte * file_size) {
      throw IoError("cannot decode image " + path + ": its header declares " + std::to_string(declared.width) + " x " +
                    std::to_string(declared.height) + " pixels, more than its " + std::to_string(file_size) +
                    " bytes can hold (truncated or corrupt)");
    }
    png = png_mode && LooksLikePng(bytes);
    if (png && !ec && file_size > bytes.size()) {  // the rest of the file, from where the head ended
      const size_t head = bytes.size();
      bytes.resize(file_size);
      in.read(bytes.data() + head, static_cast<std::streamsize>(file_size - head));
      bytes.resize(head + static_cast<size_t>(in.gcount()));  // shorter if it shrank meanwhile: libpng refuses it
    }
  }
  cv::Mat image;
  if (png && DecodePng(bytes, flags == cv::IMREAD_UNCHANGED ? PngReadMode::kUnchanged : PngReadMode::kColor, &image)) {
    return image;
  }
  try {
    image = DecodeImageFile(path, flags);
  } catch (const cv::Exception& e) {
    throw IoError("cannot decode image " + path + ": " + e.what());
  }
  if (image.empty()) {
    throw IoError("cannot decode image " + path + ": the file exists but OpenCV cannot decode it "
                  "(corrupt or unsupported format)");
  }
  return image;
}

// True for a path ending in ".png" in any case ("x.PNG" too, as imwrite chooses its codec).
bool HasPngExtension(const std::string& path) {
  std::string extension = std::filesystem::path(path).extension().string();
  for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return extension == ".png";
}

// Reads the next whitespace-separated token of a PFM header; PFM allows any whitespace.
std::string NextToken(const std::string& bytes, size_t* pos) {
  while (*pos < bytes.size() && std::isspace(static_cast<unsigned char>(bytes[*pos]))) ++*pos;
  const size_t start = *pos;
  while (*pos < bytes.size() && !std::isspace(static_cast<unsigned char>(bytes[*pos]))) ++*pos;
  return bytes.substr(start, *pos - start);
}

uint32_t SwapBytes(uint32_t v) {
  return (v >> 24) | ((v >> 8) & 0xff00u) | ((v << 8) & 0xff0000u) | (v << 24);
}

}  // namespace

cv::Mat ReadImageColor(const std::string& path) {
  // EXIF orientation is ignored, as COLMAP does, so that image sizes match cameras.txt.
  return ReadWithFlags(path, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION);
}

cv::Mat ReadImageUnchanged(const std::string& path) { return ReadWithFlags(path, cv::IMREAD_UNCHANGED); }

std::string EncodePngBytes(const cv::Mat& image) {
  // The types the pipeline writes are encoded with libdeflate (png_encoder.h: the pixels imwrite
  // writes, in 0.6-0.8 of its time), without loading OpenCV's codecs; OpenCV encodes the others.
  std::string png;
  if (EncodePng(image, &png)) return png;
  std::vector<uchar> encoded;
  bool ok = false;
  std::string reason = "OpenCV could not encode it as PNG";
  try {
    ok = EncodeImage(".png", image, &encoded);
  } catch (const cv::Exception& e) {
    reason = e.what();
  }
  if (!ok) throw IoError(reason);
  return std::string(encoded.begin(), encoded.end());
}

void WriteImage(const std::string& path, const cv::Mat& image) {
  if (image.empty()) throw IoError("cannot write image " + path + ": the image is empty");
  if (HasPngExtension(path)) {
    std::string png;
    try {
      png = EncodePngBytes(image);
    } catch (const IoError& e) {
      throw IoError("cannot write image " + path + ": " + e.what());
    }
    WriteFileAtomic(path, png);
    return;
  }
  WriteViaTemporary(path, [&](const std::string& tmp_path) {
    bool ok = false;
    std::string reason = "OpenCV could not encode it for this extension";
    try {
      ok = EncodeImageFile(tmp_path, image);
    } catch (const cv::Exception& e) {
      reason = e.what();
    }
    if (!ok) throw IoError("cannot write image " + path + ": " + reason);
  });
}

cv::Mat ReadPfm(const std::string& path) {
  const std::string bytes = ReadFile(path);
  size_t pos = 0;
  const std::string magic = NextToken(bytes, &pos);
  if (magic == "PF") throw IoError(path + ": 3-channel PFM (\"PF\") is not supported; expected \"Pf\"");
  if (magic != "Pf") throw IoError(path + ": not a PFM file (expected \"Pf\" at the start)");
  int width = 0, height = 0;
  double scale = 0;
  try {
    width = std::stoi(NextToken(bytes, &pos));
    height = std::stoi(NextToken(bytes, &pos));
    scale = std::stod(NextToken(bytes, &pos));
  } catch (const std::exception&) {
    throw IoError(path + ": bad PFM header (expected \"Pf\", width, height and scale)");
  }
  if (width <= 0 || height <= 0 || scale == 0) throw IoError(path + ": bad PFM header (size or scale)");
  ++pos;  // exactly one whitespace character separates the header from the data
  const size_t expected = static_cast<size_t>(width) * height * sizeof(float);
  if (pos > bytes.size() || bytes.size() - pos < expected) {
    throw IoError(path + ": PFM data is truncated: need " + std::to_string(expected) + " bytes for " +
                  std::to_string(width) + "x" + std::to_string(height));
  }
  cv::Mat image(height, width, CV_32FC1);
  const bool big_endian = scale > 0;
  for (int r = 0; r < height; ++r) {
    // The file's first row is the image's bottom row.
    float* row = image.ptr<float>(height - 1 - r);
    std::memcpy(row, bytes.data() + pos + static_cast<size_t>(r) * width * sizeof(float), width * sizeof(float));
    if (big_endian) {
      for (int c = 0; c < width; ++c) {
        uint32_t v;
        std::memcpy(&v, &row[c], 4);
        v = SwapBytes(v);
        std::memcpy(&row[c], &v, 4);
      }
    }
  }
  return image;
}

void WritePfm(const std::string& path, const cv::Mat& image) {
  if (image.empty() || image.type() != CV_32FC1) {
    throw IoError("cannot write " + path + ": PFM needs a non-empty CV_32FC1 image");
  }
  std::string bytes = "Pf\n" + std::to_string(image.cols) + " " + std::to_string(image.rows) + "\n-1\n";
  const size_t header = bytes.size();
  const size_t row_bytes = static_cast<size_t>(image.cols) * sizeof(float);
  bytes.resize(header + row_bytes * image.rows);
  for (int r = 0; r < image.rows; ++r) {
    std::memcpy(&bytes[header + r * row_bytes], image.ptr<float>(image.rows - 1 - r), row_bytes);
  }
  WriteFileAtomic(path, bytes);
}

}  // namespace ibmr
