// BackgroundTasks: tasks run in the order added on one thread, each future ready after its task
// (rethrowing what it threw), an empty task ready at once, and destruction skipping the tasks not
// started while waiting for the running one.
#include "stages/render/background_tasks.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

namespace ibmr {
namespace {

TEST(BackgroundTasks, RunInOrderOnOneThreadAndRethrow) {
  std::vector<int> order;
  std::vector<std::thread::id> threads;
  BackgroundTasks tasks;
  std::vector<std::shared_future<void>> done;
  for (int i = 0; i < 5; ++i) {
    done.push_back(tasks.Add([&, i] {
      order.push_back(i);
      threads.push_back(std::this_thread::get_id());
      if (i == 3) throw std::runtime_error("task 3 failed");
    }));
  }
  const std::shared_future<void> empty = tasks.Add({});
  EXPECT_EQ(empty.wait_for(std::chrono::seconds(0)), std::future_status::ready);
  done[0].get();
  done[2].get();
  EXPECT_THROW(done[3].get(), std::runtime_error);
  done[4].get();  // after a failed task the next ones still run
  EXPECT_EQ(order, (std::vector<int>{0, 1, 2, 3, 4}));
  for (const std::thread::id& id : threads) {
    EXPECT_EQ(id, threads[0]);
    EXPECT_NE(id, std::this_thread::get_id());
  }
}

TEST(BackgroundTasks, DestructionWaitsForTheRunningTaskAndSkipsTheRest) {
  std::atomic<int> finished{0}, started{0};
  {
    BackgroundTasks tasks;
    for (int i = 0; i < 4; ++i) {
      tasks.Add([&] {
        ++started;
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
        ++finished;
      });
    }
    while (started == 0) std::this_thread::yield();
  }
  EXPECT_EQ(finished.load(), started.load());  // none left half done
  EXPECT_LT(started.load(), 4);                // the queued ones were skipped
}

}  // namespace
}  // namespace ibmr
