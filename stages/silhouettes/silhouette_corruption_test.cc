// Wrong silhouettes on purpose: erosion shrinks and dilation grows a disc's mask by the stated
// radius, holes remove foreground inside it, the same view gets the same holes, and strength 0 or
// "none" leaves the mask alone.
#include "stages/silhouettes/silhouette_corruption.h"

#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

namespace ibmr {
namespace {

cv::Mat Disc() {
  cv::Mat mask(240, 320, CV_8UC1, cv::Scalar(0));
  cv::circle(mask, {160, 120}, 60, cv::Scalar(255), cv::FILLED);
  return mask;
}

TEST(SilhouetteCorruption, ErodeDilateAndHolesChangeTheMaskAsStated) {
  const double area = cv::countNonZero(Disc());
  const int radius = static_cast<int>(std::lround(0.025 * 400));  // strength 1, diagonal 400: 10 px
  cv::Mat eroded = Disc(), dilated = Disc(), holed = Disc(), again = Disc(), untouched = Disc();
  CorruptSilhouette(SilhouetteCorruption::kErode, 1.0, "v", &eroded);
  CorruptSilhouette(SilhouetteCorruption::kDilate, 1.0, "v", &dilated);
  CorruptSilhouette(SilhouetteCorruption::kHoles, 1.0, "v", &holed);
  CorruptSilhouette(SilhouetteCorruption::kHoles, 1.0, "v", &again);
  CorruptSilhouette(SilhouetteCorruption::kErode, 0.0, "v", &untouched);
  EXPECT_NEAR(cv::countNonZero(eroded), M_PI * (60 - radius) * (60 - radius), 0.03 * area);
  EXPECT_NEAR(cv::countNonZero(dilated), M_PI * (60 + radius) * (60 + radius), 0.03 * area);
  EXPECT_LT(cv::countNonZero(holed), area - M_PI * 8 * 8);  // at least one hole of radius 8 inside
  EXPECT_EQ(cv::norm(holed, again, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(untouched, Disc(), cv::NORM_INF), 0);
  SilhouetteCorruption c;
  EXPECT_TRUE(SilhouetteCorruptionFromName("holes", &c));
  EXPECT_FALSE(SilhouetteCorruptionFromName("blur", &c));
}

}  // namespace
}  // namespace ibmr
