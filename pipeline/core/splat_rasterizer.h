// Drawing oriented elliptical splats (gaussian_splats.h) into a pinhole camera, and the gradient of
// a loss on the drawn image with respect to every splat parameter: the renderer the splat fit
// adjusts the splats with and the splat_fit render model draws them with.
//
// Footprint (seed 004 §5.4: each sample drawn as an elliptical splat whose shape follows the
// surface's orientation; Huang et al., "2D Gaussian Splatting", SIGGRAPH 2024, §4.2): a disc is
// evaluated exactly where the pixel's ray meets its plane, not by an affine approximation of the
// projection. With H = [s_u t_u, s_v t_v, mu] in camera coordinates (the disc's scaled axes and
// centre) and M = K H, a pixel x~ = (x, y, 1) sees the disc point (u, v) with (u, v, 1) / z = M^-1 x~,
// z the depth of that point along the optical axis: a well-defined depth per splat and pixel. The
// falloff is G = exp(-(u^2 + v^2) / 2), with 2DGS's screen-space floor max(G, exp(-|x - c|^2 /
// (2 sigma^2))), c the projected centre, so that a disc seen edge-on still covers a pixel. The disc
// reaches as far as the circle u^2 + v^2 < R^2 of its plane, R^2 = SplatCutoffSquared (3 sigmas, or
// less where exp(-R^2 / 2) < min_alpha could not be drawn at any opacity), the floor as far as
// |x - c| < sigma R; the footprint box is the box of the circle's image (a conic: the box is exact,
// where the 3-sigma square's projected corners give up to twice the area for a disc turned on
// screen) joined with the floor's.
//
// Compositing (seed 000 §3, lines 5526-5610, the over operator; Kerbl et al., "3D Gaussian
// Splatting", SIGGRAPH 2023, §6): the image is cut in 16x16-pixel tiles; per tile, the splats
// whose footprint touches it, sorted front to back by their centres' depth, are composited
// with alpha_i = min(0.99, opacity_i G_i) (alphas below min_alpha, 1/255, skipped) until the transmittance
// falls below 1e-4. The backward pass walks the same lists in reverse, recovering each
// transmittance by division, and accumulates per splat the gradients of M^-1, of its projected
// centre, its colour and its opacity; those are then carried to the position, rotation, radii,
// opacity logit and SH coefficients analytically.
//
// The view direction a splat's SH colour is evaluated at is held fixed when differentiating (its
// gradient with respect to the position is left out, as its effect on the position is of second
// order against the footprint's). Splats whose centre lies behind `near`, or whose disc reaches
// behind the camera, are not drawn in that view.
//
// Falloffs below exp(-87) (1.6e-38, where floats turn denormal) count as 0.
//
// TBB over tiles; per tile, fixed arrays of 256 pixels, no allocation per pixel. SIMD over pixels
// (splat_tiles.h): each tile's state is structure-of-arrays (transmittance, colour sums, depth,
// splats walked, a live flag per pixel), and one splat at a time is applied to a whole 16-pixel
// row of it in a vectorised loop (M^-1's rows broadcast, a polynomial exp, selects for the alpha
// threshold, the box and the saturated pixels), compiled for the baseline, AVX2 and AVX-512 and
// picked at run time; the result is the per-pixel definition's up to float rounding.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/gaussian_splats.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

inline constexpr int kSplatTile = 16;

struct SplatCamera {
  int width = 0, height = 0;
  float fx = 1, fy = 1, cx = 0, cy = 0;  // COLMAP convention: pixel (c, r) centred at (c + 0.5, r + 0.5)
  Eigen::Matrix3f rotation = Eigen::Matrix3f::Identity();  // cam_from_world
  Eigen::Vector3f translation = Eigen::Vector3f::Zero();
  Eigen::Vector3f Centre() const { return -rotation.transpose() * translation; }
};

// The pinhole `camera` (PINHOLE or SIMPLE_PINHOLE: no distortion) at `cam_from_world`.
SplatCamera ToSplatCamera(const Camera& camera, const Rigid3d& cam_from_world);

struct SplatRasterOptions {
  Eigen::Vector3f background = Eigen::Vector3f::Zero();  // RGB in [0, 1], behind every splat
  float lowpass_sigma = 0.70710678f;  // pixels, the screen-space floor of the falloff
  float extent_sigmas = 3.0f;         // footprint radius in standard deviations
  float near = 1e-3f;                 // camera depth below which a splat is not drawn
  // Alphas below this are skipped (3DGS's 1/255). 0, with a wide extent_sigmas, makes the image a
  // smooth function of the parameters (the gradient tests): every splat reaches every pixel.
  float min_alpha = 1.0f / 255.0f;
  int sh_degree = -1;                 // SH degree used (<= the splats'); -1: the splats' own
};

// The squared radius R^2 (in standard deviations, in the disc's plane) within which a disc is drawn:
// extent_sigmas^2, or 2 ln(1 / min_alpha) where that is smaller (no opacity draws the falloff past it).
inline float SplatCutoffSquared(const SplatRasterOptions& options) {
  const float extent = options.extent_sigmas * options.extent_sigmas;
  return options.min_alpha > 0 ? std::min(extent, 2.0f * std::log(1.0f / options.min_alpha)) : extent;
}

// Per drawn splat, what the tile loops read (copies of SplatFrame's per-splat values), in one
// cache line: a tile's splats are far apart in memory, and each one read costs a miss.
struct alignas(64) SplatTileRecord {
  float inverse[9];  // M^-1, row-major
  float centre_x, centre_y, opacity;
  float colour[3];   // clamped at 0
  float view_depth;
};
static_assert(sizeof(SplatTileRecord) == 64, "one cache line");

// What a forward pass keeps for the backward pass (and gives the caller).
struct SplatFrame {
  int width = 0, height = 0, tiles_x = 0, tiles_y = 0;
  cv::Mat image;        // CV_32FC3 RGB, the splats over `background`
  cv::Mat transmittance;  // CV_32FC1: the light left after every splat (1 - coverage)
  cv::Mat depth;        // CV_32FC1: depth of the front-most splat with alpha >= 0.5 (0: none)
  std::vector<uint32_t> tile_start;   // tiles + 1 offsets into tile_splats
  std::vector<uint32_t> tile_splats;  // splat indices, front to back per tile
  // Per splat + 1: offsets of its entries in splat-major order, one per tile of its box in
  // row-major order (where the backward pass keeps each tile's sums for it; 0 for hidden splats).
  std::vector<uint32_t> entry_start;
  std::vector<uint32_t> last;         // per pixel: how many of its tile's splats were walked
  // Per splat (valid where visible[i]):
  std::vector<uint8_t> visible;
  std::vector<Eigen::Matrix3f> inverse;  // M^-1
  std::vector<Eigen::Matrix3f> m;        // M = K H
  std::vector<Eigen::Vector2f> centre;   // projected centre, pixels
  std::vector<Eigen::Vector3f> colour;   // RGB after +0.5, before the clamp at 0
  std::vector<float> opacity;            // sigmoid of the logit
  std::vector<float> view_depth;         // centre's depth
  std::vector<Eigen::Vector4i> box;      // pixels the footprint reaches: x0, y0, x1, y1 (inclusive)
  std::vector<SplatTileRecord> tile_record;
  SplatRasterOptions options;
  size_t drawn = 0;  // splats drawn (visible)
};

// Draws `splats` into `camera`. `frame` is reused from call to call (its buffers keep their size).
void RenderSplats(const GaussianSplats& splats, const SplatCamera& camera, const SplatRasterOptions& options,
                  SplatFrame* frame);

// Gradients of a loss with respect to every splat parameter, in the splats' own layout.
struct SplatGradients {
  std::vector<Eigen::Vector3f> position;
  std::vector<Eigen::Vector4f> rotation;
  std::vector<Eigen::Vector2f> log_scale;
  std::vector<float> opacity_logit;
  std::vector<float> sh;
  std::vector<float> screen;  // |d loss / d projected centre| in normalised device coordinates
                              // (3DGS's density statistic; the same at any resolution)
  // The backward pass's per-entry sums and their index, kept from call to call (no allocation per step).
  std::shared_ptr<struct SplatBackwardScratch> scratch;
  void Reset(const GaussianSplats& splats);  // sized to the splats, zero
};

// Adds to `gradients` (sized by Reset) the gradient of a loss whose gradient with respect to the
// drawn image is `d_image` (CV_32FC3 RGB, the frame's size), for the frame `frame` drew.
void BackwardSplats(const GaussianSplats& splats, const SplatCamera& camera, const SplatFrame& frame,
                    const cv::Mat& d_image, SplatGradients* gradients);

}  // namespace ibmr
