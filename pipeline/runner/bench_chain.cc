// Chain benchmark (issue 58): runs configs from scratch through the ibmr executable, one after the
// other, and writes per config and stage the wall and CPU seconds, peak memory and seconds per
// megapixel of input view, per render model its frame time per megapixel of the final image, and
// beside them the held-out scores, so a speed-up that costs accuracy shows. Timing only: nothing
// asserted. Figures come from the records each stage writes (records/<stage>.json: wall_seconds,
// cpu_seconds, peak_memory_mb; render's ms_per_frame_<model>) and scores/heldout.json.
//
// Usage: bench_chain [--out FILE.json] [--root DIR] [--jobs N] [--ibmr PATH] [CONFIG.yaml...]
//   --ibmr: another build's executable (to compare builds on the same machine; default this build's)
//   default configs: configs/middlebury_temple_ring.yaml configs/synth_dense.yaml
//   configs/synth_texture.yaml configs/synth_layers.yaml; workspaces in DIR/<config name>
//   (default bench_chain_workspaces/), removed first: every run is from scratch.
#include <algorithm>
#include <filesystem>
#include <optional>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/child_process.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/runner/record.h"

namespace fs = std::filesystem;

namespace {

// One config's figures from its finished workspace.
nlohmann::json Figures(const fs::path& workspace) {
  nlohmann::json out;
  // Views and their sizes from the sparse model; held-out views from any record that lists them.
  std::vector<std::string> heldout;
  std::vector<ibmr::StageRecord> records;
  for (const auto& entry : fs::directory_iterator(workspace / "records")) {
    if (entry.path().extension() != ".json") continue;
    std::optional<ibmr::StageRecord> record = ibmr::ReadRecord(entry.path().string());
    if (!record) continue;
    if (heldout.empty()) heldout = record->heldout.get<std::vector<std::string>>();
    records.push_back(std::move(*record));
  }
  double view_mp = 0, training_mp = 0, heldout_mp = 0;
  int training_views = 0;
  if (fs::exists(workspace / "sparse" / "images.txt")) {
    const ibmr::SparseModel model = ibmr::ReadSparseModelText((workspace / "sparse").string());
    for (const auto& [id, image] : model.images) {
      const ibmr::Camera& camera = model.CameraOf(image);
      const double mp = 1e-6 * camera.width * camera.height;
      view_mp += mp;
      if (std::find(heldout.begin(), heldout.end(), image.name) != heldout.end()) {
        heldout_mp += mp;
      } else {
        training_mp += mp, ++training_views;
      }
    }
  }
  out["view_megapixels"] = view_mp;
  out["training_views"] = training_views;
  out["training_megapixels"] = training_mp;
  out["heldout_views"] = heldout.size();
  const double frame_mp = heldout.empty() ? 0.0 : heldout_mp / heldout.size();
  double total = 0;
  for (const ibmr::StageRecord& record : records) {
    total += record.wall_seconds;
    nlohmann::json s = {{"seconds", record.wall_seconds},
                        {"cpu_seconds", record.cpu_seconds},
                        {"peak_memory_mb", record.peak_memory_mb}};
    if (training_mp > 0) s["seconds_per_training_megapixel"] = record.wall_seconds / training_mp;
    out["stages"][record.stage] = s;
    if (record.stage == "render" && frame_mp > 0) {
      for (const auto& [key, value] : record.metrics.items()) {
        if (key.rfind("ms_per_frame_", 0) != 0 || !value.is_number()) continue;
        const double ms = value.get<double>();
        out["render_models"][key.substr(13)] = {{"ms_per_frame", ms}, {"seconds_per_frame_megapixel", 1e-3 * ms / frame_mp}};
      }
    }
  }
  out["stage_seconds_total"] = total;
  const nlohmann::json scores = ibmr::ReadJsonOr((workspace / "scores" / "heldout.json").string(), nullptr);
  if (scores.is_object() && scores.contains("proxies")) {
    size_t models = 0;
    for (const auto& [model, entry] : scores["proxies"].items()) {
      if (!entry.contains("mean")) continue;
      ++models;
      nlohmann::json m;
      for (const char* key : {"psnr", "photo_psnr", "filled_photo_psnr", "ssim"}) {
        if (entry["mean"].contains(key)) m[key] = entry["mean"][key];
      }
      if (entry.contains("mean_excluding_near") && entry["mean_excluding_near"].contains("psnr")) {
        m["psnr_excluding_near"] = entry["mean_excluding_near"]["psnr"];
      }
      out["heldout"][model] = m;
    }
    if (out["stages"].contains("score") && models > 0 && heldout_mp > 0) {
      out["stages"]["score"]["seconds_per_scored_megapixel"] = out["stages"]["score"]["seconds"].get<double>() / (models * heldout_mp);
    }
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string out_path = "bench_chain.json", root = "bench_chain_workspaces", jobs, ibmr = IBMR_BINARY;
  std::vector<std::string> configs;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if ((arg == "--out" || arg == "--root" || arg == "--jobs" || arg == "--ibmr") && i + 1 < argc) {
      (arg == "--out" ? out_path : arg == "--root" ? root : arg == "--jobs" ? jobs : ibmr) = argv[++i];
    } else if (arg.rfind("--", 0) == 0) {
      std::cerr << "bench_chain: unknown option " << arg << " (--out, --root, --jobs, --ibmr, then configs)\n";
      return 2;
    } else {
      configs.push_back(arg);
    }
  }
  if (configs.empty()) {
    for (const char* c : {"middlebury_temple_ring", "synth_dense", "synth_texture", "synth_layers"}) {
      configs.push_back(std::string(IBMR_SOURCE_DIR) + "/configs/" + c + ".yaml");
    }
  }
  nlohmann::json report;
  bool ok = true;
  for (const std::string& config : configs) {
    const std::string name = fs::path(config).stem().string();
    const fs::path workspace = fs::absolute(fs::path(root) / name);
    fs::remove_all(workspace);
    fs::create_directories(workspace.parent_path());
    const std::string log = workspace.string() + ".log";
    fs::remove(log);
    std::vector<std::string> args = {ibmr, "run", config, "--workspace", workspace.string()};
    if (!jobs.empty()) args.insert(args.end(), {"--jobs", jobs});
    std::cout << "bench_chain: " << name << " ..." << std::flush;
    const ibmr::ProcessResult run = ibmr::RunProcess(args, log, [](const std::string&) {});
    const int status = run.exit_code;
    const double seconds = run.wall_seconds;
    std::cout << " " << seconds << " s" << (status == 0 ? "" : " (FAILED, see " + log + ")") << "\n";
    // A workspace the figures cannot be read from is noted and the other configs still run.
    nlohmann::json entry = nlohmann::json::object();
    if (status == 0) {
      try {
        entry = Figures(workspace);
      } catch (const std::exception& e) {
        entry["error"] = std::string("reading the figures: ") + e.what();
        ok = false;
      }
    }
    entry["config"] = config;
    entry["seconds"] = seconds;
    entry["exit_status"] = status;
    ok = ok && status == 0;
    report[name] = entry;
  }
  ibmr::WriteFileAtomic(out_path, report.dump(2) + "\n");
  std::cout << "bench_chain: wrote " << out_path << "\n";
  return ok ? 0 : 1;
}
