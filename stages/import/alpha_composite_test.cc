// Alpha compositing of imported photos: straight and premultiplied colour over white, black and a
// given colour, 8 and 16 bits, and the alpha kept so that "alpha > 0.5" is "alpha8 >= 128".
#include "stages/import/alpha_composite.h"

#include <gtest/gtest.h>

namespace ibmr {
namespace {

TEST(AlphaComposite, StraightAlphaOverEachBackground) {
  cv::Mat image(1, 3, CV_8UC4);
  image.at<cv::Vec4b>(0, 0) = {10, 20, 30, 255};   // opaque: the colour as it is
  image.at<cv::Vec4b>(0, 1) = {200, 100, 50, 0};   // transparent: the background, whatever the colour
  image.at<cv::Vec4b>(0, 2) = {100, 0, 200, 51};   // a = 0.2
  for (const cv::Vec3b background : {cv::Vec3b(255, 255, 255), cv::Vec3b(0, 0, 0), cv::Vec3b(30, 60, 90)}) {
    const AlphaComposite out = CompositeOverBackground(image, background, /*premultiplied=*/false);
    EXPECT_EQ(out.bgr.at<cv::Vec3b>(0, 0), cv::Vec3b(10, 20, 30));
    EXPECT_EQ(out.bgr.at<cv::Vec3b>(0, 1), background);
    for (int c = 0; c < 3; ++c) {
      const double expected = image.at<cv::Vec4b>(0, 2)[c] * 0.2 + background[c] * 0.8;
      EXPECT_NEAR(out.bgr.at<cv::Vec3b>(0, 2)[c], expected, 0.5001) << "channel " << c;
    }
    EXPECT_EQ(out.alpha.at<uint8_t>(0, 0), 255);
    EXPECT_EQ(out.alpha.at<uint8_t>(0, 1), 0);
    EXPECT_EQ(out.alpha.at<uint8_t>(0, 2), 51);
  }
}

TEST(AlphaComposite, PremultipliedColourIsAddedToTheRestOfTheBackground) {
  cv::Mat image(1, 1, CV_8UC4, cv::Scalar(20, 40, 60, 102));  // a = 0.4, colour already times a
  const AlphaComposite out = CompositeOverBackground(image, cv::Vec3b(255, 255, 255), /*premultiplied=*/true);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(out.bgr.at<cv::Vec3b>(0, 0)[c], 20 * (c + 1) + 255 * 0.6, 0.5001);
  const AlphaComposite straight = CompositeOverBackground(image, cv::Vec3b(255, 255, 255), false);
  EXPECT_NE(out.bgr.at<cv::Vec3b>(0, 0), straight.bgr.at<cv::Vec3b>(0, 0)) << "the two readings differ";
}

TEST(AlphaComposite, SixteenBitSamplesAndTheHalfAlphaThreshold) {
  cv::Mat image(1, 4, CV_16UC4);
  image.at<cv::Vec4w>(0, 0) = {65535, 0, 32896, 65535};
  image.at<cv::Vec4w>(0, 1) = {65535, 65535, 65535, 32767};  // just below one half
  image.at<cv::Vec4w>(0, 2) = {65535, 65535, 65535, 32768};  // just above
  image.at<cv::Vec4w>(0, 3) = {0, 0, 0, 0};
  const AlphaComposite out = CompositeOverBackground(image, cv::Vec3b(0, 0, 0), false);
  EXPECT_EQ(out.bgr.at<cv::Vec3b>(0, 0), cv::Vec3b(255, 0, 128));
  EXPECT_LT(out.alpha.at<uint8_t>(0, 1), 128);
  EXPECT_GE(out.alpha.at<uint8_t>(0, 2), 128);
  EXPECT_EQ(out.alpha.at<uint8_t>(0, 3), 0);
  EXPECT_EQ(out.bgr.at<cv::Vec3b>(0, 1), cv::Vec3b(127, 127, 127));  // white at a = 0.49999 over black
  // The same threshold for 8 bits: 127 / 255 is below one half, 128 / 255 above.
  cv::Mat eight(1, 2, CV_8UC4);
  eight.at<cv::Vec4b>(0, 0) = {0, 0, 0, 127};
  eight.at<cv::Vec4b>(0, 1) = {0, 0, 0, 128};
  const AlphaComposite out8 = CompositeOverBackground(eight, cv::Vec3b(255, 255, 255), false);
  EXPECT_EQ(out8.alpha.at<uint8_t>(0, 0), 127);
  EXPECT_EQ(out8.alpha.at<uint8_t>(0, 1), 128);
}

TEST(AlphaComposite, GreyWithAlphaAndRefusedLayouts) {
  cv::Mat grey(1, 1, CV_8UC2, cv::Scalar(100, 255));
  EXPECT_EQ(CompositeOverBackground(grey, cv::Vec3b(0, 0, 0), false).bgr.at<cv::Vec3b>(0, 0), cv::Vec3b(100, 100, 100));
  EXPECT_THROW(CompositeOverBackground(cv::Mat(2, 2, CV_8UC3), cv::Vec3b(), false), std::invalid_argument);
  EXPECT_THROW(CompositeOverBackground(cv::Mat(2, 2, CV_32FC4), cv::Vec3b(), false), std::invalid_argument);
}

}  // namespace
}  // namespace ibmr
