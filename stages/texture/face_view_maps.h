// Builds the polygon view maps of seed 003 §7 (format and lookup in pipeline/core/view_maps.h):
// per face, every view that sees it entirely (face_visibility.h), each view's direction from the
// face centroid mapped into the face's local frame, and the grid of nearest views, where a view
// that sees the face only partly (partial, hidden or back in face_visibility.h) counts
// `partial_penalty` radians farther. At most 255
// views per face are kept (the grid stores 8-bit indices): the best by quality.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "pipeline/core/view_maps.h"
#include "stages/texture/face_visibility.h"

namespace ibmr {

ViewMaps BuildViewMaps(const FaceGeometry& geometry, const FaceObservations& observations,
                       const std::vector<Eigen::Vector3d>& view_centers, const std::vector<std::string>& view_names,
                       int grid, double partial_penalty = 0);

}  // namespace ibmr
