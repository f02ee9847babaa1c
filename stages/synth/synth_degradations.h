// Degradations of the synthetic scenes, each with a strength in [0, 1], for the stability matrix:
// how each method behaves where it fails, and whether its confidence sees it coming. Test-data
// generation (no seed section); strength 0 is the clean scene, 1 a hard case.
//
//   textureless   patches of uniform albedo cover a growing share of the surface (up to all of it)
//   specular      a white Phong highlight (exponent 20) that moves with the viewpoint, up to
//                 as bright as the diffuse light: photo-consistency breaks where it shines
//   repetitive    the texture blends into stripes of one period (a few pixels): false matches
//   few_views     the ring keeps 1 - 0.75 * strength of its views (at least 4)
//   camera_noise  the written cameras (sparse/) are off the ones that rendered the images: rotation
//                 up to 1 degree, position up to 1% of the ring radius, focal up to 2% (sigmas)
//   pose_outliers the written cameras of one view in twelve (indices 3, 15, ...: none of the views
//                 an every-8th holdout takes) are turned by 5 degrees and moved by 2% of the ring
//                 radius, times the strength, about and along random directions: single views
//                 whose poses are wrong, which the per-view flag (view_agreement.h) should name.
//                 (One in six, 4 of the ring's 20 training views, defeats the flag from 2.5 degrees
//                 on: their silhouettes carve the hull wrongly, every view's depth suffers, and the
//                 spread of the good views hides the bad ones.)
//   image_noise   Gaussian noise up to sigma 24 levels, added to `noise`
//   exposure      each view's gain up to +-50% (uniform per view), as an auto-exposing camera
//   hand_held     a hand-held capture's ills together, for the forward-facing scene (whose figures
//                 on the clean scene, parallel axes and exact poses, do not carry over to real
//                 photos): each true camera's axis turned by up to 3 degrees (AxisTurn), the
//                 written cameras off by 0.02 degree and 0.02% of the grid's spread (sigmas, about
//                 0.5 px at 1008 wide; a tenth of a degree, 2.4 px there, held every model near
//                 23 dB), gains within +-15%, a highlight up to half the diffuse light, sensor
//                 noise of sigma 3 levels, and (synth_scenes.cc) a plant of thin blades, 2 cm wide
//                 tapering to 5 mm, in front of the near object; all times the strength. And the
//                 room's back wall gives way to a pale blue sky (synth.cc), where stereo finds
//                 nothing, as beyond an outdoor capture's far bound.
//
// The truth (ground_truth/: mesh, depth, masks) stays the clean scene's (hand_held: its fronds and
// turned cameras included); the true mesh's vertex
// colours carry the albedo changes (textureless, repetitive) but no highlight.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <string>

#include "pipeline/core/sparse_model.h"

namespace ibmr {

enum class SynthDegradation { kNone, kTextureless, kSpecular, kRepetitive, kFewViews, kCameraNoise, kImageNoise, kExposure, kPoseOutliers, kHandHeld };

// "none", "textureless", ... -> the enum; false for an unknown name.
bool SynthDegradationFromName(const std::string& name, SynthDegradation* degradation);
std::string SynthDegradationName(SynthDegradation degradation);
// Every name, for messages: "none, textureless, ...".
std::string SynthDegradationNames();

struct Degradation {
  SynthDegradation kind = SynthDegradation::kNone;
  double strength = 0.0;  // in [0, 1]
  uint64_t seed = 0;

  bool Active(SynthDegradation k) const { return kind == k && strength > 0; }
  // The number of views the ring keeps.
  int Views(int views) const;
  // Albedo variation in [0, 1] per channel after the texture degradations, from the clean one.
  Eigen::Vector3d Variation(const Eigen::Vector3d& clean, const Eigen::Vector3d& point, double frequency) const;
  // Radiance added by the moving highlight (0 unless specular).
  double Highlight(const Eigen::Vector3d& normal, const Eigen::Vector3d& light, const Eigen::Vector3d& to_eye) const;
  // Image gain of view `index`, and the added noise sigma (8-bit levels).
  double Gain(int index) const;
  double NoiseSigma() const;
  // The turn of view `index`'s true camera (hand_held; identity otherwise), applied on the camera's
  // side: cam_from_world's rotation becomes AxisTurn * R.
  Eigen::Matrix3d AxisTurn(int index) const;
  // Moves the cameras of `model` (camera_noise, pose_outliers, hand_held; deterministic).
  void PerturbCameras(SparseModel* model) const;
};

// Per view of `written` (by name), how far its camera is off the one that rendered the photo as
// the photo sees it: the mean distance in pixels between the view's observed sparse points
// projected by the `truth` camera and by the written one (rotation, position and focal errors
// together). Views without observations in front of both cameras get 0.
std::map<std::string, double> PoseDisplacementsPx(const SparseModel& truth, const SparseModel& written);

}  // namespace ibmr
