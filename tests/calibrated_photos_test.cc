// One writer per file, seen from a user's config: calibrate writes calibration/cameras.txt, import
// gives that camera to every photo of a folder (import.cameras) in sparse/, and sfm reads sparse/
// and writes its own sfm/sparse/. So a new calibration re-imports, which changes
// sparse/cameras.txt, which makes sfm stale; and a photo of another size is refused by name.
// Real data: the OpenCV sample chessboard photos (../shared/datasets), skipped where absent.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

const fs::path kChessboard = fs::path(IBMR_SOURCE_DIR) / "../shared/datasets/opencv_calib_chessboard_stereo";

class CalibratedPhotos : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(kChessboard / "left01.jpg")) GTEST_SKIP() << kChessboard << " is absent; real-data test skipped";
    root_ = fs::temp_directory_path() / ("ibmr_calibrated_photos_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_ / "photos");
    for (const char* name : {"left03.jpg", "left04.jpg", "left05.jpg"}) {
      fs::copy_file(kChessboard / name, root_ / "photos" / name);
    }
    // sfm never gets to run COLMAP here: its record is made by hand below.
    std::ofstream(root_ / "c.yaml") << "workspace: ws\ninputs:\n  calibration: " << kChessboard.string()
                                    << "\n  images: photos\nstages:\n"
                                       "  - calibrate: {name_filter: \"left0[1-9]\\\\.jpg\", pattern_cols: 9, "
                                       "pattern_rows: 6, square_size: 0.025}\n"
                                       "  - import: {format: folder, cameras: calibration/cameras.txt}\n"
                                       "  - sfm: {colmap: /bin/false, known_intrinsics: true}\n";
  }
  void TearDown() override {
    if (!root_.empty()) fs::remove_all(root_);
  }
  ibmr_e2e::CommandResult Ibmr(const std::string& args) {
    return ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " " + args + " '" + (root_ / "c.yaml").string() + "'");
  }
  std::string SfmStatus(const std::string& args = "") {
    const auto status = Ibmr("status" + args);
    const size_t at = status.output.find(" sfm: ");
    return at == std::string::npos ? status.output : status.output.substr(at, status.output.find('\n', at) - at);
  }
  fs::path root_;
};

TEST_F(CalibratedPhotos, ANewCalibrationMakesSfmStale) {
  auto run = Ibmr("run --to import");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const fs::path ws = root_ / "ws";
  const auto cameras = ibmr::ReadCamerasText((ws / "sparse").string());
  ASSERT_EQ(cameras.size(), 3u);
  const auto calibrated = ibmr::ReadCamerasText((ws / "calibration").string()).begin()->second;
  for (const auto& [id, camera] : cameras) EXPECT_EQ(camera.params, calibrated.params) << "camera " << id;

  // An sfm run that ended well, as far as the cache can tell: its record with the current key.
  run = Ibmr("run --only sfm");
  ASSERT_NE(run.exit_code, 0) << run.output;  // /bin/false is no COLMAP
  nlohmann::json record;
  std::ifstream(ws / "records/sfm.json") >> record;
  record["status"] = "ok";
  std::ofstream(ws / "records/sfm.json") << record.dump();
  fs::create_directories(ws / "sfm");
  ASSERT_NE(SfmStatus().find("up to date"), std::string::npos) << SfmStatus();

  // Another calibration (a different set of target views): import re-runs, sparse/cameras.txt
  // changes, and sfm, which reads it, is stale.
  const std::string other = " --set 'calibrate.name_filter=left(0[1-6]|1[1-4])\\.jpg'";
  run = Ibmr("run --to import" + other);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(ibmr::ReadCamerasText((ws / "sparse").string()).begin()->second.params, calibrated.params);
  const std::string status = SfmStatus(other);
  EXPECT_NE(status.find("input 'sparse' changed"), std::string::npos) << status;
}

TEST_F(CalibratedPhotos, APhotoOfAnotherSizeIsRefusedByName) {
  cv::Mat small = cv::imread((kChessboard / "left06.jpg").string());
  cv::Mat half;
  cv::resize(small, half, cv::Size(small.cols / 2, small.rows / 2));
  cv::imwrite((root_ / "photos/small one.jpg").string(), half);
  const auto run = Ibmr("run --to import");
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.output.find("small one.jpg is 320x240 but the camera of import.cameras is 640x480"), std::string::npos)
      << run.output;
}

}  // namespace
