// Pruning and growth of the particle system (particle_pruning.cc; seed 000 section 5).
#pragma once

#include <vector>

#include "pipeline/core/mesh.h"
#include "pipeline/core/point_index.h"
#include "stages/surfels/surfels.h"

namespace ibmr {

// Flags particles with fewer than `min_support` data points within support_radius (nor fewer than
// `min_support_fraction` of the median particle's count), or fewer than `min_neighbours`
// particles within 2.5 spacings. Data support is checked only when `check_data` (after growth, the
// grown particles have none by design).
std::vector<char> Unsupported(const PointIndex& data_index, const PointCloud& particles, bool check_data,
                              double spacing, const SurfelOptions& options);

// The stretching rule: midpoints of neighbour pairs more than stretch_distance and less than
// max_gap spacings apart whose normals agree, where no particle is near the midpoint (at most one
// candidate per gap).
PointCloud StretchCandidates(const PointCloud& particles, double spacing, const SurfelOptions& options);

}  // namespace ibmr
