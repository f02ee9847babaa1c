// Image reading and writing through OpenCV with errors that name the file, atomic writes via a
// temporary that keeps the extension (so OpenCV picks the codec), and the PFM float format
// (header "Pf\nW H\nSCALE\n", negative scale = little-endian, rows stored bottom to top).
#include "pipeline/core/image_io.h"

#include <cstring>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <cctype>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "PFM I/O assumes a little-endian host");

// Reads with OpenCV, telling a missing file apart from one OpenCV cannot decode.
cv::Mat ReadWithFlags(const std::string& path, int flags) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) {
    throw IoError("cannot read image " + path + ": " +
                  (std::filesystem::exists(path, ec) ? "not a regular file" : "no such file"));
  }
  cv::Mat image;
  try {
    image = cv::imread(path, flags);
  } catch (const cv::Exception& e) {
    throw IoError("cannot decode image " + path + ": " + e.what());
  }
  if (image.empty()) {
    throw IoError("cannot decode image " + path + ": the file exists but OpenCV cannot decode it "
                  "(corrupt or unsupported format)");
  }
  return image;
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

void WriteImage(const std::string& path, const cv::Mat& image) {
  if (image.empty()) throw IoError("cannot write image " + path + ": the image is empty");
  WriteViaTemporary(path, [&](const std::string& tmp_path) {
    bool ok = false;
    std::string reason = "OpenCV could not encode it for this extension";
    try {
      ok = cv::imwrite(tmp_path, image);
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
