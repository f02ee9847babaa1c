// Plain operations on point clouds used as particle sets (every per-point attribute follows the
// points: normals, colours, confidence, radius).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "pipeline/core/mesh.h"
#include "stages/surfels/surfels.h"

namespace ibmr {

// The entries whose `keep` flag is set.
PointCloud Select(const PointCloud& cloud, const std::vector<char>& keep);
// Appends `more` (positions, normals, colours, confidence) to `cloud`.
void Append(const PointCloud& more, PointCloud* cloud);
// Reorders the points along a Morton (Z-order) curve, so that neighbours in space are neighbours
// in memory.
void SortSpatially(PointCloud* cloud);
// Drops points with non-finite coordinates, normals or confidence; returns how many.
size_t DropNonFinite(PointCloud* cloud);
// Removes the points whose flag is set; returns how many.
size_t RemoveFlagged(const std::vector<char>& remove, PointCloud* particles);
// Pixel and z depth of a world point in a view; false when behind it or outside its image.
bool ProjectToView(const SurfelView& view, const Eigen::Vector3f& point, Eigen::Vector2d* pixel, double* z);

}  // namespace ibmr
