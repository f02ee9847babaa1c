// Tests for image I/O: PNG round trips (8-bit colour, 16-bit grey), atomic writes, PFM round
// trip and its bottom-to-top row order, and messages for missing or undecodable files.
#include "pipeline/core/image_io.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_image_io_" + name); }

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const IoError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected IoError";
  return "";
}

TEST(ImageIo, PngRoundTrip) {
  const fs::path dir = MakeTestDir("png");
  const std::string path = (dir / "renders" / "view.png").string();
  cv::Mat image(5, 7, CV_8UC3);
  for (int r = 0; r < image.rows; ++r)
    for (int c = 0; c < image.cols; ++c) image.at<cv::Vec3b>(r, c) = cv::Vec3b(r * 40, c * 30, 200 - r * c);
  WriteImage(path, image);
  const cv::Mat back = ReadImageColor(path);
  ASSERT_EQ(back.type(), CV_8UC3);
  EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir / "renders"), fs::directory_iterator()), 1)
      << "a temporary was left behind";
}

TEST(ImageIo, SixteenBitAndGreyExpansion) {
  const std::string path = (MakeTestDir("png16") / "mask.png").string();
  cv::Mat image(4, 3, CV_16UC1);
  for (int i = 0; i < 12; ++i) image.at<uint16_t>(i / 3, i % 3) = static_cast<uint16_t>(5000 * i + 1);
  WriteImage(path, image);
  const cv::Mat back = ReadImageUnchanged(path);
  ASSERT_EQ(back.type(), CV_16UC1);
  EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0);
  EXPECT_EQ(ReadImageColor(path).type(), CV_8UC3);
}

TEST(ImageIo, MissingAndUndecodableFilesAreNamed) {
  const fs::path dir = MakeTestDir("errors");
  const std::string missing = (dir / "nothing.jpg").string();
  std::string message = ErrorOf([&] { ReadImageColor(missing); });
  EXPECT_NE(message.find(missing), std::string::npos) << message;
  EXPECT_NE(message.find("no such file"), std::string::npos) << message;

  const std::string garbage = (dir / "garbage.png").string();
  WriteFileAtomic(garbage, "this is not a png");
  message = ErrorOf([&] { ReadImageUnchanged(garbage); });
  EXPECT_NE(message.find(garbage), std::string::npos) << message;
  EXPECT_NE(message.find("decode"), std::string::npos) << message;

  message = ErrorOf([&] { WriteImage((dir / "x.unknownext").string(), cv::Mat(2, 2, CV_8UC1)); });
  EXPECT_NE(message.find("x.unknownext"), std::string::npos) << message;
  message = ErrorOf([&] { ReadPfm(missing); });
  EXPECT_NE(message.find(missing), std::string::npos) << message;
}

// Found by fuzzing (tests/fuzz/fuzz_image.cc): a 378-byte JPEG whose frame header declared
// hundreds of millions of pixels made OpenCV allocate 3.6 GB before it found the data missing.
TEST(ImageIo, AHeaderClaimingMorePixelsThanTheFileHoldsIsRefusedUnread) {
  const fs::path dir = MakeTestDir("bomb");
  std::vector<uchar> jpeg;
  ASSERT_TRUE(cv::imencode(".jpg", cv::Mat(16, 24, CV_8UC3, cv::Scalar(10, 200, 30)), jpeg));
  // The frame header (SOF0): FF C0, length, precision, then height and width, big-endian.
  size_t sof = 2;
  while (sof + 9 < jpeg.size() && !(jpeg[sof] == 0xff && jpeg[sof + 1] == 0xc0)) sof += 2 + (jpeg[sof + 2] << 8 | jpeg[sof + 3]);
  ASSERT_LT(sof + 9, jpeg.size());
  EXPECT_EQ(jpeg[sof + 5] << 8 | jpeg[sof + 6], 16);
  jpeg[sof + 5] = 0x4e, jpeg[sof + 6] = 0x20;  // height 20000
  jpeg[sof + 7] = 0x75, jpeg[sof + 8] = 0x30;  // width 30000
  const std::string bomb = (dir / "bomb.jpg").string();
  WriteFileAtomic(bomb, std::string(jpeg.begin(), jpeg.end()));
  for (const auto& read : {ReadImageColor, ReadImageUnchanged}) {
    const std::string message = ErrorOf([&] { read(bomb); });
    EXPECT_NE(message.find(bomb), std::string::npos) << message;
    EXPECT_NE(message.find("declares 30000 x 20000 pixels"), std::string::npos) << message;
  }

  // PNG: IHDR (width and height at bytes 16 and 20) of a 4 x 3 image rewritten to 65536 x 65536.
  const std::string png = (dir / "bomb.png").string();
  WriteImage(png, cv::Mat(3, 4, CV_8UC1, cv::Scalar(7)));
  std::string bytes = ReadFile(png);
  bytes.replace(16, 8, std::string("\x00\x01\x00\x00\x00\x01\x00\x00", 8));
  WriteFileAtomic(png, bytes);
  EXPECT_NE(ErrorOf([&] { ReadImageUnchanged(png); }).find("declares 65536 x 65536 pixels"), std::string::npos);

  // The same images with their true sizes still read.
  WriteImage(png, cv::Mat(3, 4, CV_8UC1, cv::Scalar(7)));
  EXPECT_EQ(ReadImageUnchanged(png).size(), cv::Size(4, 3));
  const std::string real = (dir / "real.jpg").string();
  ASSERT_TRUE(cv::imencode(".jpg", cv::Mat(16, 24, CV_8UC3, cv::Scalar(10, 200, 30)), jpeg));
  WriteFileAtomic(real, std::string(jpeg.begin(), jpeg.end()));
  EXPECT_EQ(ReadImageColor(real).size(), cv::Size(24, 16));
}

TEST(ImageIo, PfmRoundTripAndRowOrder) {
  const std::string path = (MakeTestDir("pfm") / "disp.pfm").string();
  cv::Mat image(3, 4, CV_32FC1);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) image.at<float>(r, c) = 10.f * r + c + 0.5f;
  WritePfm(path, image);

  const std::string bytes = ReadFile(path);
  const std::string header = "Pf\n4 3\n-1\n";
  ASSERT_EQ(bytes.size(), header.size() + 12 * sizeof(float));
  EXPECT_EQ(bytes.substr(0, header.size()), header);
  // The first stored row is the image's bottom row (r = 2).
  float first;
  std::memcpy(&first, bytes.data() + header.size(), sizeof(float));
  EXPECT_EQ(first, 20.5f);

  const cv::Mat back = ReadPfm(path);
  ASSERT_EQ(back.type(), CV_32FC1);
  ASSERT_EQ(back.size(), image.size());
  EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0.0);
}

TEST(ImageIo, PfmBigEndianAndTruncated) {
  const std::string path = (MakeTestDir("pfm_be") / "d.pfm").string();
  // 2x1 big-endian (positive scale): 1.0f = 3f800000, 2.0f = 40000000.
  WriteFileAtomic(path, std::string("Pf\n2 1\n1.0\n\x3f\x80\x00\x00\x40\x00\x00\x00", 19));
  const cv::Mat image = ReadPfm(path);
  ASSERT_EQ(image.size(), cv::Size(2, 1));
  EXPECT_EQ(image.at<float>(0, 0), 1.f);
  EXPECT_EQ(image.at<float>(0, 1), 2.f);
  WriteFileAtomic(path, std::string("Pf\n2 2\n-1.0\n\x00\x00\x80\x3f", 16));
  const std::string message = ErrorOf([&] { ReadPfm(path); });
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("truncated"), std::string::npos) << message;
}

}  // namespace
}  // namespace ibmr
