// The libpng decoder gives imread's pixels (png_decoder.h): every PNG colour type, bit depth,
// transparency and interlacing, in both read modes, against OpenCV decoding the same bytes; the
// data sets' PNGs likewise; files it refuses are left to OpenCV.
#include "pipeline/core/png_decoder.h"

#include <gtest/gtest.h>
#include <png.h>

#include <opencv2/imgcodecs.hpp>  // the read and write flags (the codecs are the module's)

#include <filesystem>
#include <map>
#include <random>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/image_codecs.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

// A PNG written with libpng: any colour type and depth, a palette and tRNS, interlacing.
struct PngSpec {
  std::string name;
  int color_type = PNG_COLOR_TYPE_RGB;
  int bit_depth = 8;
  bool interlaced = false;
  bool transparency = false;  // a tRNS chunk (palette alphas, or one transparent grey / RGB value)
};

void AppendBytes(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::string*>(png_get_io_ptr(png));
  out->append(reinterpret_cast<const char*>(data), length);
}

std::string WritePng(const PngSpec& spec, int width, int height, uint32_t seed) {
  std::string out;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png_create_info_struct(png);
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    ADD_FAILURE() << "libpng could not write " << spec.name;
    return {};
  }
  png_set_write_fn(png, &out, AppendBytes, nullptr);
  png_set_IHDR(png, info, width, height, spec.bit_depth, spec.color_type,
               spec.interlaced ? PNG_INTERLACE_ADAM7 : PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  std::mt19937 random(seed);
  std::vector<png_color> palette(1 << std::min(spec.bit_depth, 8));
  std::vector<png_byte> alphas(palette.size());
  if (spec.color_type == PNG_COLOR_TYPE_PALETTE) {
    for (size_t i = 0; i < palette.size(); ++i) {
      palette[i] = {static_cast<png_byte>(random()), static_cast<png_byte>(random()), static_cast<png_byte>(random())};
      alphas[i] = static_cast<png_byte>(random());
    }
    png_set_PLTE(png, info, palette.data(), static_cast<int>(palette.size()));
    if (spec.transparency) png_set_tRNS(png, info, alphas.data(), static_cast<int>(alphas.size()), nullptr);
  } else if (spec.transparency) {
    png_color_16 key{};
    key.gray = 1, key.red = 1, key.green = 2, key.blue = 3;
    png_set_tRNS(png, info, nullptr, 0, &key);
  }
  png_write_info(png, info);
  if (spec.bit_depth == 16) png_set_swap(png);  // rows below hold host-order 16-bit samples
  const size_t row_bytes = png_get_rowbytes(png, info);
  std::vector<std::vector<png_byte>> rows(height, std::vector<png_byte>(row_bytes));
  for (auto& row : rows) {
    for (png_byte& b : row) b = static_cast<png_byte>(random());
  }
  // A few samples equal to the tRNS key, so that the transparent value occurs.
  if (spec.transparency && spec.color_type != PNG_COLOR_TYPE_PALETTE && spec.bit_depth == 8) {
    for (int y = 0; y < height; y += 3) {
      if (spec.color_type == PNG_COLOR_TYPE_GRAY) rows[y][0] = 1;
      if (spec.color_type == PNG_COLOR_TYPE_RGB) rows[y][0] = 1, rows[y][1] = 2, rows[y][2] = 3;
    }
  }
  std::vector<png_bytep> pointers;
  for (auto& row : rows) pointers.push_back(row.data());
  png_write_image(png, pointers.data());
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

// The decoder and OpenCV agree on these bytes in both modes: same type, size and pixels.
void ExpectSameAsOpenCv(const std::string& bytes, const std::string& what) {
  const std::vector<uchar> buffer(bytes.begin(), bytes.end());
  const std::pair<PngReadMode, int> modes[] = {{PngReadMode::kColor, cv::IMREAD_COLOR | cv::IMREAD_IGNORE_ORIENTATION},
                                               {PngReadMode::kUnchanged, cv::IMREAD_UNCHANGED}};
  for (const auto& [mode, flags] : modes) {
    const cv::Mat expected = DecodeImage(buffer, flags);
    ASSERT_FALSE(expected.empty()) << what;
    cv::Mat got;
    ASSERT_TRUE(DecodePng(bytes, mode, &got)) << what;
    ASSERT_EQ(got.type(), expected.type()) << what << " flags " << flags;
    ASSERT_EQ(got.size(), expected.size()) << what;
    cv::Mat difference;
    cv::absdiff(got.reshape(1), expected.reshape(1), difference);
    EXPECT_EQ(cv::countNonZero(difference), 0) << what << " flags " << flags;
  }
}

TEST(DecodePng, EveryKindOfPngAsOpenCvReadsIt) {
  std::vector<PngSpec> specs;
  for (const int depth : {1, 2, 4, 8, 16}) specs.push_back({"grey " + std::to_string(depth), PNG_COLOR_TYPE_GRAY, depth});
  for (const int depth : {1, 2, 4, 8}) {
    specs.push_back({"palette " + std::to_string(depth), PNG_COLOR_TYPE_PALETTE, depth});
    specs.push_back({"palette with alphas " + std::to_string(depth), PNG_COLOR_TYPE_PALETTE, depth, false, true});
  }
  for (const int depth : {8, 16}) {
    const std::string d = " " + std::to_string(depth);
    specs.push_back({"grey alpha" + d, PNG_COLOR_TYPE_GRAY_ALPHA, depth});
    specs.push_back({"rgb" + d, PNG_COLOR_TYPE_RGB, depth});
    specs.push_back({"rgba" + d, PNG_COLOR_TYPE_RGB_ALPHA, depth});
    specs.push_back({"rgb with a transparent colour" + d, PNG_COLOR_TYPE_RGB, depth, false, true});
    specs.push_back({"grey with a transparent value" + d, PNG_COLOR_TYPE_GRAY, depth, false, true});
    specs.push_back({"interlaced rgb" + d, PNG_COLOR_TYPE_RGB, depth, true});
    specs.push_back({"interlaced rgba" + d, PNG_COLOR_TYPE_RGB_ALPHA, depth, true});
  }
  specs.push_back({"interlaced palette", PNG_COLOR_TYPE_PALETTE, 4, true, true});
  uint32_t seed = 1;
  for (const PngSpec& spec : specs) {
    for (const auto& [width, height] : {std::pair<int, int>{1, 1}, {37, 23}}) {
      const std::string bytes = WritePng(spec, width, height, seed++);
      ASSERT_FALSE(bytes.empty()) << spec.name;
      ExpectSameAsOpenCv(bytes, spec.name + " " + std::to_string(width) + "x" + std::to_string(height));
    }
  }
}

// What ibmr writes (OpenCV's encoder: grey, BGR, BGRA in 8 and 16 bits, and 1-bit bilevel).
TEST(DecodePng, WhatOpenCvWritesReadsBack) {
  std::mt19937 random(7);
  for (const int type : {CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_16UC3, CV_16UC4}) {
    cv::Mat image(29, 41, type);
    cv::randu(image, 0, CV_MAT_DEPTH(type) == CV_16U ? 65536 : 256);
    std::vector<uchar> bytes;
    ASSERT_TRUE(EncodeImage(".png", image, &bytes));
    ExpectSameAsOpenCv(std::string(bytes.begin(), bytes.end()), "OpenCV type " + std::to_string(type));
    cv::Mat back;
    ASSERT_TRUE(DecodePng(std::string(bytes.begin(), bytes.end()), PngReadMode::kUnchanged, &back));
    EXPECT_EQ(cv::countNonZero(cv::Mat(back != image).reshape(1)), 0) << "type " << type;
  }
  cv::Mat mask(20, 30, CV_8UC1);
  cv::randu(mask, 0, 2);
  mask *= 255;
  std::vector<uchar> bilevel;
  ASSERT_TRUE(EncodeImage(".png", mask, &bilevel, {cv::IMWRITE_PNG_BILEVEL, 1}));
  ExpectSameAsOpenCv(std::string(bilevel.begin(), bilevel.end()), "bilevel");
}

// Not a PNG, cut short, or corrupt in its data: false and an empty image (OpenCV gets the file).
TEST(DecodePng, RefusesWhatLibpngCannotRead) {
  cv::Mat image(16, 16, CV_8UC3, cv::Scalar(1, 2, 3));
  std::vector<uchar> encoded;
  ASSERT_TRUE(EncodeImage(".png", image, &encoded));
  const std::string bytes(encoded.begin(), encoded.end());
  cv::Mat out;
  EXPECT_FALSE(DecodePng("not a png at all", PngReadMode::kColor, &out));
  EXPECT_TRUE(out.empty());
  EXPECT_FALSE(LooksLikePng("\x89PN"));
  EXPECT_TRUE(LooksLikePng(bytes));
  for (const size_t keep : {size_t{8}, size_t{20}, size_t{33}, size_t{60}, bytes.size() - 13}) {
    EXPECT_FALSE(DecodePng(bytes.substr(0, keep), PngReadMode::kColor, &out)) << keep << " bytes";
    EXPECT_TRUE(out.empty());
  }
  std::string corrupt = bytes;
  const size_t idat = corrupt.find("IDAT");
  ASSERT_NE(idat, std::string::npos);
  corrupt[idat + 6] ^= 0x5a;  // in the IDAT chunk's data: its CRC no longer matches
  EXPECT_FALSE(DecodePng(corrupt, PngReadMode::kUnchanged, &out));
  EXPECT_TRUE(out.empty());
}

// The data sets' PNGs (photos, masks, disparities): the same pixels as OpenCV's.
TEST(DecodePng, DataSetsAsOpenCvReadsThem) {
  const fs::path root = fs::path(IBMR_SHARED_DIR) / "datasets";
  if (!fs::exists(root)) GTEST_SKIP() << root << " is absent (../shared/datasets beside the project)";
  std::map<std::string, int> per_folder;
  size_t compared = 0;
  for (const auto& entry : fs::recursive_directory_iterator(root)) {
    if (!entry.is_regular_file() || entry.path().extension() != ".png") continue;
    if (per_folder[entry.path().parent_path().string()]++ >= 3) continue;  // three a folder keep it short
    ExpectSameAsOpenCv(ReadFile(entry.path().string()), entry.path().string());
    ++compared;
  }
  EXPECT_GT(compared, 10u);
}

}  // namespace
}  // namespace ibmr
