// A full disk and a read-only workspace (a small tmpfs, then remounted read-only): the run stops
// with an error naming the file it could not write and why, nothing already computed is lost or
// replaced by a partial file, no temporary is left, and once there is room again a plain run
// finishes with outputs byte-identical to an undisturbed run's. Needs permission to mount a tmpfs
// (root in a container that allows it); skipped with a message otherwise.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <map>
#include <regex>

#include "pipeline/core/content_hash.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;
using ibmr_e2e::RunCommand;

namespace {

// Hash of every output file (records/ and logs/ hold timings) by workspace-relative path.
std::map<std::string, std::string> Outputs(const fs::path& ws) {
  std::map<std::string, std::string> out;
  if (!fs::exists(ws)) return out;
  for (const auto& entry : fs::recursive_directory_iterator(ws)) {
    if (!entry.is_regular_file()) continue;
    const std::string rel = fs::relative(entry.path(), ws).string();
    if (rel.rfind("records/", 0) == 0 || rel.rfind("logs/", 0) == 0) continue;
    out[rel] = ibmr::HashPath(entry.path().string());
  }
  return out;
}

std::vector<std::string> Temporaries(const fs::path& ws) {
  static const std::regex kTemporary(R"(.*\.tmp\.?[0-9]+(\.[^./]+)?$)");
  std::vector<std::string> found;
  for (const auto& entry : fs::recursive_directory_iterator(ws)) {
    if (std::regex_match(entry.path().filename().string(), kTemporary)) found.push_back(entry.path().string());
  }
  return found;
}

class DiskFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() / ("ibmr_disk_faults_" + std::to_string(::getpid()));
    fs::create_directories(root_ / "disk");
    mounted_ = RunCommand("mount -t tmpfs -o size=20m tmpfs " + (root_ / "disk").string()).exit_code == 0;
  }
  void TearDown() override {
    if (mounted_) RunCommand("umount " + (root_ / "disk").string());
    if (!HasFailure()) fs::remove_all(root_);
  }
  std::string Run(const fs::path& ws, const std::string& extra, int* exit_code) {
    const auto result = RunCommand("IBMR_WORKSPACE=" + ws.string() + " " + IBMR_BINARY + " run " + IBMR_SOURCE_DIR +
                                   "/configs/demo.yaml " + extra);
    *exit_code = result.exit_code;
    return result.output;
  }
  fs::path root_;
  bool mounted_ = false;
};

TEST_F(DiskFaults, FullDiskAndReadOnlyWorkspaceLoseNothing) {
  if (!mounted_) GTEST_SKIP() << "cannot mount a tmpfs here (needs root and a container that allows it); skipping";
  int code = 0;
  const fs::path reference = root_ / "reference";
  Run(reference, "", &code);
  ASSERT_EQ(code, 0);
  const auto expected = Outputs(reference);

  // 20 MB: synth, silhouettes and carve fit, the dense stages do not.
  const fs::path ws = root_ / "disk" / "ws";
  const std::string full = Run(ws, "", &code);
  EXPECT_EQ(code, 1) << "a clear error, not a crash: " << full;
  EXPECT_NE(full.find("No space left on device"), std::string::npos) << full;
  EXPECT_NE(full.find(ws.string()), std::string::npos) << "the error should name the file: " << full;
  EXPECT_TRUE(Temporaries(ws).empty());
  const auto after_full = Outputs(ws);
  for (const char* done : {"images/view_001.png", "hull/hull.ply", "masks/view_001.png.png"}) {
    ASSERT_TRUE(after_full.count(done)) << done;
    EXPECT_EQ(after_full.at(done), expected.at(done)) << done;
  }

  // Room again: a plain run finishes what is missing, identical to the undisturbed run.
  ASSERT_EQ(RunCommand("mount -o remount,size=200m " + (root_ / "disk").string()).exit_code, 0);
  const std::string resumed = Run(ws, "", &code);
  ASSERT_EQ(code, 0) << resumed;
  EXPECT_EQ(Outputs(ws), expected);

  // Read-only: a forced re-run fails naming a file, and the outputs stay as they were.
  ASSERT_EQ(RunCommand("mount -o remount,ro " + (root_ / "disk").string()).exit_code, 0);
  const std::string read_only = Run(ws, "--from render --force", &code);
  EXPECT_EQ(code, 1) << "a clear error, not a crash: " << read_only;
  EXPECT_EQ(read_only.find("terminate called"), std::string::npos) << read_only;
  EXPECT_NE(read_only.find("Read-only file system"), std::string::npos) << read_only;
  EXPECT_EQ(Outputs(ws), expected);
  ASSERT_EQ(RunCommand("mount -o remount,rw " + (root_ / "disk").string()).exit_code, 0);
}

}  // namespace
