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
#include <spawn.h>
#include <fcntl.h>
#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"

extern char** environ;
namespace fs = std::filesystem;

namespace {

// Runs `args` with its output appended to `log`; returns the exit status (-1: not started/killed).
int RunLogged(const std::vector<std::string>& args, const std::string& log) {
  std::vector<char*> argv;
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  pid_t pid = 0;
  const int spawned = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0) return -1;
  int status = 0;
  waitpid(pid, &status, 0);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

nlohmann::json ReadJson(const fs::path& path) {
  std::ifstream in(path);
  return nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
}

// One config's figures from its finished workspace.
nlohmann::json Figures(const fs::path& workspace) {
  nlohmann::json out;
  // Views and their sizes from the sparse model; held-out views from any record that lists them.
  std::vector<std::string> heldout;
  std::vector<nlohmann::json> records;
  for (const auto& entry : fs::directory_iterator(workspace / "records")) {
    if (entry.path().extension() != ".json") continue;
    nlohmann::json record = ReadJson(entry.path());
    if (!record.is_object() || !record.contains("stage")) continue;
    if (heldout.empty() && record.contains("heldout")) heldout = record["heldout"].get<std::vector<std::string>>();
    records.push_back(std::move(record));
  }
  std::sort(records.begin(), records.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    return a.value("started", "") < b.value("started", "");
  });
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
  for (const nlohmann::json& record : records) {
    const std::string stage = record["stage"];
    const double seconds = record.value("wall_seconds", 0.0);
    total += seconds;
    nlohmann::json s = {{"seconds", seconds},
                        {"cpu_seconds", record.value("cpu_seconds", 0.0)},
                        {"peak_memory_mb", record.value("peak_memory_mb", 0.0)}};
    if (training_mp > 0) s["seconds_per_training_megapixel"] = seconds / training_mp;
    out["stages"][stage] = s;
    if (stage == "render" && record.contains("metrics") && frame_mp > 0) {
      for (const auto& [key, value] : record["metrics"].items()) {
        if (key.rfind("ms_per_frame_", 0) != 0 || !value.is_number()) continue;
        const double ms = value.get<double>();
        out["render_models"][key.substr(13)] = {{"ms_per_frame", ms}, {"seconds_per_frame_megapixel", 1e-3 * ms / frame_mp}};
      }
    }
  }
  out["stage_seconds_total"] = total;
  const nlohmann::json scores = ReadJson(workspace / "scores" / "heldout.json");
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
    const auto start = std::chrono::steady_clock::now();
    const int status = RunLogged(args, log);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
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
