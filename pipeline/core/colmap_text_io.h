// COLMAP's text model: sparse/cameras.txt, images.txt, points3D.txt
// (https://colmap.github.io/format.html). images.txt holds two lines per image:
//   IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME    (cam_from_world)
//   X Y POINT3D_ID ...                              (observations, may be empty)
// points3D.txt: POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX) pairs.
// Reading errors name the file, the line number and the field.
#pragma once

#include <map>
#include <string>

#include "pipeline/core/sparse_model.h"

namespace ibmr {

// Reads a folder holding cameras.txt, images.txt and points3D.txt (points3D.txt may be absent).
SparseModel ReadSparseModelText(const std::string& folder);
// Reads `folder`/cameras.txt alone (calibrate's calibration/cameras.txt), by camera id.
std::map<int, Camera> ReadCamerasText(const std::string& folder);
// Writes the three files into `folder` (created if needed), each atomically.
void WriteSparseModelText(const std::string& folder, const SparseModel& model);

}  // namespace ibmr
