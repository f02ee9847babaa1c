// Tests of the per-view flag (issue 67): the robust z-score on hand-made numbers, the flag on the
// bad side only, the guards (least scale, too few views), the log message (also for an empty
// result) and the file's round trip through ReadFlaggedViews.
#include "pipeline/core/view_agreement.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <unistd.h>

#include <filesystem>

#include "pipeline/core/atomic_file.h"

namespace ibmr {
namespace {

std::vector<ViewAgreement> Views(const std::vector<double>& figures) {
  std::vector<ViewAgreement> views;
  for (size_t i = 0; i < figures.size(); ++i) {
    ViewAgreement v;
    v.name = "v" + std::to_string(i) + ".png";
    v.has_figure = true;
    v.figure = figures[i];
    views.push_back(v);
  }
  return views;
}

TEST(ViewFlagOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(ViewFlagOptions().Check(&error)) << error;
}

TEST(ViewFlagOptions, RejectsInvalidRanges) {
  std::string error;
  ViewFlagOptions o;
  o.z_threshold = 0;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("view_flag_z:", 0), 0u) << error;
  o = ViewFlagOptions();
  o.min_scale = -0.1;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("view_flag_min_scale:", 0), 0u) << error;
  o = ViewFlagOptions();
  o.min_views = 2;
  EXPECT_FALSE(o.Check(&error));
}

// {1, 2, 3, 4, 100}: median 3, deviations {2, 1, 0, 1, 97} -> MAD 1, scale 1.4826; the outlier's
// z is 97 / 1.4826 = 65.4 while a mean/std z-score would give it only (100 - 22) / 38.9 = 2.0.
TEST(RobustZScores, MedianAndScaledMadOnHandMadeNumbers) {
  const RobustScores s = RobustZScores({1, 2, 3, 4, 100}, 0.0);
  EXPECT_DOUBLE_EQ(s.median, 3.0);
  EXPECT_DOUBLE_EQ(s.mad, 1.0);
  EXPECT_DOUBLE_EQ(s.scale, 1.4826);
  ASSERT_EQ(s.z.size(), 5u);
  EXPECT_NEAR(s.z[0], -2.0 / 1.4826, 1e-12);
  EXPECT_DOUBLE_EQ(s.z[2], 0.0);
  EXPECT_NEAR(s.z[4], 97.0 / 1.4826, 1e-9);
  // Even count: the median is the mean of the middle two; {0, 1, 2, 3}: 1.5, deviations
  // {1.5, 0.5, 0.5, 1.5} -> MAD 1.
  const RobustScores even = RobustZScores({3, 0, 2, 1}, 0.0);
  EXPECT_DOUBLE_EQ(even.median, 1.5);
  EXPECT_DOUBLE_EQ(even.mad, 1.0);
}

TEST(RobustZScores, LeastScaleAndEmptyInput) {
  // All equal: MAD 0; the least scale keeps the z-scores finite and small.
  const RobustScores flat = RobustZScores({0.8, 0.8, 0.8, 0.79}, 0.05);
  EXPECT_DOUBLE_EQ(flat.mad, 0.0);
  EXPECT_DOUBLE_EQ(flat.scale, 0.05);
  EXPECT_NEAR(flat.z[3], -0.2, 1e-9);
  const RobustScores none = RobustZScores({}, 0.05);
  EXPECT_TRUE(none.z.empty());
  EXPECT_DOUBLE_EQ(none.median, 0.0);
  // MAD 0 and no least scale: z 0 rather than a division by zero.
  EXPECT_DOUBLE_EQ(RobustZScores({1, 1, 1}, 0.0).z[0], 0.0);
}

TEST(FlagViews, OneLowViewIsFlaggedAndAHighOneIsNot) {
  // Twelve views agreeing by 0.78..0.84, one at 0.30 (bad side), one at 1.20 (good side): median
  // 0.805, MAD 0.015 -> scale the least 0.08; z -6.3 and +4.9.
  std::vector<double> figures = {0.80, 0.81, 0.79, 0.82, 0.78, 0.80, 0.83, 0.81, 0.79, 0.84, 0.80, 0.82, 0.30, 1.20};
  const ViewFlagResult r = FlagViews(Views(figures), /*higher_is_better=*/true, ViewFlagOptions());
  ASSERT_EQ(r.flagged.size(), 1u);
  EXPECT_EQ(r.flagged[0], "v12.png");
  EXPECT_TRUE(r.views[12].flagged);
  EXPECT_FALSE(r.views[13].flagged);
  EXPECT_NEAR(r.views[12].z, -0.505 / 0.08, 1e-9);
  // Lower is better: the same numbers flag the high one instead.
  const ViewFlagResult lower = FlagViews(Views(figures), /*higher_is_better=*/false, ViewFlagOptions());
  ASSERT_EQ(lower.flagged.size(), 1u);
  EXPECT_EQ(lower.flagged[0], "v13.png");
}

TEST(FlagViews, NoFlagOnACleanOrAnEquallyNoisyCapture) {
  // Clean: tight spread; a view 0.1 below the median is within the least scale's reach (3.5 * 0.08 = 0.28).
  const ViewFlagResult clean = FlagViews(Views({0.80, 0.81, 0.80, 0.79, 0.80, 0.70, 0.81, 0.80}), true, ViewFlagOptions());
  EXPECT_TRUE(clean.flagged.empty());
  // Equally noisy: every view low and spread out; the MAD grows with them.
  const ViewFlagResult noisy = FlagViews(Views({0.20, 0.35, 0.28, 0.41, 0.15, 0.30, 0.25, 0.38, 0.22, 0.33}), true, ViewFlagOptions());
  EXPECT_TRUE(noisy.flagged.empty());
  // ... but the capture as a whole agrees poorly (median 0.29 < 0.4), and the run says so.
  EXPECT_TRUE(noisy.capture_poor);
  EXPECT_NE(CaptureAgreementMessage(noisy, "confirmed fraction", ViewFlagOptions()).find("median 0.290"), std::string::npos);
  EXPECT_FALSE(clean.capture_poor);
  EXPECT_TRUE(CaptureAgreementMessage(clean, "confirmed fraction", ViewFlagOptions()).empty());
  // Without the least scale the clean capture's 0.70 would stand out (MAD 0.005).
  ViewFlagOptions no_floor;
  no_floor.min_scale = 0;
  EXPECT_EQ(FlagViews(Views({0.80, 0.81, 0.80, 0.79, 0.80, 0.70, 0.81, 0.80}), true, no_floor).flagged.size(), 1u);
}

// Precision and recall against known pose errors: one wrong view flagged, one missed; a clean
// capture calls nothing out (both undefined, no false call); a capture-wide warning calls out
// every view, so every camera off alike gives recall 1.
TEST(ScoreViewFlags, AgainstKnownPoseErrors) {
  // v5 (0.1) stands out and is wrong; v2 is wrong too but agrees (0.79); v6 is not in the truth.
  const ViewFlagResult r = FlagViews(Views({0.80, 0.81, 0.79, 0.80, 0.82, 0.10, 0.80}), true, ViewFlagOptions());
  ASSERT_EQ(r.flagged, std::vector<std::string>{"v5.png"});
  const std::map<std::string, double> px = {{"v0.png", 0.1}, {"v1.png", 0.2}, {"v2.png", 3.0},
                                            {"v3.png", 0.0}, {"v4.png", 0.3}, {"v5.png", 6.0}};
  const ViewFlagScore s = ScoreViewFlags(r, px, 1.0);
  EXPECT_EQ(s.views, 6);
  EXPECT_EQ(s.wrong, 2);
  EXPECT_EQ(s.called_out, 1);
  EXPECT_EQ(s.true_calls, 1);
  EXPECT_EQ(s.false_calls, 0);
  EXPECT_DOUBLE_EQ(s.precision, 1.0);
  EXPECT_DOUBLE_EQ(s.recall, 0.5);
  // The same flag where v5's camera is right: a false call.
  std::map<std::string, double> right = px;
  right["v5.png"] = 0.5;
  right["v2.png"] = 0.5;
  const ViewFlagScore wrongly = ScoreViewFlags(r, right, 1.0);
  EXPECT_EQ(wrongly.false_calls, 1);
  EXPECT_DOUBLE_EQ(wrongly.precision, 0.0);
  EXPECT_TRUE(std::isnan(wrongly.recall));
  // Clean: nothing called out, nothing wrong.
  const ViewFlagResult clean = FlagViews(Views({0.80, 0.81, 0.79, 0.80, 0.82, 0.78}), true, ViewFlagOptions());
  const ViewFlagScore none = ScoreViewFlags(clean, {{"v0.png", 0.2}, {"v1.png", 0.1}}, 1.0);
  EXPECT_EQ(none.called_out, 0);
  EXPECT_TRUE(std::isnan(none.precision));
  EXPECT_TRUE(std::isnan(none.recall));
  // Every camera off alike: no single flag, but the capture-wide warning names them all.
  const ViewFlagResult noisy = FlagViews(Views({0.20, 0.35, 0.28, 0.41, 0.15, 0.30}), true, ViewFlagOptions());
  ASSERT_TRUE(noisy.flagged.empty());
  ASSERT_TRUE(noisy.capture_poor);
  const ViewFlagScore all = ScoreViewFlags(noisy, {{"v0.png", 2}, {"v1.png", 3}, {"v2.png", 1.5}, {"v3.png", 4},
                                                   {"v4.png", 2}, {"v5.png", 0.5}}, 1.0);
  EXPECT_EQ(all.called_out, 6);
  EXPECT_DOUBLE_EQ(all.recall, 1.0);
  EXPECT_DOUBLE_EQ(all.precision, 5.0 / 6.0);
}

TEST(FlagViews, ViewsWithoutAFigureAndTooFewViews) {
  std::vector<ViewAgreement> views = Views({0.8, 0.8, 0.81, 0.79, 0.8, 0.1});
  ViewAgreement unscored;
  unscored.name = "lonely.png";
  views.insert(views.begin() + 2, unscored);
  const ViewFlagResult r = FlagViews(views, true, ViewFlagOptions());
  EXPECT_EQ(r.scored, 6u);
  ASSERT_EQ(r.flagged.size(), 1u);
  EXPECT_EQ(r.flagged[0], "v5.png");
  EXPECT_FALSE(r.views[2].flagged);
  // Four views: too few to judge; nothing flagged, and the message says so.
  const ViewFlagResult few = FlagViews(Views({0.8, 0.8, 0.8, 0.1}), true, ViewFlagOptions());
  EXPECT_TRUE(few.flagged.empty());
  EXPECT_NE(ViewFlagMessage(few, "confirmed fraction", ViewFlagOptions()).find("too few views"), std::string::npos);
}

TEST(ViewFlagMessage, NamesFlaggedViewsAndExplainsAnEmptyResult) {
  const ViewFlagOptions options;
  const ViewFlagResult r = FlagViews(Views({0.8, 0.81, 0.79, 0.8, 0.82, 0.2}), true, options);
  const std::string message = ViewFlagMessage(r, "confirmed fraction", options);
  EXPECT_NE(message.find("v5.png (0.200"), std::string::npos) << message;
  EXPECT_NE(message.find("wrong camera pose"), std::string::npos) << message;
  EXPECT_EQ(message.find("v4.png"), std::string::npos) << message;
  // Clean: says no view stands out.
  const ViewFlagResult clean = FlagViews(Views({0.8, 0.81, 0.79, 0.8, 0.82}), true, options);
  EXPECT_NE(ViewFlagMessage(clean, "confirmed fraction", options).find("no view stands out"), std::string::npos);
  // Empty output (no view has a figure, or no views at all): a message saying why and what to check.
  std::vector<ViewAgreement> unscored(3);
  for (size_t i = 0; i < unscored.size(); ++i) unscored[i].name = "u" + std::to_string(i);
  const std::string empty = ViewFlagMessage(FlagViews(unscored, true, options), "confirmed fraction", options);
  EXPECT_NE(empty.find("no view could be checked"), std::string::npos) << empty;
  EXPECT_NE(empty.find("3 views"), std::string::npos) << empty;
  EXPECT_NE(ViewFlagMessage(FlagViews({}, true, options), "confirmed fraction", options).find("0 views"), std::string::npos);
}

TEST(ViewAgreementJson, RoundTripOfTheFlaggedNames) {
  const ViewFlagOptions options;
  std::vector<ViewAgreement> views = Views({0.8, 0.81, 0.79, 0.8, 0.82, 0.2});
  views[0].extra["mean_geometric_consistency"] = 0.7;
  ViewAgreement unscored;
  unscored.name = "lonely.png";
  views.push_back(unscored);
  const ViewFlagResult r = FlagViews(views, true, options);
  const nlohmann::json file = ViewAgreementJson(r, "confirmed fraction", true, options);
  EXPECT_EQ(file["views"].size(), 7u);
  EXPECT_TRUE(file["views"][6]["figure"].is_null());
  EXPECT_DOUBLE_EQ(file["views"][0]["mean_geometric_consistency"].get<double>(), 0.7);
  EXPECT_DOUBLE_EQ(file["median"].get<double>(), r.scores.median);
  const std::string dir = std::filesystem::temp_directory_path().string() + "/view_agreement_test_" + std::to_string(getpid());
  std::filesystem::create_directories(dir);
  WriteFileAtomic(dir + "/view_agreement.json", file.dump());
  EXPECT_EQ(ReadFlaggedViews(dir + "/view_agreement.json"), std::vector<std::string>{"v5.png"});
  // Absent or broken: no flags, no error (the report shows flags only where a run wrote them).
  EXPECT_TRUE(ReadFlaggedViews(dir + "/missing.json").empty());
  WriteFileAtomic(dir + "/broken.json", "{not json");
  EXPECT_TRUE(ReadFlaggedViews(dir + "/broken.json").empty());
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace ibmr
