// Stage locks: an exclusive holder (a whole run) excludes every other; shared holders (shards)
// run side by side but exclude a whole run; a probe says who holds a lock; a released lock is free.
#include "pipeline/runner/stage_lock.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <memory>

namespace fs = std::filesystem;

namespace ibmr {
namespace {

class StageLockTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_stage_lock_test_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    path_ = (dir_ / "stage.lock").string();
  }
  void TearDown() override { fs::remove_all(dir_); }

  fs::path dir_;
  std::string path_;
};

TEST_F(StageLockTest, AnExclusiveHolderExcludesEveryOtherAndSaysWhoItIs) {
  EXPECT_EQ(LockHolder(path_), "") << "a lock never taken";
  auto run = std::make_unique<StageLock>();
  std::string holder;
  ASSERT_TRUE(run->TryLock(path_, true, &holder));
  const std::string pid = "pid " + std::to_string(::getpid()) + " on ";
  // Another open of the file stands for another process: flock locks belong to open files.
  StageLock second, shard;
  EXPECT_FALSE(second.TryLock(path_, true, &holder));
  EXPECT_NE(holder.find(pid), std::string::npos) << holder;
  holder.clear();
  EXPECT_FALSE(shard.TryLock(path_, false, &holder));
  EXPECT_NE(holder.find(pid), std::string::npos) << holder;
  EXPECT_NE(LockHolder(path_).find(pid), std::string::npos);
  run.reset();  // the run ends (as a killed process's lock is dropped by the kernel)
  EXPECT_EQ(LockHolder(path_), "");
  EXPECT_TRUE(second.TryLock(path_, true, &holder));
}

TEST_F(StageLockTest, ShardsRunSideBySideButExcludeAWholeRun) {
  StageLock shard_a, shard_b, run;
  std::string holder;
  ASSERT_TRUE(shard_a.TryLock(path_, false, &holder));
  EXPECT_TRUE(shard_b.TryLock(path_, false, &holder));
  EXPECT_FALSE(run.TryLock(path_, true, &holder));
  EXPECT_EQ(holder, "shards (--views) of the stage");
  EXPECT_EQ(LockHolder(path_), "shards (--views) of the stage");
}

}  // namespace
}  // namespace ibmr
