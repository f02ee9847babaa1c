// The stability matrix of a sweep (see stability.h).
#include "pipeline/runner/stability.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>

namespace ibmr {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

nlohmann::json Number(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(nullptr); }

// Why a failed variant produced nothing: the first failed stage's error (which quotes the
// warnings of the stages before it: runner.cc), else the variant's own.
std::string FailureOf(const nlohmann::json& variant) {
  for (const auto& stage : variant.value("stages", nlohmann::json::array())) {
    if (stage.value("status", "") == "failed") return "[" + stage.value("stage", "") + "] " + stage.value("error", "");
  }
  return variant.value("error", "failed");
}

// `path`'s metric of `variant`, NaN when either is absent (an optional metric of a method).
double VariantMetricOrNaN(const nlohmann::json* variant, const std::string& path) {
  return variant == nullptr || path.empty() ? kNaN : VariantMetric(*variant, path);
}

}  // namespace

double VariantMetric(const nlohmann::json& variant, const std::string& path) {
  if (path.rfind("models.", 0) == 0) {
    const std::string rest = path.substr(7);
    const size_t dot = rest.rfind('.');
    if (dot == std::string::npos) return kNaN;
    const std::string model = rest.substr(0, dot), key = rest.substr(dot + 1);
    const nlohmann::json& models = variant.contains("models") ? variant["models"] : nlohmann::json::object();
    if (!models.contains(model) || !models[model].contains(key) || !models[model][key].is_number()) return kNaN;
    return models[model][key].get<double>();
  }
  const size_t dot = path.find('.');
  if (dot == std::string::npos || !variant.contains("stages")) return kNaN;
  const std::string stage = path.substr(0, dot), key = path.substr(dot + 1);
  for (const auto& s : variant["stages"]) {
    if (s.value("stage", "") != stage || !s.contains("metrics")) continue;
    const auto& metrics = s["metrics"];
    return metrics.contains(key) && metrics[key].is_number() ? metrics[key].get<double>() : kNaN;
  }
  return kNaN;
}

nlohmann::json StabilityMatrix(const nlohmann::json& variants, const SweepPlan& plan) {
  const auto param = [](const nlohmann::json& v, const std::string& key) -> std::string {
    return v.contains("params") && v["params"].contains(key) ? v["params"][key].get<std::string>() : "";
  };
  // A variant's cell: the first degradation key it sets to something but "none", with that
  // degradation's strength; ("", 0) for the clean scene.
  struct Cell {
    std::string degradation;
    double strength = 0;
  };
  const auto cell_of = [&](const nlohmann::json& v) {
    for (size_t i = 0; i < plan.degradation_keys.size(); ++i) {
      const std::string d = param(v, plan.degradation_keys[i]);
      if (d.empty() || d == "none") continue;
      const std::string s = param(v, plan.strength_keys[i]);
      return Cell{d, s.empty() ? 0.0 : std::atof(s.c_str())};
    }
    return Cell{};
  };
  // The clean scene.
  std::map<std::string, double> clean;
  const nlohmann::json* clean_variant = nullptr;
  for (const auto& v : variants) {
    if (v.value("status", "") != "ok" || cell_of(v).strength != 0) continue;
    for (const auto& m : plan.methods) clean[m.name] = VariantMetric(v, m.metric);
    clean_variant = &v;
    break;
  }
  nlohmann::json out = {{"clean", nlohmann::json::object()}, {"cells", nlohmann::json::array()},
                        {"breaks", nlohmann::json::array()}, {"curves", nlohmann::json::array()},
                        {"sparsification_curves", nlohmann::json::array()}};
  for (const auto& [name, value] : clean) out["clean"][name] = Number(value);
  const auto relative = [&](const StabilityMethod& m, double value) {
    const auto it = clean.find(m.name);
    if (it == clean.end() || !std::isfinite(it->second) || !std::isfinite(value) || it->second == 0) return kNaN;
    if (m.higher_is_better) return value / it->second;
    return value > 0 ? it->second / value : kNaN;
  };
  // Cells, grouped by degradation and strength; a sweep that also varies another key has several
  // variants per cell: the first one counts, and the others are counted in "duplicate_cells".
  std::map<std::string, std::map<double, const nlohmann::json*>> grid;
  int out_duplicates = 0;
  for (const auto& v : variants) {
    const Cell cell = cell_of(v);
    if (cell.degradation.empty()) continue;
    if (!grid[cell.degradation].emplace(cell.strength, &v).second) ++out_duplicates;
  }
  out["duplicate_cells"] = out_duplicates;
  for (const auto& [degradation, by_strength] : grid) {
    nlohmann::json curve = {{"title", degradation},
                            {"axis", "strength"},
                            {"value", "quality relative to the clean scene"},
                            {"strengths", nlohmann::json::array({0.0})},
                            {"series", nlohmann::json::array()}};
    for (const auto& [strength, variant] : by_strength) {
      if (strength > 0) curve["strengths"].push_back(strength);
    }
    // The confidences' sparsification areas over the optimal ones, by strength (1 is perfect).
    nlohmann::json auc_curve = {{"title", degradation},
                                {"axis", "strength"},
                                {"value", "sparsification AUC / optimal AUC"},
                                {"strengths", curve["strengths"]},
                                {"series", nlohmann::json::array()}};
    for (const StabilityMethod& m : plan.methods) {
      nlohmann::json values = nlohmann::json::array({clean.count(m.name) && std::isfinite(clean[m.name]) ? 1.0 : kNaN});
      nlohmann::json broken = nullptr, rho_at_break = nullptr, auc_at_break = nullptr;
      nlohmann::json auc_values = nlohmann::json::array({VariantMetricOrNaN(clean_variant, m.sparsification)});
      bool unknown = !clean.count(m.name) || !std::isfinite(clean[m.name]);
      for (const auto& [strength, variant] : by_strength) {
        if (strength <= 0) continue;  // the clean scene's point, already at 0
        const double value = VariantMetric(*variant, m.metric);
        // A variant that failed before this method's stage ran: the method produced nothing, quality 0.
        const bool failed = variant->value("status", "") != "ok" && !std::isfinite(value);
        const double rel = failed ? 0.0 : relative(m, value);
        const double rho = VariantMetricOrNaN(variant, m.confidence);
        const double auc = VariantMetricOrNaN(variant, m.sparsification);
        out["cells"].push_back({{"degradation", degradation}, {"strength", strength}, {"method", m.name},
                                {"value", Number(value)}, {"relative", Number(rel)}, {"confidence_rho", Number(rho)},
                                {"sparsification_auc_ratio", Number(auc)}, {"failed", failed}});
        if (failed) out["cells"].back()["why"] = FailureOf(*variant);
        values.push_back(Number(rel));
        auc_values.push_back(Number(auc));
        if (!std::isfinite(rel)) unknown = true;
        if (broken.is_null() && std::isfinite(rel) && rel < kBrokenBelow) {
          broken = strength;
          rho_at_break = Number(rho);
          auc_at_break = Number(auc);
        }
      }
      // "unknown" rather than holding when the clean value or a cell could not be measured (a
      // metric path that names nothing, a clean run that failed).
      if (broken.is_null() && unknown) broken = "unknown";
      out["breaks"].push_back({{"degradation", degradation}, {"method", m.name}, {"breaks_at", broken},
                               {"confidence_rho_at_break", rho_at_break},
                               {"sparsification_auc_ratio_at_break", auc_at_break}});
      curve["series"].push_back({{"label", m.name}, {"values", values}});
      if (!m.sparsification.empty()) auc_curve["series"].push_back({{"label", m.name}, {"values", auc_values}});
    }
    out["curves"].push_back(curve);
    if (!auc_curve["series"].empty()) out["sparsification_curves"].push_back(auc_curve);
  }
  // Detectors: precision, recall and false calls in every cell, the clean scene first.
  out["detectors"] = nlohmann::json::array();
  for (const StabilityDetector& d : plan.detectors) {
    nlohmann::json cells = nlohmann::json::array();
    const auto add = [&](const std::string& degradation, double strength, const nlohmann::json* variant) {
      cells.push_back({{"degradation", degradation}, {"strength", strength},
                       {"precision", Number(VariantMetricOrNaN(variant, d.precision))},
                       {"recall", Number(VariantMetricOrNaN(variant, d.recall))},
                       {"false_calls", Number(VariantMetricOrNaN(variant, d.false_calls))}});
    };
    if (clean_variant != nullptr) add("none", 0, clean_variant);
    for (const auto& [degradation, by_strength] : grid) {
      for (const auto& [strength, variant] : by_strength) {
        if (strength > 0) add(degradation, strength, variant);
      }
    }
    out["detectors"].push_back({{"name", d.name}, {"cells", cells}});
  }
  return out;
}

}  // namespace ibmr
