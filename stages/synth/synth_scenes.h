// Geometry and cameras of the synthetic scenes (internal to the synth stage): icosphere-based
// star-shaped solids, welded grid boxes, the object ring and the box room. Test-data generation;
// follows no seed-paper section. Radiance, rendering and I/O are elsewhere (synth.cc).
#pragma once

#include <array>
#include <cstdint>
#include <random>

#include "stages/synth/synth.h"

namespace ibmr {
namespace synth_internal {

// Uniform double in [0, 1) from 53 random bits (portable, unlike std::uniform_real_distribution).
double Uniform01(std::mt19937_64* rng);
// SplitMix64 finaliser: a well-mixed 64-bit hash of `x`.
uint64_t Mix64(uint64_t x);

// A star shape with four bumps and four dents around a randomly rotated, well spread set of
// directions (the vertices of a cube), amplitudes in [0.3, 0.5] (bumps) and [-0.45, -0.35]
// (dents). The radius stays in about [0.55, 1.5] times `scale`.
StarShape RandomStarShape(const Eigen::Vector3d& center, double scale, std::mt19937_64* rng);

// Appends a closed star-shaped mesh: an icosphere with `subdivision` levels (20 * 4^n faces),
// each vertex moved to the shape's surface; faces counter-clockwise seen from outside.
void AppendStarShape(const StarShape& shape, int subdivision, int part, SynthScene* scene);

// Appends a welded box [min, max] split into about `cell` sized grid squares. Faces are
// counter-clockwise seen from outside, or from inside when `inward`. `side_parts` gives the part
// of each side in the order -x, +x, -y, +y, -z, +z.
void AppendBox(const Eigen::Vector3d& min, const Eigen::Vector3d& max, double cell, bool inward,
               const std::array<int, 6>& side_parts, SynthScene* scene);

// Fills parts, shapes, mesh geometry (no normals or colours yet), camera and views.
void BuildObjectRingGeometry(const SynthOptions& options, SynthScene* scene);
void BuildRoomGeometry(const SynthOptions& options, SynthScene* scene);
// The room with thin occluders (two poles, a rail) near the cameras, seen by a grid of cameras
// with parallel axes (forward-facing, like an LLFF capture).
void BuildForwardFacingGeometry(const SynthOptions& options, SynthScene* scene);

// View names "view_000.png", ... with at least three digits (more when views > 1000) so that
// name order is view order.
std::string ViewName(int index, int num_views);

}  // namespace synth_internal
}  // namespace ibmr
