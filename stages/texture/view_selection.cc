// Face adjacency and MRF view selection by iterated conditional modes (see view_selection.h).
#include "stages/texture/view_selection.h"

#include <algorithm>
#include <unordered_map>

namespace ibmr {

std::vector<std::array<int, 3>> FaceAdjacency(const TriangleMesh& mesh) {
  std::vector<std::array<int, 3>> adjacency(mesh.faces.size(), {-1, -1, -1});
  // Undirected edge -> (face, edge slot) of its first face; a second face links both. Edges with
  // more than two faces (non-manifold) link the first two.
  std::unordered_map<uint64_t, std::pair<int, int>> first;
  first.reserve(mesh.faces.size() * 2);
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = static_cast<uint32_t>(mesh.faces[f][e]), b = static_cast<uint32_t>(mesh.faces[f][(e + 1) % 3]);
      const uint64_t key = (static_cast<uint64_t>(std::min(a, b)) << 32) | std::max(a, b);
      const auto [it, inserted] = first.emplace(key, std::make_pair(static_cast<int>(f), e));
      if (inserted) continue;
      const auto [g, ge] = it->second;
      if (g >= 0 && adjacency[g][ge] < 0 && g != static_cast<int>(f)) {
        adjacency[g][ge] = static_cast<int>(f);
        adjacency[f][e] = g;
        it->second = {-1, -1};  // taken
      }
    }
  }
  return adjacency;
}

namespace {

double MaxQuality(const FaceObservations& observations) {
  double best = 0;
  for (const auto& list : observations) {
    for (const FaceObservation& o : list) best = std::max(best, static_cast<double>(o.quality));
  }
  return best > 0 ? best : 1.0;
}

}  // namespace

double SelectionEnergy(const FaceObservations& observations, const std::vector<std::array<int, 3>>& adjacency,
                       const std::vector<int>& labels, double smoothness) {
  const double scale = 1.0 / MaxQuality(observations);
  double energy = 0;
  for (size_t f = 0; f < labels.size(); ++f) {
    if (labels[f] < 0) continue;
    for (const FaceObservation& o : observations[f]) {
      if (o.view == labels[f]) energy -= o.quality * scale;
    }
    for (int g : adjacency[f]) {
      // Each adjacent pair once (from its smaller index); unseen faces take no part.
      if (g > static_cast<int>(f) && labels[g] >= 0 && labels[g] != labels[f]) energy += smoothness;
    }
  }
  return energy;
}

ViewSelection SelectViews(const FaceObservations& observations, const std::vector<std::array<int, 3>>& adjacency,
                          double smoothness, int max_iterations) {
  const double scale = 1.0 / MaxQuality(observations);
  ViewSelection selection;
  selection.labels.assign(observations.size(), -1);
  for (size_t f = 0; f < observations.size(); ++f) {
    float best = -1;
    for (const FaceObservation& o : observations[f]) {
      if (o.quality > best) best = o.quality, selection.labels[f] = o.view;
    }
  }
  selection.energies.push_back(SelectionEnergy(observations, adjacency, selection.labels, smoothness));
  for (int iteration = 0; iteration < max_iterations && smoothness > 0; ++iteration) {
    size_t changed = 0;
    for (size_t f = 0; f < observations.size(); ++f) {
      if (observations[f].size() < 2) continue;
      int best_label = selection.labels[f];
      double best_cost = 0;
      bool first = true;
      for (const FaceObservation& o : observations[f]) {
        double cost = -o.quality * scale;
        for (int g : adjacency[f]) {
          if (g >= 0 && selection.labels[g] >= 0 && selection.labels[g] != o.view) cost += smoothness;
        }
        // Ties keep the current label, so a sweep never cycles.
        if (first || cost < best_cost - 1e-12 || (std::abs(cost - best_cost) <= 1e-12 && o.view == selection.labels[f])) {
          best_cost = cost;
          best_label = o.view;
          first = false;
        }
      }
      if (best_label != selection.labels[f]) {
        selection.labels[f] = best_label;
        ++changed;
      }
    }
    selection.energies.push_back(SelectionEnergy(observations, adjacency, selection.labels, smoothness));
    if (changed == 0) break;
  }
  return selection;
}

}  // namespace ibmr
