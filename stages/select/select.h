// Model selection by held-out prediction: of every model a run rendered, the smallest whose
// held-out error is within a tolerance of the best one's ("this much model is enough").
//
// Szeliski's BMVC'99 layered representations (seed 000 lines 5906-5950) choose the number of
// layers by how well the representation predicts held-out views, not by how well it fits the
// views it was built from: a richer model always fits its inputs better, and only prediction
// error says when the extra detail stops paying. Here the candidates are whatever the render
// stage drew (the plane, hulls, meshes decimated to several sizes, depth splats at several
// densities, ...), their size is the bytes render reports for each, and the error is a held-out
// PSNR that counts holes (by default photo_psnr: missing pixels are black inside the photo's
// lit area), so a model cannot win by drawing less. The choice is the smallest model within
// `tolerance_db` of the best mean; the size-error curve's lower envelope is kept for the chart.
#pragma once

#include <string>
#include <vector>

namespace ibmr {

struct ModelCandidate {
  std::string name;
  std::string kind;     // plane, mesh, surfels, depth_samples, ...
  double bytes = 0;     // model size
  double elements = 0;  // triangles or samples (1 for the plane)
  double psnr = 0;      // held-out mean of the chosen metric, dB
  double coverage = 0;  // held-out mean coverage
};

struct SelectionOptions {
  std::string metric = "photo_psnr";  // a held-out mean of scores/heldout.json
  double tolerance_db = 0.5;          // "within this of the best", in [0, 20]

  bool Check(std::string* error) const;  // error starts with the YAML key
};

struct Selection {
  std::vector<ModelCandidate> by_size;  // every candidate, smallest first (ties: higher PSNR first)
  std::vector<size_t> envelope;         // indices into by_size: each strictly better than all smaller ones
  size_t best = 0;                      // index of the highest PSNR
  size_t chosen = 0;                    // index of the smallest within tolerance of the best
  double gap_db = 0;                    // best PSNR - chosen PSNR (<= tolerance)
};

// Throws std::invalid_argument when `candidates` is empty.
Selection SelectModel(std::vector<ModelCandidate> candidates, const SelectionOptions& options);

}  // namespace ibmr
