// Tests for atomic writes: contents, parent folders, no temporaries left behind, the extension
// kept by WriteViaTemporary, errors that name the path, a flush to the disk that fails, and the
// folder's entry flushed after the data.
#include "pipeline/core/atomic_file.h"

#include <gtest/gtest.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "pipeline/core/errors.h"
#include "tests/scratch_dir.h"

// This program's fsync (it takes the place of the C library's for the code linked in): fails as a
// full disk does while `fail_fsync`, else makes the system call.
// With `record_fsync`, it also notes what each flush was of (the path behind the descriptor); with
// `fail_folder_fsync`, a flush of a folder fails as an I/O error.
static std::atomic<bool> fail_fsync{false}, fail_folder_fsync{false}, record_fsync{false};
static std::vector<std::string> flushed;
extern "C" int fsync(int fd) {
  char target[4096] = {0};
  const std::string link = "/proc/self/fd/" + std::to_string(fd);
  const ssize_t length = ::readlink(link.c_str(), target, sizeof(target) - 1);
  const std::string path = length > 0 ? std::string(target, static_cast<size_t>(length)) : std::string();
  if (record_fsync) flushed.push_back(path);
  if (fail_fsync || (fail_folder_fsync && std::filesystem::is_directory(path))) {
    errno = fail_fsync ? ENOSPC : EIO;
    return -1;
  }
  return static_cast<int>(::syscall(SYS_fsync, fd));
}

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_atomic_file_" + name); }

int CountFiles(const fs::path& dir) {
  int n = 0;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) n += entry.is_regular_file() ? 1 : 0;
  return n;
}

TEST(AtomicFile, WritesCreatesFoldersAndOverwrites) {
  const fs::path dir = MakeTestDir("write");
  const std::string path = (dir / "a" / "b" / "file.bin").string();
  const std::string bytes("binary\0data\n", 12);
  WriteFileAtomic(path, bytes);
  EXPECT_EQ(ReadFile(path), bytes);
  WriteFileAtomic(path, "second");
  EXPECT_EQ(ReadFile(path), "second");
  WriteFileAtomic(path, "");
  EXPECT_EQ(ReadFile(path), "");
  EXPECT_EQ(CountFiles(dir), 1) << "a temporary was left behind";
}

// A write whose data cannot be flushed to the disk (a full disk reports it then) fails naming the
// file, and leaves the previous file and no temporary, for both writers.
TEST(AtomicFile, AFailedFlushKeepsThePreviousFileAndNamesIt) {
  const fs::path dir = MakeTestDir("flush");
  const std::string path = (dir / "map.bin").string(), image = (dir / "photo.txt").string();
  WriteFileAtomic(path, "good");
  WriteFileAtomic(image, "good too");
  fail_fsync = true;
  auto expect_refused = [&](const std::string& target, const std::function<void()>& write) {
    try {
      write();
      ADD_FAILURE() << "expected IoError for " << target;
    } catch (const IoError& e) {
      EXPECT_NE(std::string(e.what()).find(target), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("did not reach the disk"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("No space left"), std::string::npos) << e.what();
    }
  };
  expect_refused(path, [&] { WriteFileAtomic(path, "partial"); });
  expect_refused(image, [&] { WriteViaTemporary(image, [](const std::string& tmp) { std::ofstream(tmp) << "partial"; }); });
  fail_fsync = false;
  EXPECT_EQ(ReadFile(path), "good");
  EXPECT_EQ(ReadFile(image), "good too");
  EXPECT_EQ(CountFiles(dir), 2) << "a temporary was left behind";
}

// The rename is flushed too: the folder's entry after the file's data, so that a later write (a
// stage's record saying it is done) cannot reach the disk before the new name does; a folder that
// cannot be flushed fails the write, naming the file.
TEST(AtomicFile, TheFoldersNewEntryIsFlushedAfterTheData) {
  const fs::path dir = MakeTestDir("folder_flush");
  const std::string path = (dir / "sub" / "record.json").string();
  flushed.clear();
  record_fsync = true;
  WriteFileAtomic(path, "done");
  record_fsync = false;
  ASSERT_EQ(flushed.size(), 2u);
  EXPECT_NE(flushed[0].find("record.json.tmp."), std::string::npos) << flushed[0];
  EXPECT_EQ(fs::path(flushed[1]), fs::canonical(dir / "sub"));
  fail_folder_fsync = true;
  try {
    WriteViaTemporary(path, [](const std::string& tmp) { std::ofstream(tmp) << "again"; });
    ADD_FAILURE() << "a folder that cannot be flushed must fail the write";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("folder's new entry"), std::string::npos) << e.what();
  }
  fail_folder_fsync = false;
  EXPECT_EQ(CountFiles(dir), 1) << "a temporary was left behind";
}

TEST(AtomicFile, ReadMissingNamesPath) {
  const fs::path dir = MakeTestDir("missing");
  const std::string path = (dir / "nothing.txt").string();
  try {
    ReadFile(path);
    FAIL() << "expected IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("No such file"), std::string::npos) << e.what();
  }
}

TEST(AtomicFile, WriteFailureNamesPath) {
  const fs::path dir = MakeTestDir("fail");
  WriteFileAtomic((dir / "plain").string(), "x");
  // A regular file where a folder is needed.
  const std::string path = (dir / "plain" / "child.txt").string();
  try {
    WriteFileAtomic(path, "y");
    FAIL() << "expected IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
  }
}

TEST(AtomicFile, WriteViaTemporaryKeepsExtension) {
  const fs::path dir = MakeTestDir("via");
  const std::string path = (dir / "sub" / "x.png").string();
  std::string seen;
  WriteViaTemporary(path, [&](const std::string& tmp_path) {
    seen = tmp_path;
    std::ofstream(tmp_path) << "payload";
  });
  EXPECT_NE(seen, path);
  EXPECT_EQ(fs::path(seen).extension(), ".png") << seen;
  EXPECT_EQ(fs::path(seen).parent_path(), fs::path(path).parent_path()) << "rename must stay on one file system";
  EXPECT_NE(seen.find(".tmp"), std::string::npos) << seen;
  EXPECT_EQ(ReadFile(path), "payload");
  EXPECT_FALSE(fs::exists(seen));
}

TEST(AtomicFile, FailedWriterLeavesOldFile) {
  const fs::path dir = MakeTestDir("keep");
  const std::string path = (dir / "x.txt").string();
  WriteFileAtomic(path, "good");
  EXPECT_THROW(WriteViaTemporary(path,
                                 [](const std::string& tmp_path) {
                                   std::ofstream(tmp_path) << "half";
                                   throw IoError("writer failed");
                                 }),
               IoError);
  EXPECT_EQ(ReadFile(path), "good");
  EXPECT_EQ(CountFiles(dir), 1) << "the temporary must be removed";
  // A writer that produces nothing is an error too.
  EXPECT_THROW(WriteViaTemporary(path, [](const std::string&) {}), IoError);
  EXPECT_EQ(ReadFile(path), "good");
}

}  // namespace
}  // namespace ibmr

namespace ibmr {
namespace {

TEST(AtomicFile, StaleTemporariesOfDeadWritersAreRemoved) {
  const fs::path dir = ibmr_testing::ScratchDir("ibmr_stale_tmp");
  fs::create_directories(dir / "maps" / "sub");
  // A pid no process can have (above Linux's pid_max limit of 2^22).
  const std::string dead = "999999999", alive = std::to_string(::getpid());
  const auto touch = [](const fs::path& p) { std::ofstream(p) << "x"; };
  touch(dir / "maps" / ("a.tmp" + dead + ".png"));            // WriteViaTemporary's name
  touch(dir / "maps" / "sub" / ("b.bin.tmp." + dead));         // WriteFileAtomic's name
  touch(dir / "maps" / ("c.tmp" + alive + ".png"));           // a live writer's: kept
  touch(dir / "maps" / "a.png");                              // finished outputs: kept
  touch(dir / "fused.ply");
  touch(dir / ("fused.ply.tmp." + dead));
  touch(dir / ("other.ply.tmp." + dead));                     // not this output's: kept
  EXPECT_EQ(RemoveStaleTemporaries((dir / "maps").string()), 2u);
  EXPECT_EQ(RemoveStaleTemporaries((dir / "fused.ply").string()), 1u);
  EXPECT_TRUE(fs::exists(dir / "maps" / ("c.tmp" + alive + ".png")));
  EXPECT_TRUE(fs::exists(dir / "maps" / "a.png"));
  EXPECT_TRUE(fs::exists(dir / "fused.ply"));
  EXPECT_TRUE(fs::exists(dir / ("other.ply.tmp." + dead)));
  EXPECT_FALSE(fs::exists(dir / "maps" / ("a.tmp" + dead + ".png")));
  EXPECT_EQ(RemoveStaleTemporaries((dir / "missing").string()), 0u);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ibmr
