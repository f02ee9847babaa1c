// Tests of the calibrate stage: option checks, a synthetic chessboard with a known camera, and the
// OpenCV chessboard set (../shared/datasets/opencv_calib_chessboard_stereo; skipped when absent).
#include "stages/calibrate/calibrate.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_calibrate(StageRegistry* registry);

namespace {

const std::string kChessboard = std::string(IBMR_SHARED_DIR) + "/datasets/opencv_calib_chessboard_stereo";

TEST(CalibrateOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(CalibrateOptions().Check(&error)) << error;
}

TEST(CalibrateOptions, RejectsBadValues) {
  const auto expect_key = [](CalibrateOptions options, const std::string& key) {
    std::string error;
    EXPECT_FALSE(options.Check(&error));
    EXPECT_EQ(error.rfind(key + ":", 0), 0u) << error;
  };
  CalibrateOptions o;
  o.pattern_cols = 1;
  expect_key(o, "pattern_cols");
  o = {};
  o.square_size = 0;
  expect_key(o, "square_size");
  o = {};
  o.subpixel_radius = 0;
  expect_key(o, "subpixel_radius");
  o = {};
  o.outlier_factor = 0.5;
  expect_key(o, "outlier_factor");
  o = {};
  o.min_views = 0;
  expect_key(o, "min_views");
}

// Renders a chessboard seen by a known camera from several poses (a homography warp of a
// high-resolution board), then checks that calibration recovers the focal length.
TEST(Calibrate, SyntheticChessboardKnownCamera) {
  const int cols = 7, rows = 5, square_px = 60;
  cv::Mat board((rows + 3) * square_px, (cols + 3) * square_px, CV_8UC1, cv::Scalar(255));
  for (int r = 0; r < rows + 1; ++r) {
    for (int c = 0; c < cols + 1; ++c) {
      if ((r + c) % 2 == 0) {
        cv::rectangle(board, cv::Rect((c + 1) * square_px, (r + 1) * square_px, square_px, square_px), cv::Scalar(0), cv::FILLED);
      }
    }
  }
  const double f = 500, cx = 319.5, cy = 239.5;
  const cv::Matx33d k(f, 0, cx, 0, f, cy, 0, 0, 1);
  std::vector<CalibrationView> views;
  const double angles[][2] = {{0.3, 0.1}, {-0.3, 0.2}, {0.1, -0.35}, {-0.2, -0.2}, {0.35, 0.3}, {0.0, 0.4}};
  for (int v = 0; v < 6; ++v) {
    // Board plane z = 0, board pixel (u, v) -> metres u * s; camera at 0.6 m.
    const double s = 0.025 / square_px;
    cv::Matx33d rotation;
    cv::Rodrigues(cv::Vec3d(angles[v][0], angles[v][1], 0.05 * v), rotation);
    const cv::Vec3d t = rotation * cv::Vec3d(-0.5 * board.cols * s, -0.5 * board.rows * s, 0) + cv::Vec3d(0, 0, 0.6);
    cv::Matx33d h;  // board pixel -> image pixel: K [r1 r2 t] diag(s, s, 1)
    for (int i = 0; i < 3; ++i) {
      h(i, 0) = rotation(i, 0) * s;
      h(i, 1) = rotation(i, 1) * s;
      h(i, 2) = t[i];
    }
    h = k * h;
    cv::Mat image;
    cv::warpPerspective(board, image, cv::Mat(h), cv::Size(640, 480), cv::INTER_AREA, cv::BORDER_CONSTANT, cv::Scalar(128));
    views.push_back({"view" + std::to_string(v), image});
  }
  CalibrateOptions options;
  options.pattern_cols = cols;
  options.pattern_rows = rows;
  options.model = DistortionModel::kPinhole;
  const CalibrationResult result = CalibratePlanar(views, options);
  EXPECT_NEAR(result.camera_matrix.at<double>(0, 0), f, 0.01 * f);
  EXPECT_LT(result.rms, 0.3);
  EXPECT_EQ(result.colmap_model_name, "PINHOLE");
  EXPECT_NEAR(result.colmap_params[2], result.camera_matrix.at<double>(0, 2) + 0.5, 1e-9);  // pixel convention
}

TEST(Calibrate, NoPatternNamesTheViews) {
  std::vector<CalibrationView> views = {{"blank.png", cv::Mat(480, 640, CV_8UC1, cv::Scalar(90))}};
  try {
    CalibratePlanar(views, CalibrateOptions());
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("blank.png"), std::string::npos) << e.what();
  }
}

// Acceptance: fx, fy within 0.5% of the reference, RMS <= 0.42 px, left02 flagged as an outlier.
TEST(CalibrateStage, OpenCvChessboardSet) {
  if (!fs::exists(kChessboard)) GTEST_SKIP() << kChessboard << " is absent; real-data test skipped";
  StageRegistry registry;
  RegisterStage_calibrate(&registry);
  const Stage* stage = registry.Find("calibrate");
  StageContext context;
  const fs::path workspace = fs::temp_directory_path() / ("ibmr_calibrate_test_" + std::to_string(::getpid()));
  fs::remove_all(workspace);
  context.workspace = Workspace(workspace.string());
  for (const ParamSpec& spec : stage->Parameters()) {
    if (spec.type == ParamType::kInt) context.params.Set(spec.key, static_cast<int64_t>(std::stoll(spec.default_yaml)));
    else if (spec.type == ParamType::kDouble) context.params.Set(spec.key, std::stod(spec.default_yaml));
    else if (spec.type == ParamType::kBool) context.params.Set(spec.key, spec.default_yaml == "true");
    else context.params.Set(spec.key, spec.default_yaml == "\"\"" ? std::string() : spec.default_yaml);
  }
  context.params.Set("name_filter", std::string("left[0-9]+\\.jpg"));
  context.params.Set("source", kChessboard);
  NullProgress progress;
  context.progress = &progress;
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  const double fx_ref = 535.91573396163199;
  EXPECT_NEAR(context.metrics["fx"].get<double>(), fx_ref, 0.005 * fx_ref);
  EXPECT_NEAR(context.metrics["fy"].get<double>(), fx_ref, 0.005 * fx_ref);
  EXPECT_LE(context.metrics["rms_px"].get<double>(), 0.42);
  ASSERT_EQ(context.metrics["rejected"].size(), 1u) << context.metrics.dump();
  EXPECT_EQ(context.metrics["rejected"][0]["name"], "left02.jpg");
  EXPECT_NE(context.metrics["rejected"][0]["reason"].get<std::string>().find("outlier"), std::string::npos);
  EXPECT_NE(ReadFile(workspace.string() + "/calibration/cameras.txt").find("FULL_OPENCV 640 480"), std::string::npos);
  EXPECT_NE(ReadFile(workspace.string() + "/calibration/camera.yml").find("camera_matrix"), std::string::npos);
  fs::remove_all(workspace);
}

}  // namespace
}  // namespace ibmr
