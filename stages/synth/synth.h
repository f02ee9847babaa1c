// Synthetic scenes with ground truth: the test data that every later stage is measured against.
// Follows no seed-paper section; it is test-data generation (seed 000 section 6 asks for ground
// truth, which real captures rarely have).
//
// Two scenes, both seeded and deterministic:
//  * kObjectRing: one closed, star-shaped object (a subdivided icosphere whose radius varies with
//    direction: a few strong bumps and dents, so that its visual hull differs from it) seen by a
//    ring of cameras looking at its centre, in front of a plain dark background (for silhouettes).
//  * kRoom: a closed box room (floor, ceiling, four walls) holding a pillar, two star-shaped
//    objects and a box at different depths, seen by forward-facing cameras on a short horizontal
//    line (like an LLFF capture), all looking at one point: depth variation and occlusions.
//  * kForwardFacing: the room with thin occluders (two poles and a rail, 3-6 cm) in front of
//    everything, seen by a grid of cameras with parallel optical axes (columns x rows, 4:3,
//    `baseline` wide and 3/4 of it high): an LLFF-like capture, for the volume of planes.
//
// Radiance is view-independent (Lambertian, one fixed directional light, ambient term) so that
// photo-consistency holds exactly; albedo is a seeded multi-octave solid value noise of the 3D
// point, so every surface is strongly textured (except the optional textureless room wall).
//
// Conventions: world frame with +z up; cameras in COLMAP's frame (x right, y down, z forward),
// PINHOLE intrinsics, pixel (c, r) centred at (c + 0.5, r + 0.5). Depth is z along the optical axis
// sampled at native pixel centres (0: no surface). Colour is rendered at `supersample` times the
// resolution and box-averaged; the mask is 255 where at least half of a pixel's sub-samples hit a
// foreground part (the object for kObjectRing; the pillar, objects and box for kRoom, not the room's
// walls, floor or ceiling).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/sparse_model.h"
#include "stages/synth/synth_degradations.h"

namespace ibmr {

enum class SynthSceneKind { kObjectRing, kRoom, kForwardFacing };

// "object_ring" -> kObjectRing, "room" -> kRoom, "forward_facing" -> kForwardFacing; false for an
// unknown name.
bool SynthSceneKindFromName(const std::string& name, SynthSceneKind* kind);
std::string SynthSceneKindName(SynthSceneKind kind);

struct SynthOptions {
  SynthSceneKind scene = SynthSceneKind::kObjectRing;
  int views = 24;              // number of cameras, in [2, 10000]
  int width = 320;             // image width in pixels, in [16, 8192]
  int height = 240;            // image height in pixels, in [16, 8192]
  double noise = 0.0;          // Gaussian image noise sigma in 8-bit levels, in [0, 64]
  int64_t seed = 1;            // seeds shape, texture, sparse sampling and noise; >= 0
  int supersample = 2;         // anti-aliasing: sub-samples per pixel side, in [1, 8]
  double fov_deg = -1.0;       // horizontal field of view in degrees, in (1, 150); -1: automatic
                               // (object_ring: the object fills 80% of the shorter side; room: 60)
  double elevation_deg = 20.0; // object_ring: camera height above the equator, degrees, in [-80, 80]
  double ring_radius = 4.0;    // object_ring: camera distance to the object centre, scene units
                               // (object radius ~1), in [2.5, 100]
  double baseline = 1.0;       // room: length of the line the cameras sit on; forward_facing: width
                               // of the camera grid; scene units, in [0, 4]
  bool textureless_wall = false;  // room: the left wall (x = -3) gets a uniform albedo
  int subdivision = 5;         // icosphere subdivision levels of star-shaped objects (20*4^n faces),
                               // in [1, 7]
  int sparse_points = 1000;    // sparse points sampled on the visible surface, in [0, 1000000]
  double texture_frequency = 3.0;  // cycles per scene unit of the coarsest noise octave, in (0, 64]
  SynthDegradation degradation = SynthDegradation::kNone;  // for the stability matrix (synth_degradations.h)
  double strength = 0.0;       // of the degradation, in [0, 1]
  int thin_parts = 0;          // object_ring: thin blades standing out of the object (fine structure
                               // like a model's antennae or a plant's leaves: 3 cm wide at the root
                               // tapering to 7.5 mm, 6 mm thick, 0.25-0.6 long), in [0, 200]

  // Returns false and sets `error` (starting with the YAML key) when a value is out of range.
  bool Check(std::string* error) const;
};

// A star-shaped solid: the points c + s * t * u with |u| = 1 and 0 <= t < Radius(u), where
// Radius(u) = 1 + sum_k amplitude_k * exp((u . direction_k - 1) / width_k^2) (> 0 everywhere).
// Positive amplitudes are bumps, negative ones dents (concavities a visual hull cannot see).
struct StarShape {
  struct Lobe {
    Eigen::Vector3d direction = Eigen::Vector3d::UnitX();  // unit
    double amplitude = 0.0;  // relative radius change at the lobe centre
    double width = 0.5;      // angular width (radians, roughly)
  };
  Eigen::Vector3d center = Eigen::Vector3d::Zero();
  double scale = 1.0;  // scene units per unit radius
  std::vector<Lobe> lobes;

  // Unit-free radius along unit direction `u`.
  double Radius(const Eigen::Vector3d& u) const;
  // Analytic inside test of the smooth surface (the mesh is inscribed: its vertices lie on it).
  bool Inside(const Eigen::Vector3d& point) const;
};

// One surface part of the scene (the object, a wall, a box...), with its own texture tint.
struct SynthPart {
  std::string name;
  bool foreground = false;   // counted in masks
  bool smooth = false;       // shade with interpolated vertex normals (else the face normal)
  bool textured = true;      // false: uniform albedo (the textureless wall)
  Eigen::Vector3d tint = Eigen::Vector3d::Ones();  // RGB albedo multiplier in (0, 1]
};

// Everything needed to render and to describe the scene.
struct SynthScene {
  SynthSceneKind kind = SynthSceneKind::kObjectRing;
  TriangleMesh mesh;              // all parts; per-vertex normals and colours (the radiance)
  std::vector<int> face_part;     // per face: index into `parts`
  std::vector<SynthPart> parts;
  std::vector<StarShape> shapes;  // analytic description of the star-shaped parts
  Camera camera;                  // PINHOLE, shared by all views (camera_id 1)
  std::vector<Image> views;       // image_id 1..N, names "view_000.png"..., cam_from_world
  Eigen::Vector3d light_direction = Eigen::Vector3d::UnitZ();  // unit, towards the light
  double ambient = 0.4;           // radiance = albedo * (ambient + (1 - ambient) * max(0, n.l))
  Eigen::Vector3d background = Eigen::Vector3d::Zero();  // RGB in [0, 1] where nothing is hit
  Eigen::AlignedBox3d foreground_bounds;  // axis-aligned box of the foreground parts' vertices
  Eigen::AlignedBox3d scene_bounds;       // of the whole mesh
  uint64_t texture_seed = 0;
  double texture_frequency = 3.0;
  Degradation degradation;        // none unless the options ask for one
};

// Builds geometry, cameras and per-vertex radiance for the options' scene. Deterministic.
SynthScene BuildSynthScene(const SynthOptions& options);

// View-independent radiance (RGB in [0, 1]) of part `part` at world point `point` with unit
// shading normal `normal` (world frame).
Eigen::Vector3d SurfaceRadiance(const SynthScene& scene, int part, const Eigen::Vector3d& point,
                                const Eigen::Vector3d& normal);

// One rendered view, in memory.
struct SynthView {
  cv::Mat image;   // CV_8UC3, BGR
  cv::Mat mask;    // CV_8UC1, 255 where >= half of the sub-samples hit a foreground part, else 0
  cv::Mat rgba;    // CV_8UC4 BGRA, the foreground alone as a photo on a transparent background: alpha
                   // the fraction of sub-samples on a foreground part, colour their mean (straight,
                   // not premultiplied; no image noise), 0 where alpha is 0
  DepthMap depth;  // z depth at native pixel centres, 0 where no surface
  double foreground_fraction = 0.0;  // fraction of mask pixels set
};

// Renders view `view_index` (index into scene.views). Deterministic: the noise of a view depends
// on options.seed and the view index only.
SynthView RenderSynthView(const SynthScene& scene, int view_index, const SynthOptions& options);

// The true cameras and options.sparse_points points sampled uniformly by area on the surface,
// kept when seen (z-buffer test at native resolution, front-facing) in at least two views; each
// observation is the exact projection of the point. Point colour is its radiance, error 0.
SparseModel BuildSynthSparseModel(const SynthScene& scene, const SynthOptions& options,
                                  ProgressReporter* progress = nullptr);

// The contents of ground_truth/scene.json: scene name, options, camera, bounding boxes, ring
// radius, light, the star shapes' analytic parameters, parts and conventions.
nlohmann::json SynthSceneJson(const SynthScene& scene, const SynthOptions& options);

}  // namespace ibmr
