// End-to-end tests of the ibmr executable: a finished config does no work on a second run,
// a stage killed with SIGKILL halfway resumes without redoing finished views, config errors
// reach the user with file and line, and `status` explains staleness.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <thread>

#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

using ibmr_e2e::CommandResult;
using ibmr_e2e::RunCommand;

size_t CountFiles(const fs::path& dir, const std::string& suffix) {
  if (!fs::exists(dir)) return 0;
  size_t n = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.size() >= suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0) ++n;
  }
  return n;
}

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_cli_test_" + std::to_string(::getpid()) + "_" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::string WriteConfig(const std::string& synth_params) {
    const fs::path path = dir_ / "c.yaml";
    std::ofstream(path) << "workspace: ws\nstages:\n  - synth:\n" << synth_params;
    return path.string();
  }
  std::string Ibmr(const std::string& args) { return std::string(IBMR_BINARY) + " " + args; }

  fs::path dir_;
};

TEST_F(CliTest, SecondRunDoesNoWorkAndStatusIsClean) {
  const std::string config = WriteConfig("      views: 4\n      width: 64\n      height: 48\n");
  CommandResult first = RunCommand(Ibmr("run " + config));
  ASSERT_EQ(first.exit_code, 0) << first.output;
  const auto written = fs::last_write_time(dir_ / "ws" / "images" / "view_000.png");
  CommandResult second = RunCommand(Ibmr("run " + config));
  ASSERT_EQ(second.exit_code, 0) << second.output;
  EXPECT_NE(second.output.find("nothing to do"), std::string::npos) << second.output;
  EXPECT_EQ(fs::last_write_time(dir_ / "ws" / "images" / "view_000.png"), written);
  CommandResult status = RunCommand(Ibmr("status " + config));
  EXPECT_NE(status.output.find("ok     synth: up to date"), std::string::npos) << status.output;
  status = RunCommand(Ibmr("status " + config + " --set synth.seed=9"));
  EXPECT_NE(status.output.find("parameter 'seed' changed"), std::string::npos) << status.output;
  EXPECT_TRUE(fs::exists(dir_ / "ws" / "records" / "synth.json"));
  EXPECT_TRUE(fs::exists(dir_ / "ws" / "logs" / "ibmr.log"));
}

TEST_F(CliTest, StagesListsEveryStageWithDefaults) {
  CommandResult result = RunCommand(Ibmr("stages"));
  ASSERT_EQ(result.exit_code, 0) << result.output;
  for (const char* stage : {"import (version", "synth (version", "carve (version", "render (version"}) {
    EXPECT_NE(result.output.find(stage), std::string::npos) << stage;
  }
  EXPECT_NE(result.output.find("views (integer, default 24)"), std::string::npos) << result.output;
}

// OpenCV's image codecs (and GDAL's 140 libraries behind them) load with the first image that
// needs them, not with the program (pipeline/core/image_codecs.h): --help and status never load
// them, PNGs are read without them (libpng, pipeline/core/png_decoder.h), a JPEG loads them, and a
// missing codecs module is an error saying what to build.
TEST_F(CliTest, ImageCodecsLoadWithTheFirstImageNotAtStart) {
  // What the dynamic loader maps at start (ldd's listing, without running main).
  CommandResult start = RunCommand("LD_TRACE_LOADED_OBJECTS=1 " + std::string(IBMR_BINARY));
  ASSERT_EQ(start.exit_code, 0) << start.output;
  EXPECT_NE(start.output.find("libopencv_core"), std::string::npos) << start.output;
  EXPECT_EQ(start.output.find("libopencv_imgcodecs"), std::string::npos) << start.output;
  EXPECT_EQ(start.output.find("libgdal"), std::string::npos) << start.output;

  // A pair with a 4-pixel shift, as PNGs and as JPEGs: stereo-pair reads both and writes a PFM.
  cv::Mat left(40, 64, CV_8UC1), right;
  cv::randu(left, 0, 255);
  right = cv::Mat::zeros(left.size(), CV_8UC1);
  left.colRange(4, 64).copyTo(right.colRange(0, 60));
  const auto pair = [&](const std::string& extension) {
    return " stereo-pair " + (dir_ / ("l" + extension)).string() + " " + (dir_ / ("r" + extension)).string() +
           " --max-disparity 8 --out " + (dir_ / "d.pfm").string();
  };
  for (const std::string extension : {".png", ".jpg"}) {
    ASSERT_TRUE(cv::imwrite((dir_ / ("l" + extension)).string(), left) && cv::imwrite((dir_ / ("r" + extension)).string(), right));
    fs::remove(dir_ / "d.pfm");
    CommandResult read = RunCommand(Ibmr(pair(extension)));
    ASSERT_EQ(read.exit_code, 0) << extension << ": " << read.output;
    EXPECT_TRUE(fs::exists(dir_ / "d.pfm")) << extension;
  }

  // Commands that touch no image, and PNG reading, run without the module at all (nothing loads it
  // at start either).
  const std::string nowhere = "IBMR_IMAGE_CODECS=" + (dir_ / "nowhere.so").string() + " ";
  for (const std::string command : {std::string("--help"), std::string("stages"), pair(".png")}) {
    CommandResult without = RunCommand(nowhere + Ibmr(command));
    EXPECT_EQ(without.exit_code, 0) << command << ": " << without.output;
  }
  CommandResult missing = RunCommand(nowhere + Ibmr(pair(".jpg")));
  EXPECT_NE(missing.exit_code, 0);
  EXPECT_NE(missing.output.find("cannot load the image codecs module"), std::string::npos) << missing.output;
  EXPECT_NE(missing.output.find("nowhere.so: no such file"), std::string::npos) << missing.output;
  EXPECT_NE(missing.output.find("ibmr_image_codecs"), std::string::npos) << missing.output;
}

TEST_F(CliTest, ConfigErrorNamesFileLineAndKey) {
  const std::string config = WriteConfig("      views: 4\n      widht: 64\n");
  CommandResult result = RunCommand(Ibmr("run " + config));
  EXPECT_EQ(result.exit_code, 2);
  EXPECT_NE(result.output.find("c.yaml:5"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("synth.widht"), std::string::npos) << result.output;
  EXPECT_NE(result.output.find("did you mean 'width'"), std::string::npos) << result.output;
}

TEST_F(CliTest, ResumesAfterSigkillKeepingFinishedViews) {
  // Enough work that the kill lands halfway: many views at a high supersampling factor.
  const int views = 48;
  const std::string config = WriteConfig("      views: " + std::to_string(views) +
                                         "\n      width: 640\n      height: 480\n      supersample: 4\n");
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::execl(IBMR_BINARY, IBMR_BINARY, "run", config.c_str(), "--jobs", "2", static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const fs::path marks = dir_ / "ws" / "records" / "synth.views";
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
  while (CountFiles(marks, ".done") < 4 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  ::kill(pid, SIGKILL);
  int status = 0;
  ::waitpid(pid, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the run finished before it could be killed; make it longer";
  const size_t done = CountFiles(marks, ".done");
  ASSERT_GE(done, 4u);
  ASSERT_LT(done, static_cast<size_t>(views)) << "killed too late to test resumption";
  // Every image already there under its final name is whole (written under a temporary name,
  // "view_007.tmp<pid>.png", then renamed); a killed write leaves only such a temporary.
  for (const auto& e : fs::directory_iterator(dir_ / "ws" / "images")) {
    const std::string name = e.path().filename().string();
    if (e.path().extension() == ".png" && name.find(".tmp") == std::string::npos) {
      EXPECT_FALSE(cv::imread(e.path().string()).empty()) << e.path();
    }
  }
  CommandResult resumed = RunCommand(Ibmr("run " + config + " --jobs 2"));
  ASSERT_EQ(resumed.exit_code, 0) << resumed.output;
  EXPECT_NE(resumed.output.find("interrupted while running"), std::string::npos) << resumed.output;
  EXPECT_NE(resumed.output.find("resuming, "), std::string::npos) << resumed.output;
  EXPECT_EQ(CountFiles(dir_ / "ws" / "images", ".png"), static_cast<size_t>(views))
      << "every view once, and no temporary left by the killed run";
  EXPECT_FALSE(fs::exists(marks)) << "checkpoints are cleared once the stage finished";
  CommandResult again = RunCommand(Ibmr("run " + config));
  EXPECT_NE(again.output.find("nothing to do"), std::string::npos) << again.output;
}

}  // namespace
