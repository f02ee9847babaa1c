// A small triangle rasterizer for visibility and rendering: z-buffer, pixel-centre sampling
// (COLMAP convention: pixel (c, r) is sampled at (c + 0.5, r + 0.5)), and perspective-correct
// interpolation of per-vertex attributes. Pinhole only: distortion is removed beforehand
// (Camera::Undistorted). Triangles are clipped against the near plane.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

struct RasterizeOptions {
  double near_z = 1e-3;  // scene units; geometry closer than this is clipped
  bool cull_backfaces = false;  // drop faces whose vertices appear clockwise in the image
  // Bands of rows drawn in parallel, the same image to the bit; 0: four a thread for a mesh of
  // 4096 faces or more (else one), 1: one pass.
  int row_bands = 0;
};

struct RasterResult {
  DepthMap depth;              // z along the optical axis; 0 where no triangle covers the pixel
  std::vector<int> face_id;    // width*height, row-major; -1 where uncovered
  FloatMap barycentric;        // 3 channels: perspective-correct weights of the face's vertices
};
// A RasterResult's bytes a pixel: depth, face id and three weights.
constexpr int64_t kRasterBytesPerPixel = sizeof(float) + sizeof(int) + 3 * sizeof(float);

// Rasterizes `mesh` seen by `camera` (intrinsics; distortion ignored) at pose `cam_from_world`.
RasterResult Rasterize(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
                       const RasterizeOptions& options = RasterizeOptions());
// The same into `out`, whose buffers are reused when they hold enough (a caller drawing many
// meshes saves their allocation and first touches).
void Rasterize(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
               const RasterizeOptions& options, RasterResult* out);

// The image's rows a window at a time: rows [first_row, first_row + window_rows) (fewer in the
// last window) into `window` (depth.height: the window's rows; its row r - first_row holds the
// image's row r), handed to `visit` before the next window is drawn, in order of first_row. Each
// pixel gets the values Rasterize gives it, to the bit (the faces meet each pixel in the mesh's
// order); the vertices are transformed once. For a caller that reduces each window as it comes (a
// layer's covered pixels) and so never holds the whole image's raster: 20 bytes a pixel, 480 MB
// at 5664 x 4256. `window_rows` >= 1 (InputError otherwise); the image's height: one window.
using RasterWindowVisitor = std::function<void(int first_row, const RasterResult& window)>;
void RasterizeWindows(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
                      const RasterizeOptions& options, int window_rows, RasterResult* window,
                      const RasterWindowVisitor& visit);

// Perspective-correct interpolation of a per-vertex attribute at a covered pixel (x, y) of the
// raster (a window's own rows: its row y is the image's row first_row + y).
template <typename T>
T InterpolateAttribute(const RasterResult& raster, const TriangleMesh& mesh, const std::vector<T>& attribute,
                       int x, int y) {
  const int f = raster.face_id[static_cast<size_t>(y) * raster.depth.width + x];
  const Eigen::Vector3i& face = mesh.faces[f];
  return attribute[face[0]] * raster.barycentric.At(x, y, 0) + attribute[face[1]] * raster.barycentric.At(x, y, 1) +
         attribute[face[2]] * raster.barycentric.At(x, y, 2);
}

}  // namespace ibmr
