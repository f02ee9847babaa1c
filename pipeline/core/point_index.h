// Neighbour queries on a fixed set of 3-D points through nanoflann's k-d tree (kept in one
// translation unit). The tree keeps a reference to the points: they must outlive it and not move.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

namespace ibmr {

class PointIndex {
 public:
  explicit PointIndex(const std::vector<Eigen::Vector3f>& points);
  ~PointIndex();
  PointIndex(const PointIndex&) = delete;
  PointIndex& operator=(const PointIndex&) = delete;

  // Points within `radius` of `query` as (index, squared distance), in no particular order; `out` is
  // cleared first (reuse it across calls to avoid allocations). Thread-safe.
  void Radius(const Eigen::Vector3f& query, float radius, std::vector<std::pair<uint32_t, float>>* out) const;
  // The `k` nearest points (fewer when the set is smaller) as (index, squared distance).
  void Nearest(const Eigen::Vector3f& query, int k, std::vector<std::pair<uint32_t, float>>* out) const;
  size_t size() const;

 private:
  struct Tree;
  std::unique_ptr<Tree> tree_;
};

}  // namespace ibmr
