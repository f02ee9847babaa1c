// Smallest model within a tolerance of the best held-out prediction (see select.h).
#include "stages/select/select.h"

#include <algorithm>
#include <stdexcept>

namespace ibmr {

bool SelectionOptions::Check(std::string* error) const {
  if (metric.empty()) {
    *error = "metric: name a held-out mean of scores/heldout.json, e.g. photo_psnr";
    return false;
  }
  if (!(tolerance_db >= 0 && tolerance_db <= 20)) {
    *error = "tolerance_db: must be in [0, 20]";
    return false;
  }
  return true;
}

Selection SelectModel(std::vector<ModelCandidate> candidates, const SelectionOptions& options) {
  if (candidates.empty()) throw std::invalid_argument("no scored model to select from");
  std::stable_sort(candidates.begin(), candidates.end(), [](const ModelCandidate& a, const ModelCandidate& b) {
    return a.bytes != b.bytes ? a.bytes < b.bytes : a.psnr > b.psnr;
  });
  Selection selection;
  selection.by_size = std::move(candidates);
  const auto& models = selection.by_size;
  for (size_t i = 0; i < models.size(); ++i) {
    if (models[i].psnr > models[selection.best].psnr) selection.best = i;
    if (selection.envelope.empty() || models[i].psnr > models[selection.envelope.back()].psnr) {
      selection.envelope.push_back(i);
    }
  }
  const double floor = models[selection.best].psnr - options.tolerance_db;
  for (size_t i = 0; i < models.size(); ++i) {
    if (models[i].psnr >= floor) {
      selection.chosen = i;
      break;
    }
  }
  selection.gap_db = models[selection.best].psnr - models[selection.chosen].psnr;
  return selection;
}

}  // namespace ibmr
