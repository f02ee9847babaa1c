// Multiple depth maps made mutually consistent (seed 000, Szeliski BMVC'99 section 5 "Multiple
// depth maps", lines 5812-5950, and the "Multi-view representation" slides, lines 3847-3894):
// one depth map per key view; each sample of a key view is projected into its neighbour views,
// where the neighbour's own depth map decides its vote:
//   * visibility v_st (line ~5880): the neighbour's depth at the projection is clearly smaller than
//     the sample's depth in that view -> a nearer surface hides the sample there: no vote;
//   * clearly larger (by more than violation_tolerance) -> the neighbour saw through the sample
//     (a free-space violation): a vote against it;
//   * within a relative tolerance -> depth compatibility (the "controlled depth compatibility"
//     term): a vote for it.
// Samples that fewer than `min_consistent_views` neighbours confirm, or that more neighbours see
// through than max_violation_ratio times those that confirm, are rejected. Kept samples are
// optionally refined to the confidence- (inverse-variance-) weighted mean of the confirming
// depths along the key pixel's ray (the uncertainty-weighted merging of seed 000 section 4,
// lines 4399-4453, in one dimension).
// The output confidence is the geometric mean of the photometric one and the multi-view geometric consistency (the
// neighbours' reprojected depth disagreement, geometric_consistency.h), which falls where matches
// are wrong but photometrically confident (repetitive texture) and where camera poses are off.
// Key pixels left without a depth (missing or rejected, but not dropped for low confidence) are
// filled from the neighbours' depths forward-warped into the key view when other views confirm
// them: the compatibility term lets neighbours inform the key's estimate (line ~5890).
// Per key view the first pass also counts, per neighbour, the samples it sees and confirms
// (NeighborAgreement): the view's agreement with the capture (ViewConfirmedFraction), which the
// stage turns into issue 67's flag of views that stand out (pipeline/core/view_agreement.h).
#pragma once

#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/rigid3.h"
#include "pipeline/core/sparse_model.h"

namespace ibmr {

struct MultiDepthOptions {
  double depth_tolerance = 0.01;     // relative depth difference counted as agreement, in (0, 0.5]
  int min_consistent_views = 2;      // other views that must confirm a sample, in [1, 64]
  double max_violation_ratio = 0.5;  // reject when free-space violations > ratio * confirmations, >= 0
  // A neighbour sees through a sample only when its depth there is farther by more than this
  // (relative; at least depth_tolerance). Between the two tolerances the neighbour neither
  // confirms nor contradicts: two noisy estimates of one surface often differ by a little more
  // than the agreement tolerance, and counting that as free space rejects good samples.
  double violation_tolerance = 0.03;  // in (0, 1]
  double min_confidence = 0.1;       // photometric confidence below this: sample dropped, in [0, 1]
  bool refine_depth = true;          // replace depth by the weighted mean of the confirming depths
  int max_neighbors = 8;             // neighbour views per key view (closest viewing directions), [1, 64]
  double max_view_angle_deg = 80.0;  // neighbour's viewing direction within this of the key's, (0, 180]
  bool fill_from_neighbors = true;   // fill missing / rejected key pixels with a confirmed neighbour depth
  double min_baseline_ratio = 0.05;  // neighbour baseline >= ratio * median baseline of the key, [0, 1)
  // The output confidence's geometric factor (geometric_consistency.h): the mean over the neighbours
  // that see a sample of exp(-r^2 / (2 sigma^2)), r their relative depth disagreement with it
  // (confirming ones included: the spread inside depth_tolerance counts). In [0, 0.5]; 0: off.
  double geometric_sigma = 0.003;
  // A key view's confidence is scaled by min(1, its agreement / this): its agreement is the mean
  // geometric consistency of all its samples some neighbour sees, which falls when its camera is
  // off its neighbours'. In [0, 1]; 0: off.
  double view_agreement_reference = 0.8;  // (clean synthetic ring: views agree by 0.78-0.83;
                                          // with camera_noise 0.5: 0.24-0.38)
  // The output confidence's surface factor (ApplySurfaceFactor): pixels whose depth lies off the
  // plane through the depths of the (2 surface_window + 1)^2 pixels around them are less certain.
  // Image noise makes a view's depths scatter about the surface, which neither its cost curve nor
  // its neighbours' agreement within depth_tolerance ranks; the local plane averages the scatter
  // out. surface_window 3, scale 2 (in medians of the view's residuals), floor 0.5 (the factor's
  // least value: fuse weighs and filters samples by this confidence, and without a floor the
  // clean ring's fused completeness fell 0.856 -> 0.814). Measured on the stability matrix's
  // synthetic ring, stereo depth's confidence-error rho with image noise 0.5 / 0.75 / 1: -0.28 /
  // -0.29 / -0.27 -> -0.42 / -0.43 / -0.40, clean -0.37 -> -0.46; synth_dense.yaml's surfel mesh
  // (accuracy / completeness) 0.00609 / 0.9248 -> 0.00605 / 0.9268.
  int surface_window = 3;             // [0, 15]; 0: off
  double surface_residual_scale = 2.0;  // > 0
  double surface_floor = 0.5;           // [0, 1]

  // False with `error` starting with the YAML key when a value is out of range.
  bool Check(std::string* error) const;
};

// One view's camera and maps, in memory. `normals` (3 channels, camera frame) and `confidence`
// (1 channel in [0, 1]) may be empty: normals are then computed from the depth map and the
// confidence is taken as 1.
struct DepthView {
  std::string name;
  Camera camera;
  Rigid3d cam_from_world;
  DepthMap depth;
  FloatMap normals;
  FloatMap confidence;
};

// How well one neighbour agrees with the key view's samples, over the first pass (the key's own
// samples of usable confidence): issue 67's per-view figure is built from these.
struct NeighborAgreement {
  std::string name;
  size_t seen = 0;             // samples the neighbour sees (its depth there not clearly nearer)
  size_t confirmed = 0;        // of those, within depth_tolerance of the neighbour's depth
  double consistency_sum = 0;  // sum of their geometric consistency terms (geometric_sigma)
};

struct MultiDepthStats {
  size_t input_samples = 0;      // valid key-view depths
  size_t low_confidence = 0;     // dropped for photometric confidence below min_confidence
  size_t unconfirmed = 0;        // fewer than min_consistent_views confirmations
  size_t violated = 0;           // too many free-space violations
  size_t kept = 0;               // own samples kept
  size_t filled = 0;             // pixels filled from a neighbour's confirmed depth
  double view_agreement = 1;     // mean geometric consistency of the samples a neighbour sees (1: none)
  std::vector<NeighborAgreement> neighbors;  // one per neighbour with a depth map, in the given order
};

// The key view's agreement with the capture (issue 67, pipeline/core/view_agreement.h): the median
// over its neighbours that see at least `min_seen` of its samples of the fraction of them the
// neighbour confirms. A median over neighbours, not a pooled fraction, so that one badly posed
// neighbour does not drag down the views around it while a badly posed key, which every neighbour
// contradicts, falls. False (and *fraction untouched) when no neighbour sees enough.
bool ViewConfirmedFraction(const MultiDepthStats& stats, size_t min_seen, double* fraction);

struct MultiDepthResult {
  DepthMap depth;        // 0 where rejected
  FloatMap normals;      // 3 channels, camera frame, unit, facing the camera; 0 where rejected
  // In [0, 1]; 0 where rejected: the geometric mean of the photometric confidence (the mean over
  // the key sample and the views that confirm it, divided by 1 + confirmations + violations) and
  // the geometric consistency of the neighbours that see it (geometric_sigma), times the view's
  // agreement factor (view_agreement_reference).
  FloatMap confidence;
  MultiDepthStats stats;
};

// Neighbour views of `key` among `candidates` (indices into candidates, best first; `key` itself
// is skipped): viewing directions within max_view_angle_deg, a baseline of at least
// min_baseline_ratio times the median distance from the key to the candidates (two photos from one
// position confirm nothing), sorted by angle, at most max_neighbors.
std::vector<int> SelectNeighbors(const Image& key, const std::vector<const Image*>& candidates,
                                 const MultiDepthOptions& options);

// Multiplies `confidence` (the depth map's size) by floor + (1 - floor) exp(-(r / (scale * median
// r))^2 / 2) where `depth` has a depth and at least 6 of the (2 radius + 1)^2 pixels around it do:
// r the pixel's relative distance to the least-squares plane through their inverse depths, the
// median over the map's judged pixels (at least 1e-4). radius 0: unchanged. Pure but for `confidence`.
void ApplySurfaceFactor(const DepthMap& depth, int radius, double scale, double floor, FloatMap* confidence);

// Makes `key`'s depth map consistent with its `neighbors` (their depth and confidence maps are
// read; their normals are not), then applies the surface factor (options.surface_window) to the
// confidence. Pure; thread-safe.
MultiDepthResult MakeDepthConsistent(const DepthView& key, const std::vector<const DepthView*>& neighbors,
                                     const MultiDepthOptions& options);

// Ground-truth comparison on `depth`'s pixel grid (truth sampled at the nearest pixel when the
// resolutions differ): among pixels where the truth is > 0, how many have an estimate and how many
// are within `relative_tolerance` of the truth (missing estimates count as wrong in FractionOfTruth).
struct DepthAccuracy {
  size_t truth_pixels = 0;
  size_t estimated = 0;        // truth > 0 and depth > 0
  size_t within_tolerance = 0;
  double FractionOfTruth() const { return truth_pixels ? double(within_tolerance) / truth_pixels : 0.0; }
  double FractionOfEstimated() const { return estimated ? double(within_tolerance) / estimated : 0.0; }
};
DepthAccuracy CompareDepth(const DepthMap& depth, const DepthMap& truth, double relative_tolerance);

}  // namespace ibmr
