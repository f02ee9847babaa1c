// Per-view resumption and sharding: a per-view stage marks each finished view with the run's cache
// key in records/<stage>.views/<view>.done, together with the view's piece of the stage's metrics
// (a JSON value the stage's per-view work returns). After a kill, the next run with the same key
// skips views already done and still has their pieces; a different key (parameters or inputs
// changed) redoes them all. Shards of one stage, run as separate processes or cluster jobs, leave
// their views' marks here, and the merge (the stage run without a shard) finds every view done and
// aggregates the pieces, so its record equals a local run's.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>

namespace ibmr {

class ViewCheckpoint {
 public:
  ViewCheckpoint() = default;  // inert: nothing is ever done
  ViewCheckpoint(std::string folder, std::string key) : folder_(std::move(folder)), key_(std::move(key)) {}

  // The view's piece when the view is done under this key; nullopt otherwise (no mark, another
  // key, or an unreadable mark: the view is then simply done again).
  std::optional<nlohmann::json> Piece(const std::string& view) const;
  bool Done(const std::string& view) const { return Piece(view).has_value(); }
  // Written atomically, after the view's outputs.
  void MarkDone(const std::string& view, const nlohmann::json& piece = nullptr) const;
  // Removes every mark (after the stage finished, its record takes over).
  void Clear() const;

 private:
  std::string folder_;
  std::string key_;
};

}  // namespace ibmr
