// Unstructured Lumigraph Rendering (Buehler et al., seed 001), evaluated per pixel on the CPU.
//
// Per desired pixel (the per-pixel form of the camera blending field, [U 163] Fig. 7):
//  1. the pixel's ray meets the geometric proxy at p (ProxySurface: a plane or a rasterized mesh);
//  2. every source camera i that sees p (in front, inside its image, and, when the source carries a
//     depth map of the proxy, |z_i(p) - depth_i| < eps * z_i: visibility [U 44-52, 154-161]) gets
//       penalty_i = alpha * angle(C_i - p, D - p)                [U 115-128]
//                 + beta  * max(0, |p - C_i| - |p - D|)          [U 148]
//                 + gamma * fov_i(p)                             [U 154-159]
//     where fov_i is 0 farther than `fov_margin` from the image border and rises smoothly,
//     (m/d - 1)^2, to infinity at the border (d = distance to the border, m the margin);
//  3. the k smallest penalties are kept; thresh = the k-th, capped at max_penalty;
//     w_i = max(0, 1 - penalty_i / thresh) [U 128], optionally times 1 / penalty_i (exact epipole
//     consistency, [U 130]); normalised [U 134];
//  4. colour = sum_i w_i * bilinear(I_i at the projection of p).
// Explicit cases: fewer than k usable cameras -> the missing ones count as penalty max_penalty
// (thresh = max_penalty), so weights stay continuous as cameras leave the field of view or become
// occluded (taking the largest usable penalty instead jumps when one leaves); a zero penalty with
// the 1/penalty variant ->
// the zero-penalty cameras share the weight (the desired ray passes through their centres);
// all kept penalties equal (every w_i = 0) -> uniform weights, never NaN; every kept penalty at or
// above the threshold but not all equal (all beyond max_penalty, e.g. near every source's border)
// -> the smallest-penalty camera(s) share the weight, the limit of the weights as the penalties rise
// to max_penalty (continuous); no usable camera -> the pixel is not covered.
// Plane proxy [U 218, "pond"]: parallel to the desired image plane at the mean inverse depth of the
// sparse points; without sparse points, through the point nearest to all optical axes.
#pragma once

#include "pipeline/core/optical_axes.h"  // PointNearestToAxes, used with the plane proxy

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rasterizer.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

struct RenderOptions {
  int k = 4;                       // cameras in the neighbourhood; the k-th is the threshold [U 214], in [2, 64]
  double alpha = 1.0;              // weight of the angle penalty (radians), >= 0
  double beta = 0.0;               // weight of the resolution penalty (per scene unit), >= 0
  double gamma = 1.0;              // weight of the field-of-view penalty (unitless), >= 0
  bool epipole_consistent = true;  // multiply w_i by 1/penalty_i [U 130]
  double fov_margin = 0.05;        // width of the border band where fov_i rises, fraction of
                                   // min(width, height), in (0, 0.5)
  double max_penalty = 3.14159265358979;  // penalty of a missing camera; caps the threshold, > 0
                                   // (default: the largest angle penalty, pi radians)
  double visibility_epsilon = 0.01;  // relative depth tolerance of the visibility test, in (0, 1)
  // Mesh proxies: uncovered pixels within this many pixels of the mesh's image take the depth of
  // the nearest covered one (ExtendIntoHoles), in the desired view (times the supersampling) and
  // in each source's visibility map; 0 (default): the mesh as rasterized. In [0, 16].
  int proxy_extend_px = 0;

  // False with `error` starting with the YAML key when a value is out of range.
  bool Check(std::string* error) const;
};

// One source photograph with its pinhole camera.
struct SourceView {
  std::string name;
  Camera camera;           // no distortion (PINHOLE / SIMPLE_PINHOLE)
  Rigid3d cam_from_world;
  cv::Mat image;           // CV_8UC3, camera.width x camera.height
  DepthMap proxy_depth;    // the proxy's z depth seen from this camera; empty: no visibility test
};

// Visibility of a point at depth z projecting to (u, v) in a source: every depth-map pixel of the
// bilinear footprint must hold the proxy within eps * z, so a sample never mixes in an occluder or
// the background across a depth edge (the footprint is the 2x2 pixels bilinear sampling reads).
bool VisibleInSource(const DepthMap& depth, double u, double v, double z, double eps);

// The proxy as seen by the desired camera: per pixel the world point of the first hit.
struct ProxySurface {
  int width = 0;
  int height = 0;
  FloatMap points;             // 3 channels: world x, y, z
  std::vector<uint8_t> hit;    // width*height, row-major; 1 where the ray meets the proxy
};

struct Plane {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  // unit
};

// Ray-plane intersections of every pixel centre (hits behind the camera do not count).
ProxySurface PlaneSurface(const Plane& plane, const Camera& camera, const Rigid3d& cam_from_world);
// First hits of a mesh, through the core rasterizer (pixel centres, z-buffer).
ProxySurface MeshSurface(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world);
// The proxy mesh's z depth from a source camera (0 where not covered), for the visibility test.
DepthMap MeshDepth(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world);
// A proxy with fallbacks: each pixel takes the first hit of the first mesh in `layers` that covers
// it (e.g. a surface reconstruction that leaves holes, then the visual hull that encloses it);
// `extend_px` > 0 then extends it into the holes near it (ExtendIntoHoles).
DepthMap MeshDepth(const std::vector<const TriangleMesh*>& layers, const Camera& camera, const Rigid3d& cam_from_world,
                   int extend_px = 0);
// Extends a proxy's depth map into its holes by `radius` pixels: `radius` times, every pixel
// without a depth next to one with a depth (8-neighbourhood) takes the nearest such depth (the
// front-most where several touch it), so a hole pixel gets the depth of a covered pixel at most
// `radius` away and a hole wider than 2 * radius stays open in its middle. A surface meshed from
// particles stops about one particle spacing short of the object's outline and leaves pinholes
// between its pieces; the photographs' colours there are still the object's (or the
// background's, beyond the outline: a point at the edge's depth projects beside the object in the
// sources too). On templeRing (surfel mesh, 2x supersampling) the held-out photo PSNR with holes
// black rises from 25.61 dB (0) to 26.20 (1 px), 26.21 (2), 26.23 (3), 26.39 (5).
void ExtendIntoHoles(DepthMap* depth, int radius);
// The pixel (index y * width + x) whose depth each pixel of `depth` takes in ExtendIntoHoles: its
// own index where it has a depth, a covered pixel at most `radius` away for a hole it reaches, -1
// for a hole it does not.
std::vector<int> HoleSources(const DepthMap& depth, int radius);
// The same hole extension for a mesh drawn with its faces (textured, vdtm): a hole pixel within
// `radius` takes the depth, face and barycentrics of the covered pixel ExtendIntoHoles gives its
// depth from. Returns per pixel 1 where it was a hole and now holds a face; empty when radius is
// 0 (nothing extended).
std::vector<uint8_t> ExtendIntoHoles(RasterResult* raster, int radius);
// The sources with each one's visibility map: the depth of the mesh proxy `layers` (first hits,
// fallbacks where the first misses) extended by `extend_px` into its holes, as ULR sees the proxy.
// Every mesh model tests visibility against these maps. Sources in parallel (TBB).
std::vector<SourceView> WithProxyDepth(const std::vector<SourceView>& sources,
                                       const std::vector<const TriangleMesh*>& layers, int extend_px);
ProxySurface MeshSurface(const std::vector<const TriangleMesh*>& layers, const Camera& camera,
                         const Rigid3d& cam_from_world, int extend_px = 0);

// Plane facing the desired camera (normal = its viewing direction) at 1 / mean(1/z) of the points
// in front of it. Returns false when no point is in front.
bool PlaneAtMeanInverseDepth(const std::vector<Eigen::Vector3d>& points, const Rigid3d& desired_cam_from_world,
                             Plane* plane);

// One source's blending weight at a point (for tests and visualisation).
struct BlendWeight {
  int source = -1;       // index into the sources
  double weight = 0.0;   // normalised
  double penalty = 0.0;  // combined penalty
};

struct RenderResult {
  cv::Mat image;     // CV_8UC3; black where not covered
  cv::Mat coverage;  // CV_8UC1; 255 where covered (proxy hit and at least one camera usable); after
                     // Downsample, the covered fraction of the pixel (alpha, 1-255): `image` is then
                     // premultiplied, the model's colour over black
  size_t covered_pixels = 0;
};

// Box-filters a render made at `factor` times the resolution (Camera::Scaled(factor)) down to
// the desired size, like a camera integrating over its pixel. Sub-samples that miss the proxy
// (`fine_surface.hit` 0) count as black background (anti-aliased silhouettes); sub-samples that
// hit it but that no source sees (holes) are left out of the mean. A pixel is covered when any of its
// other sub-samples is, with its coverage (alpha) the covered fraction of them: a silhouette pixel
// the model covers a quarter of shows a quarter of its colour, as the photograph does, rather than
// nothing. Held out, holes black, against the earlier rule (covered when half of them are): synthetic
// ring textured 35.7 -> 37.9 dB, ULR 30.5 -> 31.2; templeRing's surfel mesh 24.84 -> 24.93.
RenderResult Downsample(const RenderResult& fine, const ProxySurface& fine_surface, int factor);
// Which sub-samples a model drew, for Downsample, where that is its coverage (splats, textured
// meshes: every drawn sub-sample has a colour).
ProxySurface HitsOf(const RenderResult& fine);

// A model's render with its holes filled by a background render of the same view (issue: "a
// background fallback for every renderer"): covered pixels keep the model's colour, uncovered ones
// take the background's where it is covered; pixels the model covers less than half of (alpha below
// 128) count as uncovered here.
RenderResult FillHoles(const RenderResult& model, const RenderResult& background);
// A model's render over a known background colour (a capture composited on white, issue
// "Captures as people download them"): every pixel covered, a partly covered one blended by its
// coverage as the composited photo blends its alpha (the render is premultiplied: colour over
// black), so that the figures over the whole image measure the model, not the background.
RenderResult FillWithColour(const RenderResult& model, const cv::Vec3b& background_bgr);

// The renderer: prepares per-source projection data once, then renders any number of views.
class UlrRenderer {
 public:
  UlrRenderer(const std::vector<SourceView>* sources, const RenderOptions& options);

  // Normalised blending weights at world point p for a desired camera centred at `desired_center`
  // (empty when no source can see p). Allocates: not for the hot loop. `exhaustive`: every source's
  // penalty and visibility computed, the definition the renderer's pruned search must reproduce
  // exactly (see Blend; for tests).
  std::vector<BlendWeight> Weights(const Eigen::Vector3d& p, const Eigen::Vector3d& desired_center,
                                   bool exhaustive = false) const;

  // Renders the desired camera over `surface` (same size as `camera`). Rows run in parallel (TBB,
  // the caller's arena decides the thread count).
  RenderResult Render(const Camera& camera, const Rigid3d& cam_from_world, const ProxySurface& surface) const;

 private:
  struct Prepared {  // per source: projection and sampling constants
    Eigen::Matrix3d rotation;
    Eigen::Vector3d translation, center;
    double fx, fy, cx, cy, margin;
    int width, height;
  };
  struct Candidate {
    double penalty;
    double u, v;  // projection in source pixels (COLMAP convention)
    int source;
    // The penalty's parts, kept until it is needed: depth in the source, the angle's atan2
    // arguments, the resolution and field-of-view terms, and a lower bound of the penalty.
    double z, sin, cos, resolution, fov, lower;
  };
  // Scratch space of one thread for Blend, sized for the sources (allocated once per block of rows).
  struct BlendScratch {
    std::vector<Candidate> candidates, best;
    std::vector<int> heap;
    std::vector<double> weights;
  };
  BlendScratch NewScratch() const;
  // Finds the usable sources' k smallest penalties and turns them into normalised weights: on
  // return the first n entries of scratch->best and scratch->weights; returns n (0: not covered).
  int Blend(const Eigen::Vector3d& p, const Eigen::Vector3d& desired_center, BlendScratch* scratch,
            bool exhaustive = false) const;
  double Penalty(const Candidate& c) const;

  const std::vector<SourceView>* sources_;
  RenderOptions options_;
  std::vector<Prepared> prepared_;
  bool prunable_ = true;  // the penalty's weights are >= 0, which the pruned search's bound needs
};

}  // namespace ibmr
