// The libdeflate PNG encoder (png_encoder.h): every type it takes, odd sizes and ROIs read back to
// the same pixels through the project's decoder and OpenCV's; the file itself (chunks and their
// CRCs, RGB order, big-endian samples, SUB-filtered rows) checked byte by byte and by libpng, which
// must read it without a warning; WriteImage's routing of .png paths and its errors.
#include "pipeline/core/png_encoder.h"

#include <gtest/gtest.h>
#include <libdeflate.h>
#include <png.h>

#include <opencv2/imgcodecs.hpp>  // the read flags (the codecs are the module's)

#include <cstring>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_codecs.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/png_decoder.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

constexpr int kTypes[] = {CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_16UC3, CV_16UC4};

cv::Mat RandomImage(int rows, int cols, int type, uint64_t seed) {
  cv::Mat image(rows, cols, type);
  cv::RNG random(seed);
  random.fill(image, cv::RNG::UNIFORM, 0, CV_MAT_DEPTH(type) == CV_16U ? 65536 : 256);
  return image;
}

std::string Describe(const cv::Mat& image) {
  return cv::typeToString(image.type()) + " " + std::to_string(image.cols) + "x" + std::to_string(image.rows);
}

void ExpectSamePixels(const cv::Mat& got, const cv::Mat& expected, const std::string& what) {
  ASSERT_EQ(got.type(), expected.type()) << what;
  ASSERT_EQ(got.size(), expected.size()) << what;
  cv::Mat difference;
  cv::absdiff(got.reshape(1), expected.reshape(1), difference);
  EXPECT_EQ(cv::countNonZero(difference), 0) << what;
}

// Encodes `image`, then decodes it with the project's decoder and with OpenCV: both the same pixels.
void ExpectRoundTrip(const cv::Mat& image, const std::string& what) {
  std::string bytes;
  ASSERT_TRUE(EncodePng(image, &bytes)) << what;
  cv::Mat ours;
  ASSERT_TRUE(DecodePng(bytes, PngReadMode::kUnchanged, &ours)) << what;
  ExpectSamePixels(ours, image, what + " (png_decoder)");
  ExpectSamePixels(DecodeImage(std::vector<uchar>(bytes.begin(), bytes.end()), cv::IMREAD_UNCHANGED), image,
                   what + " (imdecode)");
}

struct Chunk {
  std::string type;
  std::string data;
};

// The file's chunks after the signature; a failure for a bad length or CRC.
std::vector<Chunk> Chunks(const std::string& bytes) {
  std::vector<Chunk> chunks;
  EXPECT_EQ(bytes.compare(0, 8, "\x89PNG\r\n\x1a\n"), 0);
  const auto be32 = [&bytes](size_t at) {
    uint32_t value = 0;
    for (size_t i = 0; i < 4; ++i) value = value << 8 | static_cast<unsigned char>(bytes[at + i]);
    return value;
  };
  size_t at = 8;
  while (at + 12 <= bytes.size()) {
    const uint32_t size = be32(at);
    if (at + 12 + size > bytes.size()) break;
    EXPECT_EQ(libdeflate_crc32(0, bytes.data() + at + 4, 4 + size), be32(at + 8 + size))
        << "CRC of chunk " << chunks.size();
    chunks.push_back({bytes.substr(at + 4, 4), bytes.substr(at + 8, size)});
    at += 12 + size;
  }
  EXPECT_EQ(at, bytes.size()) << "bytes after the last whole chunk";
  return chunks;
}

// The filtered rows the IDAT chunks hold (their data concatenated and inflated).
std::string InflatedRows(const std::vector<Chunk>& chunks, size_t expected_size) {
  std::string zlib;
  for (const Chunk& chunk : chunks) {
    if (chunk.type == "IDAT") zlib += chunk.data;
  }
  std::string rows(expected_size, '\0');
  libdeflate_decompressor* decompressor = libdeflate_alloc_decompressor();
  const libdeflate_result result =
      libdeflate_zlib_decompress(decompressor, zlib.data(), zlib.size(), rows.data(), rows.size(), nullptr);
  libdeflate_free_decompressor(decompressor);
  EXPECT_EQ(result, LIBDEFLATE_SUCCESS) << "the zlib stream does not inflate to exactly " << expected_size << " bytes";
  return rows;
}

TEST(EncodePng, EveryTypeAndOddSizesReadBack) {
  uint64_t seed = 1;
  for (const int type : kTypes) {
    for (const auto& [rows, cols] : {std::pair<int, int>{1, 1}, {1, 9}, {9, 1}, {77, 333}, {480, 640}}) {
      const cv::Mat image = RandomImage(rows, cols, type, seed++);
      ExpectRoundTrip(image, Describe(image));
    }
  }
}

// A smooth image (what renders are, mostly) compresses and reads back too.
TEST(EncodePng, SmoothImagesReadBack) {
  cv::Mat gradients(120, 160, CV_32FC4);
  for (int y = 0; y < gradients.rows; ++y) {
    for (int x = 0; x < gradients.cols; ++x) gradients.at<cv::Vec4f>(y, x) = cv::Vec4f(x, y, (x + y) / 2, 255 - x);
  }
  std::vector<cv::Mat> planes;
  cv::split(gradients, planes);
  for (const int type : kTypes) {
    cv::Mat image;
    cv::merge(std::vector<cv::Mat>(planes.begin(), planes.begin() + CV_MAT_CN(type)), image);
    image.convertTo(image, type, CV_MAT_DEPTH(type) == CV_16U ? 257.0 : 1.0);
    ExpectRoundTrip(image, "smooth " + Describe(image));
  }
}

// ROIs are not continuous: each row is read at its own address.
TEST(EncodePng, RoisReadBack) {
  uint64_t seed = 100;
  for (const int type : kTypes) {
    const cv::Mat whole = RandomImage(50, 60, type, seed++);
    for (const cv::Rect rect : {cv::Rect(3, 5, 17, 11), cv::Rect(59, 0, 1, 50), cv::Rect(0, 49, 60, 1), cv::Rect(7, 7, 1, 1)}) {
      const cv::Mat roi = whole(rect);
      if (rect.height > 1) ASSERT_FALSE(roi.isContinuous());
      ExpectRoundTrip(roi, "ROI " + Describe(roi) + " of " + Describe(whole));
    }
  }
}

// The bytes themselves: signature, IHDR, IDAT, IEND with valid CRCs; the header's fields; each row
// a SUB filter byte and the differences of samples in RGB(A) order, 16-bit ones big-endian.
TEST(EncodePng, FileLayoutChannelOrderAndFilter) {
  cv::Mat bgr(2, 2, CV_8UC3);
  bgr.at<cv::Vec3b>(0, 0) = {10, 20, 30};
  bgr.at<cv::Vec3b>(0, 1) = {11, 25, 27};
  bgr.at<cv::Vec3b>(1, 0) = {200, 100, 50};
  bgr.at<cv::Vec3b>(1, 1) = {0, 100, 255};
  std::string bytes;
  ASSERT_TRUE(EncodePng(bgr, &bytes));
  std::vector<Chunk> chunks = Chunks(bytes);
  ASSERT_EQ(chunks.size(), 3u);
  EXPECT_EQ(chunks[0].type, "IHDR");
  EXPECT_EQ(chunks[0].data, std::string("\0\0\0\x02\0\0\0\x02\x08\x02\0\0\0", 13));  // 2x2, 8-bit RGB
  EXPECT_EQ(chunks[1].type, "IDAT");
  EXPECT_EQ(chunks[2].type, "IEND");
  EXPECT_TRUE(chunks[2].data.empty());
  // Row 0: R G B of (30, 20, 10) then (27 - 30, 25 - 20, 11 - 10) modulo 256.
  const unsigned char expected[] = {1, 30, 20, 10, 253, 5, 1, 1, 50, 100, 200, 205, 0, 56};
  EXPECT_EQ(InflatedRows(chunks, sizeof(expected)), std::string(reinterpret_cast<const char*>(expected), sizeof(expected)));

  cv::Mat bgra16(1, 2, CV_16UC4);
  bgra16.at<cv::Vec4w>(0, 0) = {0x0102, 0x0304, 0x0506, 0x0708};
  bgra16.at<cv::Vec4w>(0, 1) = {0x0102, 0x0305, 0x0506, 0x0709};
  ASSERT_TRUE(EncodePng(bgra16, &bytes));
  chunks = Chunks(bytes);
  ASSERT_EQ(chunks.size(), 3u);
  EXPECT_EQ(chunks[0].data, std::string("\0\0\0\x02\0\0\0\x01\x10\x06\0\0\0", 13));  // 2x1, 16-bit RGBA
  const unsigned char expected16[] = {1, 5, 6, 3, 4, 1, 2, 7, 8, 0, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_EQ(InflatedRows(chunks, sizeof(expected16)),
            std::string(reinterpret_cast<const char*>(expected16), sizeof(expected16)));

  cv::Mat grey(3, 1, CV_8UC1, cv::Scalar(9));
  ASSERT_TRUE(EncodePng(grey, &bytes));
  chunks = Chunks(bytes);
  ASSERT_EQ(chunks.size(), 3u);
  EXPECT_EQ(chunks[0].data, std::string("\0\0\0\x01\0\0\0\x03\x08\x00\0\0\0", 13));  // 1x3, 8-bit grey
  EXPECT_EQ(InflatedRows(chunks, 6), std::string("\x01\x09\x01\x09\x01\x09", 6));
}

// A zlib stream longer than one IDAT chunk holds is split over several, in order.
TEST(EncodePng, LargeImagesSpanSeveralIdatChunks) {
  const cv::Mat image = RandomImage(700, 700, CV_8UC4, 7);  // ~1.9 MB of noise: deflate cannot shrink it
  std::string bytes;
  ASSERT_TRUE(EncodePng(image, &bytes));
  const std::vector<Chunk> chunks = Chunks(bytes);
  ASSERT_GE(chunks.size(), 4u);
  EXPECT_EQ(chunks.front().type, "IHDR");
  EXPECT_EQ(chunks.back().type, "IEND");
  for (size_t i = 1; i + 1 < chunks.size(); ++i) EXPECT_EQ(chunks[i].type, "IDAT") << i;
  ExpectRoundTrip(image, "large " + Describe(image));
}

struct LibpngMessages {
  std::vector<std::string> messages;
};

void RecordError(png_structp png, png_const_charp message) {
  static_cast<LibpngMessages*>(png_get_error_ptr(png))->messages.push_back(std::string("error: ") + message);
  png_longjmp(png, 1);
}

void RecordWarning(png_structp png, png_const_charp message) {
  static_cast<LibpngMessages*>(png_get_error_ptr(png))->messages.push_back(std::string("warning: ") + message);
}

struct Source {
  const std::string* bytes;
  size_t position;
};

void ReadFromSource(png_structp png, png_bytep out, png_size_t length) {
  auto* source = static_cast<Source*>(png_get_io_ptr(png));
  if (length > source->bytes->size() - source->position) png_error(png, "read past the end");
  std::memcpy(out, source->bytes->data() + source->position, length);
  source->position += length;
}

// libpng reads the whole file, its end included, without an error or a warning (CRCs, the zlib
// stream's checksum and length, the chunk order are all checked), with the header's fields.
std::vector<std::string> LibpngMessagesReading(const std::string& bytes, const cv::Mat& image) {
  LibpngMessages log;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &log, RecordError, RecordWarning);
  png_infop info = png_create_info_struct(png);
  png_infop end = png_create_info_struct(png);
  Source source{&bytes, 0};
  std::vector<std::vector<png_byte>> rows;
  std::vector<png_bytep> pointers;
  if (setjmp(png_jmpbuf(png)) == 0) {
    png_set_read_fn(png, &source, ReadFromSource);
    png_read_info(png, info);
    EXPECT_EQ(png_get_image_width(png, info), static_cast<png_uint_32>(image.cols));
    EXPECT_EQ(png_get_image_height(png, info), static_cast<png_uint_32>(image.rows));
    EXPECT_EQ(png_get_bit_depth(png, info), image.depth() == CV_16U ? 16 : 8);
    EXPECT_EQ(png_get_channels(png, info), image.channels());
    EXPECT_EQ(png_get_interlace_type(png, info), PNG_INTERLACE_NONE);
    rows.assign(image.rows, std::vector<png_byte>(png_get_rowbytes(png, info)));
    for (auto& row : rows) pointers.push_back(row.data());
    png_read_image(png, pointers.data());
    png_read_end(png, end);
    EXPECT_EQ(source.position, bytes.size()) << "bytes after IEND";
  }
  png_destroy_read_struct(&png, &info, &end);
  return log.messages;
}

TEST(EncodePng, LibpngReadsItWithoutWarnings) {
  uint64_t seed = 200;
  for (const int type : kTypes) {
    for (const auto& [rows, cols] : {std::pair<int, int>{1, 1}, {77, 333}}) {
      const cv::Mat image = RandomImage(rows, cols, type, seed++);
      std::string bytes;
      ASSERT_TRUE(EncodePng(image, &bytes));
      EXPECT_EQ(LibpngMessagesReading(bytes, image), std::vector<std::string>{}) << Describe(image);
    }
  }
  const cv::Mat large = RandomImage(700, 700, CV_8UC4, 9);
  std::string bytes;
  ASSERT_TRUE(EncodePng(large, &bytes));
  EXPECT_EQ(LibpngMessagesReading(bytes, large), std::vector<std::string>{}) << "several IDAT chunks";
  // The check itself: a flipped byte in the data is reported.
  bytes[bytes.find("IDAT") + 100] ^= 0x20;
  EXPECT_NE(LibpngMessagesReading(bytes, large), std::vector<std::string>{});
}

// Every type OpenCV encodes differently (other depths, 2 channels) or not at all is left to it.
TEST(EncodePng, LeavesOtherTypesToOpenCv) {
  for (const int type : {CV_8UC2, CV_16UC2, CV_8SC1, CV_16SC3, CV_32SC1, CV_32FC1, CV_32FC3, CV_64FC1}) {
    const cv::Mat image(4, 5, type, cv::Scalar::all(1));
    EXPECT_FALSE(CanEncodePng(image)) << cv::typeToString(type);
    std::string bytes = "left over";
    EXPECT_FALSE(EncodePng(image, &bytes)) << cv::typeToString(type);
    EXPECT_TRUE(bytes.empty());
  }
  std::string bytes;
  EXPECT_FALSE(EncodePng(cv::Mat(), &bytes));
  EXPECT_FALSE(EncodePng(cv::Mat(3, 3, CV_8UC3, cv::Scalar::all(0)), &bytes, 13)) << "no level 13";
  for (const int type : kTypes) EXPECT_TRUE(CanEncodePng(cv::Mat(2, 2, type)));
}

// WriteImage encodes .png paths (any case) here; other formats and types still go to OpenCV.
TEST(WriteImage, PngPathsAreEncodedHere) {
  const fs::path dir = ibmr_testing::ScratchDir("ibmr_png_encoder_write");
  const cv::Mat image = RandomImage(33, 45, CV_8UC3, 11);
  std::string expected;
  ASSERT_TRUE(EncodePng(image, &expected));
  for (const std::string name : {"renders/view.png", "upper.PNG", "mixed.Png"}) {
    const std::string path = (dir / name).string();
    WriteImage(path, image);
    EXPECT_EQ(ReadFile(path), expected) << name;
    ExpectSamePixels(ReadImageUnchanged(path), image, name + " (ReadImageUnchanged)");
    ExpectSamePixels(DecodeImageFile(path, cv::IMREAD_UNCHANGED), image, name + " (imread)");
  }
  EXPECT_EQ(std::distance(fs::directory_iterator(dir / "renders"), fs::directory_iterator()), 1)
      << "a temporary was left behind";
  const std::string jpeg = (dir / "photo.jpg").string();
  WriteImage(jpeg, image);
  EXPECT_EQ(ReadFile(jpeg).substr(0, 2), "\xff\xd8") << "a JPEG, from OpenCV";
  // A float image has no PNG of its own: OpenCV converts it to 8 bits, as before.
  const std::string floats = (dir / "floats.png").string();
  WriteImage(floats, cv::Mat(3, 4, CV_32FC1, cv::Scalar(7.0)));
  const cv::Mat back = ReadImageUnchanged(floats);
  ASSERT_EQ(back.type(), CV_8UC1);
  EXPECT_EQ(cv::countNonZero(back != 7), 0);
}

// A .png that cannot be written: an IoError naming the path, and no file or temporary left.
TEST(WriteImage, PngWriteFailuresNameThePath) {
  const fs::path dir = ibmr_testing::ScratchDir("ibmr_png_encoder_fail");
  const cv::Mat image(8, 8, CV_8UC3, cv::Scalar(1, 2, 3));
  WriteFileAtomic((dir / "plain_file").string(), "not a folder");
  fs::create_directories(dir / "a_folder.png");
  for (const fs::path& path : {dir / "plain_file" / "view.png", dir / "a_folder.png"}) {
    try {
      WriteImage(path.string(), image);
      ADD_FAILURE() << "expected IoError for " << path;
    } catch (const IoError& e) {
      EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
    }
  }
  EXPECT_TRUE(fs::is_directory(dir / "a_folder.png"));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2) << "a temporary was left behind";
}

}  // namespace
}  // namespace ibmr
