// nanoflann k-d tree over Eigen points (see point_index.h).
#include "pipeline/core/point_index.h"

#include <nanoflann.hpp>

namespace ibmr {

namespace {

struct PointsAdaptor {
  const std::vector<Eigen::Vector3f>& points;
  size_t kdtree_get_point_count() const { return points.size(); }
  float kdtree_get_pt(size_t index, size_t dim) const { return points[index][static_cast<int>(dim)]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, PointsAdaptor>, PointsAdaptor, 3,
                                                   uint32_t>;

}  // namespace

struct PointIndex::Tree {
  explicit Tree(const std::vector<Eigen::Vector3f>& points)
      : adaptor{points}, tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(16)) {
    tree.buildIndex();
  }
  PointsAdaptor adaptor;
  KdTree tree;
};

PointIndex::PointIndex(const std::vector<Eigen::Vector3f>& points) : tree_(std::make_unique<Tree>(points)) {}
PointIndex::~PointIndex() = default;

size_t PointIndex::size() const { return tree_->adaptor.points.size(); }

void PointIndex::Radius(const Eigen::Vector3f& query, float radius, std::vector<std::pair<uint32_t, float>>* out) const {
  out->clear();
  if (size() == 0) return;
  tree_->tree.radiusSearch(query.data(), radius * radius, *out, nanoflann::SearchParams(32, 0, false));
}

void PointIndex::Nearest(const Eigen::Vector3f& query, int k, std::vector<std::pair<uint32_t, float>>* out) const {
  out->clear();
  if (size() == 0 || k <= 0) return;
  std::vector<uint32_t> indices(static_cast<size_t>(k));
  std::vector<float> distances(static_cast<size_t>(k));
  const size_t found = tree_->tree.knnSearch(query.data(), static_cast<size_t>(k), indices.data(), distances.data());
  for (size_t i = 0; i < found; ++i) out->emplace_back(indices[i], distances[i]);
}

}  // namespace ibmr
