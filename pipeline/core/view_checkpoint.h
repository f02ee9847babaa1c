// Per-view resumption: a per-view stage marks each finished view with the run's cache key in
// records/<stage>.views/<view>.done. After a kill, the next run with the same key skips views
// already done; a different key (parameters or inputs changed) redoes them all.
#pragma once

#include <string>

namespace ibmr {

class ViewCheckpoint {
 public:
  ViewCheckpoint() = default;  // inert: nothing is ever done
  ViewCheckpoint(std::string folder, std::string key) : folder_(std::move(folder)), key_(std::move(key)) {}

  bool Done(const std::string& view) const;
  void MarkDone(const std::string& view) const;
  // Removes every mark (after the stage finished, its record takes over).
  void Clear() const;

 private:
  std::string folder_;
  std::string key_;
};

}  // namespace ibmr
