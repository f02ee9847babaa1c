// Runs a config's variants and collects their costs and held-out scores (see sweep.h).
#include "pipeline/runner/sweep.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/heldout_scores.h"
#include "pipeline/core/workspace.h"
#include "pipeline/runner/record.h"
#include "pipeline/runner/runner.h"
#include "pipeline/runner/stability.h"

namespace ibmr {

namespace fs = std::filesystem;

namespace {

std::pair<std::string, std::string> SplitAssignment(const std::string& text, const std::string& flag) {
  const size_t eq = text.find('=');
  const size_t dot = text.find('.');
  if (eq == std::string::npos || dot == std::string::npos || dot > eq || eq + 1 == text.size()) {
    throw ConfigError(flag + " " + text + ": expected stage.key=value, e.g. " + flag +
                      " plane_sweep.num_planes=64" + (flag == "--vary" ? ",128" : ""));
  }
  return {text.substr(0, eq), text.substr(eq + 1)};
}

std::vector<std::string> Split(const std::string& text, char separator) {
  std::vector<std::string> parts;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = std::min(text.find(separator, start), text.size());
    if (end > start) parts.push_back(text.substr(start, end - start));
    start = end + 1;
  }
  return parts;
}

std::string VariantName(size_t index) {
  char name[16];
  std::snprintf(name, sizeof(name), "v%02zu", index);
  return name;
}

}  // namespace

std::vector<Assignments> ExpandVariants(const std::vector<std::string>& vary, const std::vector<std::string>& listed) {
  std::vector<Assignments> variants;
  if (!vary.empty()) {
    variants.emplace_back();
    for (const std::string& axis : vary) {
      const auto [key, list] = SplitAssignment(axis, "--vary");
      const std::vector<std::string> values = Split(list, ',');
      if (values.empty()) throw ConfigError("--vary " + axis + ": no values after '='");
      std::vector<Assignments> crossed;
      for (const Assignments& partial : variants) {
        for (const std::string& value : values) {
          crossed.push_back(partial);
          crossed.back().emplace_back(key, value);
        }
      }
      variants = std::move(crossed);
    }
  }
  for (const std::string& combination : listed) {
    Assignments assignments;
    for (const std::string& part : Split(combination, ' ')) assignments.push_back(SplitAssignment(part, "--variant"));
    if (assignments.empty()) throw ConfigError("--variant '" + combination + "': no stage.key=value in it");
    variants.push_back(std::move(assignments));
  }
  if (variants.empty()) variants.emplace_back();
  return variants;
}

nlohmann::json ParetoFront(const nlohmann::json& points) {
  std::vector<nlohmann::json> sorted;
  for (const auto& p : points) {
    if (p.contains("seconds") && p.contains("psnr") && p["seconds"].is_number() && p["psnr"].is_number()) {
      sorted.push_back(p);
    }
  }
  std::stable_sort(sorted.begin(), sorted.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    const double ta = a["seconds"], tb = b["seconds"];
    if (ta != tb) return ta < tb;
    return a["psnr"].get<double>() > b["psnr"].get<double>();
  });
  nlohmann::json front = nlohmann::json::array();
  double best = -std::numeric_limits<double>::infinity();
  for (const auto& p : sorted) {
    const double psnr = p["psnr"];
    if (psnr > best) {
      front.push_back(p);
      best = psnr;
    }
  }
  return front;
}

nlohmann::json CollectVariant(const Config& config, const StageRegistry& registry, bool ran_clean) {
  const Workspace workspace(config.workspace);
  // A record that is not up to date (a stage after one that failed, left from an earlier run of
  // this folder) describes other inputs: it is reported as stale, without its costs or metrics.
  // After a clean run every record is current, and the inputs need not be hashed again.
  std::map<std::string, bool> current;
  for (const StageConfig& stage : config.stages) current[stage.name] = true;
  if (!ran_clean) {
    for (const StageStatus& s : Runner(config, registry).Status()) current[s.name] = s.up_to_date;
  }
  nlohmann::json stages = nlohmann::json::array();
  double wall = 0, cpu = 0, peak = 0, computed = 0;
  std::string status = "ok";
  for (const StageConfig& stage : config.stages) {
    const auto record = ReadRecord(workspace.RecordsDir() + "/" + stage.name + ".json");
    nlohmann::json entry = {{"stage", stage.name}};
    if (!record || (record->status == "ok" && !current[stage.name])) {
      entry["status"] = record ? "stale" : "not run";
      if (status == "ok") status = "incomplete";
      stages.push_back(entry);
      continue;
    }
    entry["status"] = record->status;
    entry["wall_seconds"] = record->wall_seconds;
    entry["cpu_seconds"] = record->cpu_seconds;
    entry["peak_memory_mb"] = record->peak_memory_mb;
    entry["reused"] = !record->reused_from.empty();
    entry["metrics"] = record->metrics;
    if (!record->error.empty()) entry["error"] = record->error;
    if (record->status != "ok" && record->status != "skipped") status = "failed";  // skipped: the run's plan
    wall += record->wall_seconds;
    cpu += record->cpu_seconds;
    peak = std::max(peak, record->peak_memory_mb);
    if (record->reused_from.empty()) computed += record->wall_seconds;
    stages.push_back(entry);
  }
  // Held-out scores only when every stage is current: otherwise they are an earlier run's.
  const nlohmann::json sizes = ModelSizes(ReadJsonOr(workspace.Path("renders/renders.json"), nlohmann::json::object()));
  nlohmann::json models = nlohmann::json::object();
  const nlohmann::json scores = status == "ok" ? ReadJsonOr(workspace.Path("scores/heldout.json"), nlohmann::json::object())
                                               : nlohmann::json::object();
  const nlohmann::json proxies = scores.value("proxies", nlohmann::json::object());
  for (const auto& [name, proxy] : proxies.items()) {
    nlohmann::json model = HeldoutMeans(proxy);
    if (model.empty()) continue;
    if (sizes.contains(name)) model["size"] = sizes[name];
    models[name] = model;
  }
  return {{"status", status},
          {"stages", stages},
          {"wall_seconds", wall},           // the cost of the variant from scratch
          {"computed_wall_seconds", computed},  // what this sweep spent on it (reused stages excluded)
          {"cpu_seconds", cpu},
          {"peak_memory_mb", peak},
          {"models", models}};
}

std::string SweepFolder(const SweepOptions& options, const Config& base) {
  return fs::absolute(options.out.empty() ? base.workspace + ".sweep" : options.out).lexically_normal().string();
}

int RunSweep(const SweepOptions& given, const StageRegistry& registry) {
  const Config base = LoadConfig(given.config_path, registry);
  // The config's sweep: block first, then the command line's.
  SweepOptions options = given;
  options.vary.insert(options.vary.begin(), base.sweep.vary.begin(), base.sweep.vary.end());
  options.listed.insert(options.listed.begin(), base.sweep.variants.begin(), base.sweep.variants.end());
  if (!base.sweep.metric.empty() && given.metric == SweepOptions().metric) options.metric = base.sweep.metric;
  const std::vector<Assignments> variants = ExpandVariants(options.vary, options.listed);
  const std::string out = SweepFolder(options, base);
  fs::create_directories(out);
  // Every override is checked before anything runs: a typo in the last variant fails now.
  std::vector<Config> configs;
  for (size_t i = 0; i < variants.size(); ++i) {
    Config config = base;
    for (const auto& [key, value] : variants[i]) ApplyOverride(key + "=" + value, registry, &config);
    config.workspace = out + "/" + VariantName(i);
    configs.push_back(std::move(config));
  }
  spdlog::info("sweep of {}: {} variant(s) in {}", options.config_path, variants.size(), out);

  nlohmann::json sweep = {{"config", fs::absolute(options.config_path).lexically_normal().string()},
                          {"metric", options.metric},
                          {"variants", nlohmann::json::array()}};
  nlohmann::json varied = nlohmann::json::array();
  for (const Assignments& assignments : variants) {
    for (const auto& [key, value] : assignments) {
      if (std::find(varied.begin(), varied.end(), key) == varied.end()) varied.push_back(key);
    }
  }
  sweep["varied"] = varied;
  int failed = 0;
  std::vector<std::string> done;
  const auto sweep_start = std::chrono::steady_clock::now();
  for (size_t i = 0; i < configs.size(); ++i) {
    nlohmann::json params = nlohmann::json::object();
    std::string label;
    for (const auto& [key, value] : variants[i]) {
      params[key] = value;
      label += (label.empty() ? "" : " ") + key + "=" + value;
    }
    // Progress: the variants so far set the pace for the rest (reused stages make later ones quicker,
    // so the estimate errs long).
    const double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - sweep_start).count();
    const std::string eta = i == 0 ? std::string("")
                                   : fmt::format(", {:.0f} s so far, about {:.0f} s to go", elapsed,
                                                 elapsed / static_cast<double>(i) * static_cast<double>(configs.size() - i));
    spdlog::info("sweep variant {} of {}: {} ({}){}", i + 1, configs.size(), VariantName(i),
                 label.empty() ? "the config as it is" : label, eta);
    RunOptions run;
    run.jobs = options.jobs;
    run.interactive = options.interactive;
    run.reuse_from = done;
    int code = 1;
    std::string error;
    try {
      code = Runner(configs[i], registry).Run(run);
    } catch (const std::exception& e) {
      error = e.what();
      spdlog::error("sweep variant {}: {}", VariantName(i), error);
    }
    nlohmann::json variant = CollectVariant(configs[i], registry, code == 0);
    variant["name"] = VariantName(i);
    variant["workspace"] = VariantName(i);
    variant["params"] = params;
    variant["label"] = label;
    if (code != 0) {
      ++failed;
      variant["status"] = "failed";
      if (!error.empty()) variant["error"] = error;
    }
    sweep["variants"].push_back(variant);
    done.push_back(configs[i].workspace);

    // Points of time against held-out error: every scored model of every variant.
    nlohmann::json points = nlohmann::json::array();
    for (const auto& v : sweep["variants"]) {
      for (const auto& [model, scores] : v["models"].items()) {
        if (!scores.contains(options.metric) || !scores[options.metric].is_number()) continue;
        points.push_back({{"variant", v["name"]}, {"model", model}, {"seconds", v["wall_seconds"]},
                          {"psnr", scores[options.metric]}});
      }
    }
    sweep["points"] = points;
    sweep["pareto"] = ParetoFront(points);
    if (base.sweep.HasStability()) sweep["stability"] = StabilityMatrix(sweep["variants"], base.sweep);
    WriteFileAtomic(out + "/sweep.json", DumpJson(sweep, 2) + "\n");
  }
  spdlog::info("sweep: {} of {} variant(s) ran; {}", configs.size() - failed, configs.size(), out + "/sweep.json");
  for (const auto& p : sweep["pareto"]) {
    spdlog::info("  pareto: {} {}: {:.1f} s, {} {:.2f} dB", p["variant"].get<std::string>(),
                 p["model"].get<std::string>(), p["seconds"].get<double>(), options.metric, p["psnr"].get<double>());
  }
  return failed == 0 ? 0 : 1;
}

}  // namespace ibmr
