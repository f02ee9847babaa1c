// A small least-recently-used cache of what a per-view stage reads for other views than the one it
// computes. Each view of a capture reads its neighbours' maps, and consecutive views share most of
// their neighbours (multi_depth on templeRing read 19 maps a view, 17 of them read before), so
// keeping the most recently used views loaded reads each map about once. Thread-safe: views in
// flight together share it; two threads that ask for the same absent view at once may both load
// it (the load runs outside the lock, so one slow read does not stall the other thread), and the
// first one's copy is kept.
#pragma once

#include <tbb/task_arena.h>

#include <algorithm>
#include <cstddef>
#include <functional>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

namespace ibmr {

// The capacity that keeps every view in flight supplied: each of the threads' views asks for
// `views_per_task` views (itself and its neighbours), and as many again stay for the next ones.
inline size_t CapacityForViewsInFlight(int views_per_task) {
  const size_t threads = static_cast<size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  return static_cast<size_t>(std::max(1, views_per_task)) * (threads + 1);
}

template <typename T>
class ViewCache {
 public:
  // `capacity`: views kept (at least 1); `load` reads one view by name and may throw (nothing is
  // cached then, and the exception reaches the caller of Get).
  ViewCache(size_t capacity, std::function<T(const std::string&)> load)
      : capacity_(capacity < 1 ? 1 : capacity), load_(std::move(load)) {}

  std::shared_ptr<const T> Get(const std::string& name) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      for (auto it = entries_.begin(); it != entries_.end(); ++it) {
        if (it->first != name) continue;
        entries_.splice(entries_.begin(), entries_, it);  // most recently used first
        ++hits_;
        return entries_.front().second;
      }
    }
    auto value = std::make_shared<const T>(load_(name));
    std::lock_guard<std::mutex> lock(mutex_);
    ++loads_;
    for (const auto& entry : entries_) {
      if (entry.first == name) return entry.second;  // another thread loaded it meanwhile
    }
    entries_.emplace_front(name, value);
    while (entries_.size() > capacity_) entries_.pop_back();
    return value;
  }

  size_t Loads() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return loads_;
  }
  size_t Hits() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return hits_;
  }

 private:
  const size_t capacity_;
  const std::function<T(const std::string&)> load_;
  mutable std::mutex mutex_;
  std::list<std::pair<std::string, std::shared_ptr<const T>>> entries_;  // most recently used first
  size_t loads_ = 0, hits_ = 0;
};

}  // namespace ibmr
