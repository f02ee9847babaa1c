// View selection: one training view per face, as a Markov random field over the face adjacency
// (after Waechter et al., "Let There Be Color!" 2014, §4.1: a data term preferring large, sharp
// projections and a Potts smoothness term preferring neighbours from the same view, which makes
// large patches and few seams). seed 003 §7 keeps every visible view for the view maps; the
// static atlas needs one.
//
// Energy E(l) = sum_f D_f(l_f) + smoothness * #{adjacent (f, g) : l_f != l_g}, with
// D_f(v) = -quality(f, v) / max quality over all faces and views (in [-1, 0]). Faces no view sees
// take the label -1, cost 0, and are not part of the smoothness term.
//
// Solver: iterated conditional modes (Besag 1986). Start from each face's best view; sweep the
// faces in order, giving each the label that minimises its data cost plus the Potts cost with its
// neighbours' current labels. Each change lowers E or leaves it, so E never increases; the
// sweeps stop when nothing changes or after max_iterations. ICM finds a local minimum only
// (alpha-expansion would find a stronger one), but it is simple, needs no graph-cut library, and
// with a start at the best views its patches are the data term's, smoothed.
#pragma once

#include <array>
#include <vector>

#include "pipeline/core/mesh.h"
#include "stages/texture/face_visibility.h"

namespace ibmr {

// Per face, the faces sharing an edge with it (-1: a border edge), in edge order (v0v1, v1v2, v2v0).
std::vector<std::array<int, 3>> FaceAdjacency(const TriangleMesh& mesh);

struct ViewSelection {
  std::vector<int> labels;        // per face: a view, or -1 when no view sees the face
  std::vector<double> energies;   // E before the first sweep and after each sweep
};

double SelectionEnergy(const FaceObservations& observations, const std::vector<std::array<int, 3>>& adjacency,
                       const std::vector<int>& labels, double smoothness);

ViewSelection SelectViews(const FaceObservations& observations, const std::vector<std::array<int, 3>>& adjacency,
                          double smoothness, int max_iterations);

}  // namespace ibmr
