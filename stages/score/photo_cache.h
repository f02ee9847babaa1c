// Part of held-out-view scoring (seed 000, BMVC'99 section 6, lines 5906-5920; see score.h).
// The held-out photos the score stage compares renders with, each decoded once with its SSIM
// reference (score.h: the Gaussian means of its values and squares), shared by the renders of
// every model of that view. Before, each render re-read its photo and blurred it again: on
// templeRing 14 models x 6 views read and blurred each photo 14-28 times (twice where a filled
// render is scored too).
//
// Bounded: it keeps the `capacity` photos used last and forgets the older ones (a photo asked for
// again is read again, with identical results); the score stage sets the capacity from the items
// it runs at once, which the memory budget decides. The score stage lists its items view by view, so
// the threads work on a few views at a time and the photos they need are the recent ones.
// Thread-safe: a photo asked for by several threads at once is prepared by the first and waited
// for by the others.
#pragma once

#include <condition_variable>
#include <functional>
#include <iterator>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

#include <opencv2/core.hpp>

#include "stages/score/score.h"

namespace ibmr {

struct ScoredPhoto {
  cv::Mat image;            // CV_8UC3
  SsimReference reference;  // PrepareSsimReference(image)
};

class PhotoCache {
 public:
  // `load` reads a photo by path (CV_8UC3); an exception from it reaches the caller of Get, and
  // the next Get of that path tries again.
  PhotoCache(size_t capacity, std::function<cv::Mat(const std::string& path)> load)
      : capacity_(capacity < 1 ? 1 : capacity), load_(std::move(load)) {}

  // The photo at `path`, read and prepared by this call or an earlier one.
  std::shared_ptr<const ScoredPhoto> Get(const std::string& path) {
    std::unique_lock<std::mutex> lock(mutex_);
    for (;;) {
      auto found = entries_.find(path);
      if (found != entries_.end() && found->second.photo) {
        order_.splice(order_.begin(), order_, found->second.place);  // now the most recent
        return found->second.photo;
      }
      if (found == entries_.end()) break;  // nobody is preparing it: this thread does
      ready_.wait(lock);                   // another thread is preparing it
    }
    order_.push_front(path);
    entries_[path] = Entry{nullptr, order_.begin()};
    lock.unlock();
    std::shared_ptr<ScoredPhoto> photo;
    try {
      photo = std::make_shared<ScoredPhoto>();
      photo->image = load_(path);
      photo->reference = PrepareSsimReference(photo->image);
    } catch (...) {
      lock.lock();
      order_.erase(entries_[path].place);
      entries_.erase(path);
      ready_.notify_all();
      throw;
    }
    lock.lock();
    entries_[path].photo = photo;
    EvictBeyondCapacity();
    ready_.notify_all();
    return photo;
  }

  // At least 1; photos beyond it are forgotten at the next Get.
  void SetCapacity(size_t capacity) {
    std::lock_guard<std::mutex> lock(mutex_);
    capacity_ = capacity < 1 ? 1 : capacity;
  }

 private:
  // Forgets the least recently used photos beyond the capacity, keeping the most recent (the one
  // just prepared) and never one being prepared (its preparer finds its entry by path). Under the lock.
  void EvictBeyondCapacity() {
    for (auto it = std::prev(order_.end()); entries_.size() > capacity_ && it != order_.begin();) {
      auto previous = std::prev(it);
      if (entries_[*it].photo) {
        entries_.erase(*it);
        order_.erase(it);
      }
      it = previous;
    }
  }

  struct Entry {
    std::shared_ptr<const ScoredPhoto> photo;  // null while being prepared
    std::list<std::string>::iterator place;    // in order_
  };
  size_t capacity_;
  std::function<cv::Mat(const std::string&)> load_;
  std::mutex mutex_;
  std::condition_variable ready_;
  std::map<std::string, Entry> entries_;
  std::list<std::string> order_;  // most recently used first
};

}  // namespace ibmr
