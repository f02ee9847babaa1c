// Point splatting (Nyland et al., seed 004 section 5.4, lines 222-236; splat sizes as in Shade et
// al., seed 000 lines 11743-12999; McMillan's mesh-versus-splat reconstruction, seed 000 lines
// 7085-8625): every sample of a model is drawn as a screen-space disc in the desired view.
//
// Samples. From depth images (depth_images.h): the drawable pixels, each with its source view. From
// surfels: oriented discs with a world radius (surfels/surfels.ply); discs facing away from the
// desired camera are not drawn.
//
// Splat radius [N 226-228]. The paper scales the composite projection C = P V M by the cube root of
// the determinant of its 3x3 principal submatrix and the viewport's scaling, over the sample's w.
// For a sample of a source with focal length f_s at depth z_s, seen at depth z_d by a desired camera
// of focal length f_d, that is the projected size of the source pixel, (f_d / f_s) * (z_s / z_d):
// the per-source constant f_d / f_s over w = z_d / z_s. Here each sample carries a world radius,
// the footprint: for a depth sample the half diagonal of its source pixel, z_s / f_s / sqrt(2) (the
// smallest disc covering the pixel: a fronto-parallel plane seen at the source resolution has no
// holes, and the discs overlap by pi/2 < 2); for a surfel its own radius.
//
// Footprint shape. The paper's radius (and the LDI's, [S 5.3]) is isotropic: the projected area of
// the warped pixel. Kept as the full differential instead, the footprint is an ellipse: the source
// pixel's disc laid on the sample's tangent plane (its normal; from one-sided differences where the
// normal map has none), projected by the desired camera's Jacobian. Where the desired view sees the
// surface edge-on, at its silhouette, the ellipse is thin across it; an isotropic disc reaches past
// the silhouette by its radius and paints the object's colour on the background (synthetic ring,
// true depth, held out: 30.99 dB with discs, 36.06 dB with ellipses). A surfel is its disc, seen
// obliquely. Samples without a normal stay discs. Where the source sees the surface at a grazing
// angle the footprint stretches along it, at most max_stretch times (a noisy normal would smear the
// sample). The ellipse's axes are scaled by radius_scale and
// bounded to [0.35, max_radius_px] desired pixels: large splats scallop silhouettes [N 228].
//
// Compositing. Each disc has the quadratic depth falloff of the paper's quadratic splat [N 230]:
// z' = z * (1 + depth_tolerance / 2 * (r / R)^2), so the nearest sample wins the z test inside a
// surface. Instead of keeping only the front-most sample, the samples within depth_tolerance * z'
// of the front at a pixel are blended (the "compositing by confidence" of [N 5.3], without the
// alpha blur across surfaces). Which ones, and how much, follows ULR's blending field [U 115-134]
// per pixel: angle = that between a sample's source ray and the desired ray at the sample; the k
// sources with the smallest angles among all the samples drawn at the pixel are kept, chosen before
// the depth test (each source's depth map is one consistent surface, so an outlier of a distant
// view can neither hide nor tint the pixel), and only their samples take part in the z test and
// the blend; threshold = the k-th angle, and a sample weighs
//     confidence * (1 - (r / R)^2) * max(0, 1 - angle / threshold) / max(angle, angle_epsilon),
// so the nearest views dominate and, at a source camera, that source's samples (epipole
// consistency [U 130]). Surfel samples have no source ray: angle 0, one "source".
// Supersampling [N 236]: the caller renders at a multiple of the resolution and box-filters down.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rigid3.h"
#include "stages/render/depth_images.h"

namespace ibmr {

struct SplatOptions {
  double radius_scale = 1.0;        // scales the footprints (pixel half-diagonals, surfel radii), in (0, 8]
  double max_radius_px = 8.0;       // bound on a splat's radius in desired pixels, in [0.5, 256]
  double max_stretch = 2.0;         // bound on a depth footprint's stretch along its tangent plane, in
                                    // multiples of its size facing the source, in [1, 16]: 1/cos of the
                                    // steepest tangent plane trusted. Stereo normals are noisy at grazing
                                    // angles (templeRing held out: 4 -> 25.31 dB, 2 -> 25.42); true ones
                                    // are not (synthetic ring, true depth: 2 -> 34.5 dB, 4 -> 36.1)
  double depth_tolerance = 0.05;    // relative depth band blended at a pixel, in (0, 1); stereo depth is noisy
                                    // at the percent level (templeRing held out: 0.01 -> 24.5 dB, 0.03 -> 25.1,
                                    // 0.06 -> 25.4, 0.1 -> 25.3)
  double angle_epsilon_deg = 0.5;   // smallest angle counted (epipole consistency without a division by 0), in (0, 90]
  int k = 4;                        // sources blended per pixel, ULR's k; 0: every source, weight 1/angle^2, in [0, 8]
  // RenderSplats draws the image in passes over bands of rows, a pass per this many bytes of the
  // cloud's projected samples (48 a sample), so that a view holds that much of them at most, not a
  // projection of every sample (985 MB for the full-size Sceaux castle's 20 M); the image is the
  // same. Not a parameter of the stage; > 0.
  size_t pass_bytes = size_t{384} << 20;

  bool Check(std::string* error) const;  // error starts with the YAML key
};

// Samples as structure of arrays. `source` indexes `source_centers` (-1: no source ray, a surfel).
struct SplatCloud {
  std::vector<Eigen::Vector3f> positions;
  std::vector<Eigen::Vector3f> normals;      // unit, or 0 (unknown: never culled as back-facing)
  std::vector<cv::Vec3b> colors;              // BGR
  std::vector<float> confidence;
  std::vector<float> footprint;               // world radius: z_s / (f_s sqrt 2) for a source pixel, or a surfel's radius
  std::vector<int> source;
  std::vector<Eigen::Vector3f> source_centers;
  std::vector<Eigen::Matrix3f> source_axes;   // per source: world_from_cam (image x, image y, optical axis)

  size_t size() const { return positions.size(); }
};

// The drawable samples of the depth images (normals from the images' normal maps, in world frame).
SplatCloud CloudFromDepthImages(const std::vector<DepthImage>& images);
// The same, freeing each image once its samples are in the cloud (`images` is left empty): the
// full-size Sceaux castle's 9 depth images hold 1.2 GB beside the 20 M samples' 0.8 GB.
SplatCloud CloudFromDepthImages(std::vector<DepthImage>&& images);
// Oriented discs from a surfel cloud (positions, normals, radius; colours and confidence when
// present). Points without a radius get `default_radius`.
SplatCloud CloudFromSurfels(const PointCloud& surfels, float default_radius);

struct SplatImage {
  cv::Mat image;           // CV_8UC3, black where not covered
  cv::Mat coverage;        // CV_8UC1, 255 where some sample was drawn
  DepthMap depth;          // the front-most sample's z per pixel (0 where not covered)
  size_t covered_pixels = 0;
  size_t splats_drawn = 0;  // samples in front of the camera and inside the image
  size_t pixel_hits = 0;    // (sample, pixel) pairs blended: pixel_hits / covered_pixels is the overlap
};

// Draws `cloud` into `camera` (any resolution: pass camera.Scaled(s) to supersample). Bands of rows
// run in parallel (TBB). `exclude_source` >= 0: that source's samples are not drawn (leave-one-out:
// a training view rendered without its own depth and photo).
SplatImage RenderSplats(const SplatCloud& cloud, const Camera& camera, const Rigid3d& cam_from_world,
                        const SplatOptions& options, int exclude_source = -1);

}  // namespace ibmr
