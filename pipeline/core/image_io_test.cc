// Tests for image I/O: PNG round trips (8-bit colour, 16-bit grey), atomic writes, PFM round
// trip and its bottom-to-top row order, and messages for missing or undecodable files.
#include "pipeline/core/image_io.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>

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
