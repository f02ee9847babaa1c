// Camera formats of the NeRF world, read and written against COLMAP's conventions (sparse_model.h:
// cam_from_world, OpenCV camera axes x right, y down, z forward; pixel centres at +0.5).
//
// transforms.json (nerfstudio, instant-ngp, and the Blender synthetic layout): per frame a
// "file_path" and a 4x4 "transform_matrix", camera-to-world with OpenGL camera axes (x right,
// y up, z backwards): cam_to_world_opencv = transform_matrix * diag(1, -1, -1, 1). Intrinsics at
// the top level or per frame: "fl_x", "fl_y", "cx", "cy", "w", "h" (nerfstudio writes COLMAP's
// principal point unchanged), optional "k1", "k2", "p1", "p2" (an OPENCV camera then); or the
// Blender layout's "camera_angle_x" (focal 0.5 w / tan(angle / 2), principal point at the image
// centre, size from the image). Blender paths carry no extension ("./train/r_0"): ".png" is added.
//
// poses_bounds.npy (LLFF): a float64 array N x 17, one row per image in sorted name order: a 3x5
// matrix row-major [R | C | (h, w, f)] where R's columns are the camera's down, right and
// backwards axes in the world (camera to world) and C its centre, then the near and far depth
// bounds. The principal point is the image centre; images_<N>/ holds the photos downscaled N
// times (sizes and focal divided by N).
#pragma once

#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/core/sparse_model.h"

namespace ibmr {

// `image_size(relative_path)` gives an image's width and height (for the Blender layout); `names`
// receives the frames' image paths relative to the json's folder, in file order. Throws IoError
// naming `path` and the frame or key that is wrong.
SparseModel ParseTransformsJson(const std::string& text, const std::string& path,
                                const std::function<std::pair<int, int>(const std::string&)>& image_size,
                                std::vector<std::string>* names);
// transforms.json text for every image of `model` ("file_path": image_prefix + name); one camera
// shared by all images goes to the top level, otherwise intrinsics go per frame. Throws
// std::invalid_argument for camera models it cannot express (RADIAL_FISHEYE-like ones).
std::string WriteTransformsJson(const SparseModel& model, const std::string& image_prefix);

// Poses of `names` (sorted image names, one per row) from poses_bounds.npy bytes; `downscale` is
// the N of images_<N> (1: full size). `bounds` (optional) receives the near and far bounds.
SparseModel ParsePosesBounds(const std::string& bytes, const std::string& path, const std::vector<std::string>& names,
                             int downscale, std::vector<std::pair<double, double>>* bounds);
// poses_bounds.npy bytes for `names` (cameras with a principal point at the image centre and equal
// focal lengths; throws std::invalid_argument otherwise), with the given bounds per image.
std::string WritePosesBounds(const SparseModel& model, const std::vector<std::string>& names,
                             const std::vector<std::pair<double, double>>& bounds);

}  // namespace ibmr
