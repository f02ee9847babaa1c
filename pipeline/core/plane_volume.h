// A volume of coloured, partly transparent planes in a virtual camera: the (x, y, d) volume of
// colours and real-valued opacities of seed 000 section 3 (lines 5526-5610, Szeliski & Golland,
// ICCV 1998), "a set of (potentially) transparent acetates stacked at different d levels", with d
// planes z = const of a virtual camera (generalized disparity space, lines 5314-5345). The view
// synthesis field calls it a multiplane image (MPI). Shared by the volume stage, which fits it to
// the photos, and the render stage, which draws it.
//
// Drawing a camera (seed 000 lines 5560-5575, eq. 6): each plane is re-projected into the camera
// by its homography and the planes are composited with the over operator, back to front:
// C = c_k a_k + (1 - a_k) C. Evaluated per pixel along the pixel's ray: the ray meets plane k at
// the volume pixel
//   x_k = fx (o_x w_k + (1 - o_z w_k) r_x) + cx,   y_k likewise,   w_k = 1 / z_k,
// where o is the camera centre and r = d / d_z the ray direction in the volume's frame (the same
// mapping as the plane's homography, without a 3x3 product per plane); the plane lies ahead of the
// camera where (1 - o_z w_k) has the sign of d_z, and the planes met ahead are ordered by their
// distance along the ray: nearest plane first for d_z > 0, farthest first otherwise. The
// composite is accumulated front to back, C = sum_k c_k a_k T_k with T_k = prod_{j before k}
// (1 - a_j), which is the same sum as back-to-front "over" and lets a ray stop once T is ~0.
//
// On disk (volume/<reference>/, written by the volume stage):
//   plane_000.png ... plane_<D-1>.png   RGBA, 8 bits, straight (not premultiplied) colour; plane
//                                       000 is the nearest
//   volume.json  {"format": "ibmr_plane_volume", "version": 1, "width", "height",
//                 "camera": {"model": "PINHOLE", "params": [fx, fy, cx, cy]} (COLMAP's pixel
//                 convention: the top-left pixel's centre at (0.5, 0.5)),
//                 "cam_from_world": {"qvec": [w, x, y, z], "tvec": [x, y, z]} (COLMAP's),
//                 "depths": [z_0, ..., z_{D-1}] (ascending, along the virtual camera's axis),
//                 "planes": ["plane_000.png", ...], "premultiplied": false}
// The farthest plane is opaque (alpha 1 everywhere): a ray that reaches it inside the volume's
// image is fully covered, so the volume leaves no hole inside its field of view.
#pragma once

#include <algorithm>
#include <opencv2/core.hpp>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

// A ray stops once the transmittance in front of the next plane falls to this: the planes behind
// add at most this fraction of a colour (renders and the fitting's model alike).
constexpr float kOpaqueTransmittance = 1e-3f;

struct PlaneVolume {
  Camera camera;            // PINHOLE; camera.width x camera.height is the size of every plane
  Rigid3d cam_from_world;   // the virtual camera's pose
  std::vector<double> depths;  // z of each plane in the virtual camera, ascending (plane 0 nearest)
  // Plane-major cells: cells[((k * height + y) * width + x) * 4 + c], c = B, G, R (OpenCV's order,
  // straight colour) and alpha, all in [0, 1].
  std::vector<float> cells;

  int Width() const { return camera.width; }
  int Height() const { return camera.height; }
  int Planes() const { return static_cast<int>(depths.size()); }
  size_t PlaneFloats() const { return static_cast<size_t>(camera.width) * camera.height * 4; }
  float* Plane(int k) { return cells.data() + k * PlaneFloats(); }
  const float* Plane(int k) const { return cells.data() + k * PlaneFloats(); }
  // Allocates `planes` transparent black planes for the current camera.
  void Allocate();
};

// Where a ray meets one plane: plane index and volume pixel coordinates in index units (pixel
// (i, j)'s centre at (i, j)); `inside` when within the plane's image (half a pixel beyond the
// outer centres at most).
struct RaySample {
  int plane = 0;
  float x = 0, y = 0;
  bool inside = false;
};

// The constants of one camera looking at a volume, for per-pixel ray sampling without allocation.
class VolumeRays {
 public:
  // One pixel's ray: its direction's x/z and y/z in the volume's frame, and whether it runs toward
  // larger z (then the planes are met nearest first).
  struct Ray {
    double rx = 0, ry = 0;
    bool forward = true, valid = false;  // valid: not parallel to the planes
  };

  VolumeRays(const PlaneVolume& volume, const Camera& camera, const Rigid3d& cam_from_world);
  Ray RayAt(double u, double v) const {
    const Eigen::Vector3d d = direction_from_pixel_ * Eigen::Vector3d(u, v, 1.0);
    Ray ray;
    if (d.z() == 0) return ray;
    ray.rx = d.x() / d.z();
    ray.ry = d.y() / d.z();
    ray.forward = d.z() > 0;
    ray.valid = true;
    return ray;
  }
  // The plane met i-th along the ray's direction (nearest first for a forward ray).
  int PlaneAt(const Ray& ray, int i) const { return ray.forward ? i : planes_ - 1 - i; }
  // Where the ray meets plane k; false when the plane is not ahead of the camera.
  bool On(const Ray& ray, int k, RaySample* out) const {
    const double w = inverse_depths_[k];
    const double along = 1.0 - origin_.z() * w;  // (z_k - o_z) / z_k: ahead where it has d_z's sign
    if (!ray.valid || (ray.forward ? along <= 0 : along >= 0)) return false;
    const double x = fx_ * (origin_.x() * w + along * ray.rx) + cx_;
    const double y = fy_ * (origin_.y() * w + along * ray.ry) + cy_;
    out->plane = k;
    out->x = static_cast<float>(x);
    out->y = static_cast<float>(y);
    out->inside = x >= -0.5 && y >= -0.5 && x <= width_ - 0.5 && y <= height_ - 0.5;
    return true;
  }
  // Whether the ray reaches the farthest plane inside the volume's image (it is then covered).
  bool ReachesFarPlane(const Ray& ray) const {
    RaySample s;
    return On(ray, planes_ - 1, &s) && s.inside;
  }
  // The planes the ray of pixel coordinates (u, v) (pixel centre at +0.5) meets ahead of the camera,
  // front to back, into `out` (room for volume.Planes()); returns their count.
  int Samples(double u, double v, RaySample* out) const;
  // Where the ray of (u, v) meets plane k; false when the plane is not ahead of the camera.
  bool SampleOn(double u, double v, int k, RaySample* out) const { return On(RayAt(u, v), k, out); }

 private:
  Eigen::Matrix3d direction_from_pixel_;  // R_vc K_c^-1: a pixel's ray direction in the volume's frame
  Eigen::Vector3d origin_;                 // the camera centre in the volume's frame
  std::vector<double> inverse_depths_;
  double fx_, fy_, cx_, cy_;
  int width_, height_, planes_;
};

// The bilinear footprint of index coordinates (x, y) in a plane of width x height cells, clamped
// to the plane: four cell offsets (in floats, 4 per cell) and their weights. The fitting's gradient
// scatters through the same footprint, so that it is the exact adjoint of the read.
struct CellFootprint {
  size_t offset[4];
  float weight[4];
};
inline CellFootprint Footprint(int width, int height, float x, float y) {
  x = std::min(std::max(x, 0.f), static_cast<float>(width - 1));
  y = std::min(std::max(y, 0.f), static_cast<float>(height - 1));
  const int x0 = std::max(0, std::min(static_cast<int>(x), width - 2));
  const int y0 = std::max(0, std::min(static_cast<int>(y), height - 2));
  const int x1 = std::min(x0 + 1, width - 1), y1 = std::min(y0 + 1, height - 1);
  const float fx = x - x0, fy = y - y0;
  CellFootprint f;
  f.offset[0] = (static_cast<size_t>(y0) * width + x0) * 4;
  f.offset[1] = (static_cast<size_t>(y0) * width + x1) * 4;
  f.offset[2] = (static_cast<size_t>(y1) * width + x0) * 4;
  f.offset[3] = (static_cast<size_t>(y1) * width + x1) * 4;
  f.weight[0] = (1 - fx) * (1 - fy);
  f.weight[1] = fx * (1 - fy);
  f.weight[2] = (1 - fx) * fy;
  f.weight[3] = fx * fy;
  return f;
}
// Bilinear read of a plane's 4 channels through a footprint (a cell's 4 floats are one SSE
// vector: cells start 16-byte aligned in a PlaneVolume's storage).
inline void SampleCell(const float* plane, const CellFootprint& f, float out[4]) {
#if defined(__SSE2__)
  __m128 sum = _mm_mul_ps(_mm_set1_ps(f.weight[0]), _mm_loadu_ps(plane + f.offset[0]));
  sum = _mm_add_ps(sum, _mm_mul_ps(_mm_set1_ps(f.weight[1]), _mm_loadu_ps(plane + f.offset[1])));
  sum = _mm_add_ps(sum, _mm_mul_ps(_mm_set1_ps(f.weight[2]), _mm_loadu_ps(plane + f.offset[2])));
  sum = _mm_add_ps(sum, _mm_mul_ps(_mm_set1_ps(f.weight[3]), _mm_loadu_ps(plane + f.offset[3])));
  _mm_storeu_ps(out, sum);
#else
  for (int i = 0; i < 4; ++i) {
    out[i] = f.weight[0] * plane[f.offset[0] + i] + f.weight[1] * plane[f.offset[1] + i] +
             f.weight[2] * plane[f.offset[2] + i] + f.weight[3] * plane[f.offset[3] + i];
  }
#endif
}
// The adjoint of SampleCell: adds `value` (4 channels) times each footprint weight to its cell.
inline void ScatterCell(float* plane, const CellFootprint& f, const float value[4]) {
#if defined(__SSE2__)
  const __m128 v = _mm_loadu_ps(value);
  for (int j = 0; j < 4; ++j) {
    float* cell = plane + f.offset[j];
    _mm_storeu_ps(cell, _mm_add_ps(_mm_loadu_ps(cell), _mm_mul_ps(_mm_set1_ps(f.weight[j]), v)));
  }
#else
  for (int j = 0; j < 4; ++j) {
    for (int ch = 0; ch < 4; ++ch) plane[f.offset[j] + ch] += f.weight[j] * value[ch];
  }
#endif
}

// The volume drawn into a camera (rows in parallel): colour CV_32FC3 (B, G, R in [0, 1]) and
// coverage CV_8UC1 (255 where the ray reaches the farthest plane inside the volume's image).
// Pixels not covered hold whatever the planes they met add up to (black where none).
void CompositePlaneVolume(const PlaneVolume& volume, const Camera& camera, const Rigid3d& cam_from_world,
                          cv::Mat* colour, cv::Mat* coverage);

// The planes as 8-bit BGRA images (straight colour, as on disk), for CompositePlaneVolumeByWarps.
std::vector<cv::Mat> PlaneImages(const PlaneVolume& volume);
// The same composite drawn plane by plane: each 8-bit plane warped into the camera by its
// homography (OpenCV's warpPerspective, bilinear, transparent outside the plane) and composited
// over the ones behind it, far to near; coverage 255 where the warped farthest plane's opacity is
// at least half. Several times faster than the per-ray composite for a whole frame (the warps are
// vectorised; no early stop at an opaque plane, which costs less than the per-ray arithmetic).
// Needs every ray of the camera to meet every plane ahead of it (the camera in front of the
// nearest plane, looking toward the planes: a forward-facing capture's views); returns false and
// draws nothing otherwise (then CompositePlaneVolume draws it). Differs from CompositePlaneVolume
// only within half a volume pixel of the volume's border, which it fades out instead of clamping.
bool CompositePlaneVolumeByWarps(const PlaneVolume& volume, const std::vector<cv::Mat>& planes, const Camera& camera,
                                 const Rigid3d& cam_from_world, cv::Mat* colour, cv::Mat* coverage);

// Writes volume.json and the planes into `folder` (created), each file atomically.
void WritePlaneVolume(const std::string& folder, const PlaneVolume& volume);
// Reads a folder written by WritePlaneVolume. Throws InputError (missing folder or file) or IoError
// (a malformed volume.json or plane) naming the file and what is wrong.
PlaneVolume ReadPlaneVolume(const std::string& folder);

}  // namespace ibmr
