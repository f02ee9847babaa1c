// Volumetric stereo with transparency (seed 000 section 3, lines 5526-5610; Szeliski & Golland,
// "Stereo matching with transparency and matting", ICCV 1998): an (x, y, d) volume of colours and
// real-valued opacities in a virtual camera (generalized disparity space, lines 5314-5345; a
// multiplane image in the view-synthesis field's words), fitted to the training photos.
//
//  * The virtual camera (virtual_camera.cc): the training views' mean pose, or a chosen training
//    view's, its image widened so that the volume covers every training view's frustum between
//    the near and far depth; D planes equally spaced in inverse depth between them.
//  * Phase 1, initialisation (volume_init.cc; lines 5548-5557, 5576-5596 and the slides at
//    3700-3780): a plane sweep from the virtual camera. Per cell (x, y, d) the training views'
//    samples give a mean colour and a variance (the "composite (mosaic) image" and the "error
//    image" of the slides), aggregated over a box window; the cost curve of each (x, y) votes for
//    its planes (soft: exp(-(cost - min) / temperature); 0: the winner alone), the votes become
//    opacities whose composite weights they are. Then visibility: each training view's
//    transmittance through the planes in front of a cell (the (x, y, d, k) visibility map) weights
//    that view's sample, and the means, variances and votes are computed again.
//  * Phase 2, refinement (volume_fit.cc; lines 5597-5604): every colour and opacity adjusted to
//    minimise
//        E = 1/N sum_views sum_pixels sum_channels rho(C_view(p) - I_view(p))
//          + smoothness / M sum_planes sum_cells sum_channels (rho_s(dx) + rho_s(dy))
//          + opacity_prior / M sum_cells a (1 - a)
//    (N: the training views' pixels, those outside the volume adding nothing; M: cells per plane; rho(r) = sqrt(r^2 + e^2) - e, a
//    robust "weighted error norm"; rho_s the same with e = 0.01 over RGBA differences of 4-
//    neighbours, the weak smoothness; a (1 - a), the prior that pushes opacities to 0 or 1), with
//    C_view the volume composited into the training camera (plane_volume.h). Analytic gradients of
//    the compositing: with T_k the transmittance in front of plane k and B_k the composite behind
//    it, dC/dc_k = a_k T_k and dC/da_k = T_k (c_k - B_k), scattered through the bilinear reads.
//    The step is Adam (Kingma & Ba 2015), a first-order method with a diagonal preconditioner: the
//    running root mean square of each cell's gradient. The seed says "preconditioned gradient
//    descent"; a fixed step cannot serve both the cells in front, whose gradients carry the whole
//    residual, and those behind them, whose gradients are scaled by the transmittance and smaller by
//    orders of magnitude; Adam's per-cell scale is that preconditioner, kept up to date.
//    `optimizer: gradient_descent` takes plain steps (monotone at a safe step; slow). Coarse to
//    fine: the volume and the photos are fitted at 1/2^(levels-1) of the size first, then each
//    level's volume is upsampled to start the next. The farthest plane is kept opaque (the
//    background: no ray inside the volume leaves it empty). Training views only.
#pragma once

#include <cstddef>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/plane_volume.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

enum class VolumeOptimizer { kAdam, kGradientDescent };

struct VolumeOptions {
  int num_planes = 32;            // D, planes equally spaced in inverse depth, in [2, 256]
  double resolution = 1.0;        // volume pixels per training pixel (focal length scale), in (0, 4]
  double max_widen = 1.5;         // the volume's image at most this times the training image's width
                                  // and height (its field of view is widened to cover the training
                                  // frusta), in [1, 4]
  // Phase 1.
  int window_radius = 2;          // box window of the variance cost, pixels of the coarsest level, [0, 16]
  double vote_temperature = 0.002;  // soft votes exp(-(cost - min) / T), T in colour variance units
                                  // ([0, 1] colours); 0: the winning plane alone is opaque. >= 0
  int visibility_rounds = 1;      // times the votes are recomputed with visibility, [0, 5]
  // Phase 2.
  int levels = 3;                 // pyramid levels, the coarsest at 1/2^(levels-1) of the size, [1, 6]
  int iterations = 100;           // steps at the coarsest level; each finer level takes half as
                                  // many (at least `min_iterations`), [0, 100000]
  int min_iterations = 12;        // steps at least per level, [0, 100000]
  VolumeOptimizer optimizer = VolumeOptimizer::kAdam;
  double learning_rate = 0.05;    // Adam's step (colour and opacity units), or the gradient step, at
                                  // each level's first step, falling geometrically to a tenth by its
                                  // last, > 0
  int views_per_step = 6;         // training views each step's objective sees, in turn (stochastic
                                  // steps); 0: all of them, [0, 10000]
  double robust_epsilon = 0.01;   // e of the data term's rho, colour units, > 0
  double smoothness = 0.002;      // weight of the colour and opacity smoothness, >= 0
  double opacity_prior = 0.001;   // weight of the a (1 - a) prior, >= 0
  double max_memory_mb = 3000;    // refuse a volume whose fitting needs more, MB, > 0

  // False with `error` starting with the YAML key when a value is out of range.
  bool Check(std::string* error) const;
};

// A training view: photo and pinhole camera.
struct VolumeView {
  std::string name;
  Camera camera;            // PINHOLE (undistorted)
  Rigid3d cam_from_world;
  cv::Mat image;            // CV_8UC3, BGR, camera.width x camera.height
};

// The virtual camera with its depth range (the planes' z in it).
struct VirtualCamera {
  Camera camera;            // PINHOLE
  Rigid3d cam_from_world;
  double near = 0, far = 0;
};

// The mean pose of the views (centre: the mean centre; rotation: the mean rotation matrix
// projected back onto the rotations), or view `reference`'s pose (>= 0), with the views' mean
// focal length times `resolution`, and the image widened (principal point moved) to hold every
// view's image corners at depths near and far, at most max_widen times the views' mean size.
// Throws std::invalid_argument for no views or 0 < near < far violated.
VirtualCamera ChooseVirtualCamera(const std::vector<VolumeView>& views, int reference, double near, double far,
                                  const VolumeOptions& options);

// The data term's gradient works through a view in bands of rows whose per-plane samples hold at
// most this many floats (volume_fit.cc); VolumeFitBytes counts them.
inline constexpr size_t kVolumeBandFloats = size_t{1} << 22;

// Bytes the fitting holds at the finest level: the cells, their gradient and Adam's two moments,
// the photos as floats and the gradient bands.
double VolumeFitBytes(const VirtualCamera& virtual_camera, const std::vector<VolumeView>& views,
                      const VolumeOptions& options);

// One point of the optimisation curve: the objective E (and its data term alone) before step
// `iteration` of pyramid level `level` (0: the coarsest), over that step's views; a level's last
// point (iteration = its step count) is over every view.
struct VolumeCurvePoint {
  int level = 0, iteration = 0;
  double objective = 0, data = 0;
};

struct VolumeResult {
  PlaneVolume volume;
  std::vector<VolumeCurvePoint> curve;
  double init_seconds = 0, fit_seconds = 0;
  double initial_data = 0, final_data = 0;  // the data term at the finest level before and after fitting
};

// Phase 1 and phase 2 on the views (at least 2). Throws std::invalid_argument for bad options or
// views that are not pinhole or not of their camera's size.
VolumeResult FitPlaneVolume(const std::vector<VolumeView>& views, const VirtualCamera& virtual_camera,
                            const VolumeOptions& options, ProgressReporter* progress = nullptr);

// --- The parts, for tests ---

// A training view at one pyramid level: camera scaled to the level and the photo as floats.
struct LevelView {
  Camera camera;
  Rigid3d cam_from_world;
  cv::Mat image;  // CV_32FC3, B, G, R in [0, 1]
};
std::vector<LevelView> LevelViews(const std::vector<VolumeView>& views, double scale);

// The planes' depths: D planes equally spaced in 1/z from near (plane 0) to far (plane D-1).
std::vector<double> PlaneDepths(double near, double far, int planes);

// Phase 1 on `volume` (camera, pose and depths set; cells allocated): colours and opacities from
// the views' samples.
void InitializeVolume(const std::vector<LevelView>& views, const VolumeOptions& options, PlaneVolume* volume);

// The objective E of the volume against the views; with `gradient` (resized to the cells) its
// gradient with respect to every cell value. `data` (optional) receives the data term alone;
// `scratch` (optional) is a buffer the caller keeps from one call to the next (no fresh pages).
double VolumeObjective(const PlaneVolume& volume, const std::vector<LevelView>& views, const VolumeOptions& options,
                       std::vector<float>* gradient, double* data = nullptr, std::vector<float>* scratch = nullptr);

// Phase 2 at one level: `iterations` steps from `volume`; appends to `curve`.
void RefineVolume(const std::vector<LevelView>& views, const VolumeOptions& options, int level, int iterations,
                  PlaneVolume* volume, std::vector<VolumeCurvePoint>* curve, ProgressReporter* progress = nullptr);

}  // namespace ibmr
