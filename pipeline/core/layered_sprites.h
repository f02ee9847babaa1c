// Layered sprites with depth: the representation of seed 000 section 4 (lines 5625-5811, Baker,
// Szeliski & Anandan, CVPR 1998) that the layered_stereo stage writes and the `layers` renderer
// reads, and the compositing both use (the stage to predict held-out views when it chooses the
// layer count, the renderer to draw desired views).
//
// A reference view's layers: each is a world plane n.X = d, a sprite in the reference view's pixel
// grid (colour with per-pixel alpha) and a per-pixel residual depth off the plane (the relief of
// "cutouts with relief", seed 000 line 5940). The residual here is along the reference ray, in z:
// a sprite pixel's point has the reference camera depth z_plane(pixel) + residual(pixel). Drawing a
// sprite with depth in another view follows seed 000 lines 12080-12355 (plane plus parallax): each
// sprite pixel is a vertex at its depth, neighbouring pixels make triangles (not across depth
// steps), and the triangles are rasterized into the desired view; the layers are then composited
// per pixel back to front by their depth in that view (McMillan's occlusion-compatible order, seed
// 000 lines 12421-12438), with the "over" operator on premultiplied colour.
//
// On disk, `layers/<image>/`:
//   layers.json             {"image", "width", "height" (the sprites' size), "camera" (PINHOLE
//                            fx fy cx cy at that size), "cam_from_world" {"qvec" wxyz, "tvec"},
//                            "layers": [{"normal", "offset", "sprite", "residual", "pixels"}],
//                            plus what the stage records (the layer-count curve)}; layers are
//                            listed back to front as the reference view sees them
//   layer_<k>.png           RGBA sprite, straight (not premultiplied) alpha; 255 on the layer's
//                            own pixels (and where it extends under nearer layers), kSeamAlpha on
//                            the seam it laps over its neighbours' pixels
//   layer_<k>.residual.bin  residual depth, COLMAP array (1 channel, float)
//   depth.bin               the front-most layer's depth per pixel (COLMAP array; 0: none), which
//                            multi_depth and fuse read like a plane-sweep depth map
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rasterizer.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

struct SpriteLayer {
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit, world
  double offset = 0;                                  // the plane n.X = offset
  cv::Mat rgba;      // CV_8UC4 (B, G, R, alpha), the reference view's size; alpha 0: not in the layer
  cv::Mat residual;  // CV_32F, depth offset along the reference ray (z units); empty: all 0
};

struct LayerSet {
  std::string image;      // the reference view's image name
  Camera camera;          // pinhole, the sprites' size
  Rigid3d cam_from_world;
  std::vector<SpriteLayer> layers;  // back to front from the reference view
  nlohmann::json facts = nlohmann::json::object();  // extra keys for layers.json

  // Depth z of layer `k` at reference pixel (x + 0.5, y + 0.5), residual included; 0 when the
  // plane is behind the camera or parallel to the ray.
  double Depth(size_t k, int x, int y) const;
  // z of the plane alone along the pixel centre's ray (no residual); 0 as above.
  double PlaneDepth(size_t k, double px, double py) const;
};

// An RGBA image with premultiplied colour, floats in [0, 1] (alpha) and [0, 255] (colour).
struct RgbaImage {
  cv::Mat color;  // CV_32FC3, premultiplied
  cv::Mat alpha;  // CV_32F in [0, 1]
};

// One layer drawn in a window of rows of a view, only where it covers a pixel (row by row, left
// to right): the columns, premultiplied colour and alpha, and depth of its covered pixels, the
// window's row y's at [row_start[y], row_start[y + 1]). A layer covers part of a view (the castle's sets cover each
// pixel 1.3-1.8 times over 3-6 layers): 24 bytes a covered pixel, where an image per layer would
// take 20 bytes a pixel of the view for every layer (the full-size castle's render peaked at
// 4.8 GB with those).
struct LayerFragments {
  std::vector<size_t> row_start;
  std::vector<int> column;
  std::vector<Eigen::Vector4f> rgba;
  std::vector<float> depth;
};

// The raster CompositeLayers draws a layer into: a window of rows of this many bytes (kRasterBytesPerPixel a pixel),
// not the whole view (480 MB for the full-size Sceaux castle supersampled twice).
constexpr int64_t kCompositeWindowBytes = int64_t{64} << 20;

// CompositeLayers' working memory: each layer's drawing (LayerFragments, a window of rows
// each), the raster of a window of rows (kCompositeWindowBytes) and a layer's mesh (about 36
// bytes a sprite pixel). A caller that composites many sets
// (the layer count's held-out predictions: a few dozen a view) keeps one, so that these buffers
// are allocated and first touched once instead of every time (page faults were a quarter of
// layered_stereo's time).
struct CompositeScratch {
  int64_t window_bytes = kCompositeWindowBytes;  // the raster's size, at least 16 rows
  TriangleMesh mesh;
  std::vector<Eigen::Vector4f> rgba;
  std::vector<int> index;
  std::vector<float> vertex_depth;
  RasterResult raster;
  std::vector<LayerFragments> drawn;
};

// Relative depth step between neighbouring sprite pixels beyond which no triangle joins them.
constexpr double kLayerMaxDepthStep = 0.05;

// Draws every layer of `set` in the view (camera, cam_from_world) and composites them per pixel
// back to front by their depth there. `max_depth_step` (relative) stops triangles between sprite
// pixels whose depths differ by more than that fraction. Returns premultiplied colour and alpha.
// `scratch` (optional): working memory kept by a caller that composites many times.
RgbaImage CompositeLayers(const LayerSet& set, const Camera& camera, const Rigid3d& cam_from_world,
                          double max_depth_step = kLayerMaxDepthStep, CompositeScratch* scratch = nullptr);

// CompositeLayers without the image: each composited row (premultiplied colour and alpha, `width`
// pixels) goes to `row` as soon as it is done, from several threads at once (each row once), for a
// caller that blends it into buffers of its own (16 bytes a pixel less).
using CompositedRow = std::function<void(int y, const cv::Vec3f* color, const float* alpha)>;
void CompositeLayerRows(const LayerSet& set, const Camera& camera, const Rigid3d& cam_from_world, double max_depth_step,
                        CompositeScratch* scratch, const CompositedRow& row);

// The alpha of a sprite's seam: the pixels of other layers next to its own, which it covers so
// that a novel view that pulls the layers apart shows no crack. Drawn as opaque as the rest (to
// within 1/255), but not the layer's surface there: the combined depth map prefers a layer that
// owns the pixel.
constexpr uint8_t kSeamAlpha = 254;

// Per pixel, the front-most layer's depth among those with alpha 255 there (its own pixels, or
// extended under nearer ones), else among those with alpha at least 0.5 (a seam), 0 where none:
// the combined depth map (CV_32F). Seams do not push a nearer surface out over a farther one by a
// pixel. `front` (optional): that layer's index per pixel (CV_32S, -1: none).
cv::Mat CombinedDepth(const LayerSet& set, cv::Mat* front = nullptr);

// layers/<image>/ as documented above (files written atomically). Read throws InputError naming
// the file and what is wrong.
void WriteLayerSet(const std::string& folder, const LayerSet& set);
LayerSet ReadLayerSet(const std::string& folder);

}  // namespace ibmr
