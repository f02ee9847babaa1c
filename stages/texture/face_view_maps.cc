// View maps from the visibility lists (see face_view_maps.h; seed 003 §7).
#include "stages/texture/face_view_maps.h"

#include <algorithm>

#include <tbb/parallel_for.h>

namespace ibmr {

ViewMaps BuildViewMaps(const FaceGeometry& geometry, const FaceObservations& observations,
                       const std::vector<Eigen::Vector3d>& view_centers, const std::vector<std::string>& view_names,
                       int grid, double partial_penalty) {
  ViewMaps maps;
  maps.grid = grid;
  maps.view_names = view_names;
  maps.faces.resize(observations.size());
  tbb::parallel_for(size_t{0}, observations.size(), [&](size_t f) {
    std::vector<FaceObservation> list = observations[f];
    if (list.size() > 255) {
      std::partial_sort(list.begin(), list.begin() + 255, list.end(),
                        [](const FaceObservation& a, const FaceObservation& b) { return a.quality > b.quality; });
      list.resize(255);
    }
    FaceViewMap& face = maps.faces[f];
    if (list.empty()) return;
    const Eigen::Matrix3d frame = FaceFrame(geometry.normals[f]);
    std::vector<float> penalty;
    for (const FaceObservation& o : list) {
      penalty.push_back(o.SeesWhole() ? 0.f : static_cast<float>(partial_penalty));
      face.views.push_back(static_cast<uint16_t>(o.view));
      const Eigen::Vector3d direction = (view_centers[o.view] - geometry.centroids[f]).normalized();
      face.directions.push_back(MapDirection(frame, direction).cast<float>());
    }
    BuildGrid(grid, &face, penalty);
  });
  return maps;
}

}  // namespace ibmr
