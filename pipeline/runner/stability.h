// The stability matrix of a sweep over (degradation, strength): for every method the config names
// (SweepPlan::methods), its error in each cell, its quality relative to the clean scene, where it
// breaks, and whether its confidence saw it coming (Spearman's rho of confidence and error, and the
// area under the confidence's sparsification curve over the optimal one, as the stage measured them). Generic: methods are named by the metrics their stages record.
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "pipeline/runner/config.h"

namespace ibmr {

// A metric of one collected variant (CollectVariant): "stage.key" from the stage's record metrics,
// or "models.NAME.key" from the held-out means; NaN when absent or not a number.
double VariantMetric(const nlohmann::json& variant, const std::string& path);

// Quality relative to the clean scene below which a method counts as broken.
inline constexpr double kBrokenBelow = 0.8;

// From the sweep's collected variants (each with "params" holding the varied values as strings):
//   {"clean": {method: value}, "cells": [{degradation, strength, method, value, relative, confidence_rho,
//                                         sparsification_auc_ratio, failed, why (failed: the first
//                                         failed stage's error, with its upstream warnings)}],
//    "breaks": [{degradation, method, breaks_at (strength, null: holds, "unknown": not measurable),
//                confidence_rho_at_break, sparsification_auc_ratio_at_break}],
//    "duplicate_cells": variants beyond the first per cell,
//    "curves": [{title, axis, value, strengths, series: [{label, values}]}],   (for the report)
//    "sparsification_curves": the same per degradation, the methods' AUC ratios (clean at strength 0),
//    "detectors": [{name, cells: [{degradation, strength, precision, recall, false_calls}]}]
//                 (the clean scene first as degradation "none", strength 0; null where unmeasured)}
// relative = value / clean (higher is better) or clean / value (lower is better): 1 is as good as
// the clean scene. The clean value comes from a variant whose degradation is "none" or whose
// strength is 0. In a variant that failed, a method without its metric has quality 0 (failed).
nlohmann::json StabilityMatrix(const nlohmann::json& variants, const SweepPlan& plan);

}  // namespace ibmr
