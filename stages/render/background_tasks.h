// Tasks run one after the other on one background thread, in the order added, each with a future
// that is ready when it has run (and rethrows what it threw). The render stage runs its models'
// preparation ahead this way (RenderModel::BackgroundWork): one thread, so that the work beside the
// drawing never takes more than one core. Destroying the queue skips the tasks not yet started and
// waits for the running one: a task may use objects that outlive the queue, never the reverse.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <future>
#include <mutex>
#include <thread>
#include <utility>

namespace ibmr {

class BackgroundTasks {
 public:
  BackgroundTasks() = default;
  BackgroundTasks(const BackgroundTasks&) = delete;
  BackgroundTasks& operator=(const BackgroundTasks&) = delete;
  ~BackgroundTasks() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
      queue_.clear();  // their promises break: nobody waits for them any more
    }
    wake_.notify_all();
    if (worker_.joinable()) worker_.join();
  }

  // Queues `task` (an empty one is ready at once); the thread starts with the first task.
  std::shared_future<void> Add(std::function<void()> task) {
    std::promise<void> done;
    std::shared_future<void> future = done.get_future().share();
    if (!task) {
      done.set_value();
      return future;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      queue_.emplace_back(std::move(task), std::move(done));
      if (!worker_.joinable()) worker_ = std::thread([this] { Work(); });
    }
    wake_.notify_one();
    return future;
  }

 private:
  void Work() {
    for (;;) {
      std::pair<std::function<void()>, std::promise<void>> next;
      {
        std::unique_lock<std::mutex> lock(mutex_);
        wake_.wait(lock, [this] { return stop_ || !queue_.empty(); });
        if (stop_ || queue_.empty()) return;  // stop_: skip the rest
        next = std::move(queue_.front());
        queue_.pop_front();
      }
      try {
        next.first();
        next.second.set_value();
      } catch (...) {
        next.second.set_exception(std::current_exception());
      }
    }
  }

  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<std::pair<std::function<void()>, std::promise<void>>> queue_;
  bool stop_ = false;
  std::thread worker_;
};

}  // namespace ibmr
