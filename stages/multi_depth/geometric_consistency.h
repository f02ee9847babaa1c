// Multi-view geometric consistency of a depth sample: how well the neighbours' depth maps agree
// with it where it reprojects into them (the multi-view extension of the left-right consistency
// of Hu & Mordohai, "A quantitative evaluation of confidence measures for stereo vision", PAMI
// 2012, section 2.6; the per-view residuals are the depth disagreements whose spread seed 000
// section 4, lines 4399-4453, turns into the uncertainty that merging weighs). Each neighbour that
// sees the sample (its depth there is not clearly nearer, which would be an occluder) contributes
// exp(-r^2 / (2 sigma^2)) for the relative depth difference r; the consistency is their mean, in
// [0, 1]. A wrong but photometrically confident match (repetitive texture) lands on different
// surfaces in different views; an error in a camera's pose moves its reprojections off the
// surface the other views measured: both raise r where the photometric confidence cannot see it.
#pragma once

#include <cmath>

namespace ibmr {

class GeometricConsistency {
 public:
  // `sigma`: relative depth difference at which a neighbour's agreement falls to exp(-1/2), > 0.
  explicit GeometricConsistency(float sigma) : inverse_two_sigma_squared_(0.5f / (sigma * sigma)) {}

  // A neighbour that sees the sample, its relative depth difference `relative` = (its depth - the
  // sample's depth in its camera) / the latter.
  // Returns this neighbour's term.
  float Add(float relative) {
    const float term = std::exp(-relative * relative * inverse_two_sigma_squared_);
    agreement_ += term;
    ++seen_;
    return term;
  }

  int seen() const { return seen_; }
  // Mean agreement of the neighbours that saw the sample, in [0, 1]; 1 when none did (nothing
  // contradicts it; the caller's confirmation count decides whether that is enough).
  float Value() const { return seen_ > 0 ? agreement_ / static_cast<float>(seen_) : 1.f; }

 private:
  float inverse_two_sigma_squared_;
  float agreement_ = 0;
  int seen_ = 0;
};

}  // namespace ibmr
