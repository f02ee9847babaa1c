// Multi-view benchmark of the plane_sweep stage, running the stage adapters in-process on
// temporary workspaces (2 threads by default) and writing JSON:
//  * synth object_ring (true depth): fraction of textured (object) pixels within 1% of the true
//    depth, fraction kept, precision of the kept samples, time, evaluations per second;
//  * Middlebury templeSparseRing at full resolution: plane_sweep wall time (MVE dmrecon: 161.6 s),
//    evaluations per second (over the stage's wall time, and over the CPU time of the evaluations
//    alone: evaluations_per_second_all_threads), where the threads' time went (thread_seconds:
//    evaluations, box filter, semi-global passes and winners, writing the maps, against the wall
//    times the threads), cost volume per view and peak memory, with the
//    engine's build in use, again with the portable build, and again with the bilinear census
//    cost (`bilinear`: the cost before the one along the epipolar lines; CensusSampling);
//  * Middlebury dinoSparseRing (untextured): fraction of pixels kept at the confidence threshold,
//    on the object (grey >= 40) and on the black background;
//  * the machine's limit for the census cost (MachineLimit: how it is derived).
// Method: plane_sweep.h (seed 000 lines 3659-3760, 5300-5525, 4352-4453).
//
// Usage: bench_plane_sweep [--out FILE.json] [--threads N] [--only synth|temple|dino]
//                          [--confidence-threshold T] [--work DIR] [--portable-too true|false]
//                          [--census-sampling epipolar|bilinear] [--bilinear-too true|false]
#include <tbb/global_control.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "pipeline/core/process_memory.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/stage_api.h"
#include "pipeline/core/workspace.h"
#include "stages/plane_sweep/sweep_engine.h"

#ifndef IBMR_SHARED_DIR
#define IBMR_SHARED_DIR "../shared"
#endif

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_import(StageRegistry* registry);
void RegisterStage_synth(StageRegistry* registry);
void RegisterStage_plane_sweep(StageRegistry* registry);
}  // namespace ibmr

namespace {

using namespace ibmr;

Params Defaults(const Stage& stage) {
  Params params;
  for (const ParamSpec& spec : stage.Parameters()) {
    std::string v = spec.default_yaml;
    if (v.size() >= 2 && v.front() == '"') v = v.substr(1, v.size() - 2);
    switch (spec.type) {
      case ParamType::kInt: params.Set(spec.key, int64_t{std::stoll(v)}); break;
      case ParamType::kDouble: params.Set(spec.key, std::stod(v)); break;
      case ParamType::kBool: params.Set(spec.key, v == "true"); break;
      case ParamType::kDoubleList: params.Set(spec.key, std::vector<double>{}); break;
      case ParamType::kIntList: params.Set(spec.key, std::vector<int64_t>{}); break;
      case ParamType::kStringList: params.Set(spec.key, std::vector<std::string>{}); break;
      default: params.Set(spec.key, v); break;
    }
  }
  return params;
}

struct Runner {
  StageRegistry registry;
  NullProgress progress;
  nlohmann::json Run(const std::string& workspace, const std::string& name, const Params& params) {
    StageContext context;
    context.workspace = Workspace(workspace);
    context.params = params;
    context.progress = &progress;
    context.role = registry.Find(name)->Role();
    registry.Find(name)->Run(context);
    return context.metrics;
  }
};

nlohmann::json Summary(const nlohmann::json& metrics) {
  nlohmann::json out = metrics;
  out.erase("per_view");
  return out;
}

nlohmann::json Synth(Runner& runner, const std::string& dir, double threshold, const std::string& sampling) {
  const std::string ws = dir + "/synth";
  fs::remove_all(ws);
  Params synth = Defaults(*runner.registry.Find("synth"));
  synth.Set("scene", std::string("object_ring"));
  synth.Set("views", int64_t{24});
  synth.Set("width", int64_t{320});
  synth.Set("height", int64_t{240});
  runner.Run(ws, "synth", synth);
  Params params = Defaults(*runner.registry.Find("plane_sweep"));
  params.Set("confidence_threshold", threshold);
  params.Set("census_sampling", sampling);
  const nlohmann::json metrics = runner.Run(ws, "plane_sweep", params);
  const Workspace w(ws);
  size_t truth = 0, within = 0, kept = 0;
  for (const auto& entry : fs::directory_iterator(ws + "/images")) {
    const std::string name = entry.path().filename().string();
    const DepthMap gt = ReadColmapArray(w.GroundTruthDepthPath(name));
    const DepthMap depth = ReadColmapArray(w.DepthMapPath(name, "photometric"));
    for (size_t i = 0; i < gt.data.size(); ++i) {
      if (!IsValidDepth(gt.data[i])) continue;
      ++truth;
      if (!IsValidDepth(depth.data[i])) continue;
      ++kept;
      within += std::fabs(depth.data[i] - gt.data[i]) < 0.01 * gt.data[i];
    }
  }
  nlohmann::json out = {{"scene", "object_ring 24 views 320x240"},
                        {"textured_pixels", truth},
                        {"fraction_within_1_percent", static_cast<double>(within) / truth},
                        {"fraction_kept", static_cast<double>(kept) / truth},
                        {"precision_1_percent_of_kept", kept ? static_cast<double>(within) / kept : 0.0},
                        {"plane_sweep", Summary(metrics)}};
  std::cout << "synth: " << out.dump() << "\n";
  return out;
}

nlohmann::json Middlebury(Runner& runner, const std::string& dir, const std::string& dataset,
                          const std::vector<double>& box, double threshold, const std::string& sampling) {
  const std::string ws = dir + "/" + dataset;
  fs::remove_all(ws);
  Params import = Defaults(*runner.registry.Find("import"));
  import.Set("source", std::string(IBMR_SHARED_DIR) + "/datasets/" + dataset);
  import.Set("format", std::string("middlebury"));
  runner.Run(ws, "import", import);
  Params params = Defaults(*runner.registry.Find("plane_sweep"));
  params.Set("bounding_box", box);
  params.Set("depth_margin", 0.05);
  params.Set("confidence_threshold", threshold);
  params.Set("census_sampling", sampling);
  const auto t0 = std::chrono::steady_clock::now();
  const nlohmann::json metrics = runner.Run(ws, "plane_sweep", params);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  const Workspace w(ws);
  size_t object = 0, object_kept = 0, background = 0, background_kept = 0;
  for (const auto& entry : fs::directory_iterator(ws + "/images")) {
    const std::string name = entry.path().filename().string();
    const cv::Mat gray = cv::imread(entry.path().string(), cv::IMREAD_GRAYSCALE);
    const DepthMap depth = ReadColmapArray(w.DepthMapPath(name, "photometric"));
    for (int y = 0; y < gray.rows; ++y) {
      for (int x = 0; x < gray.cols; ++x) {
        const bool on_object = gray.at<uint8_t>(y, x) >= 40;
        const bool kept = IsValidDepth(depth.At(x, y));
        (on_object ? object : background) += 1;
        (on_object ? object_kept : background_kept) += kept;
      }
    }
  }
  nlohmann::json out = {{"dataset", dataset},
                        {"wall_seconds", seconds},
                        {"fraction_kept_object", static_cast<double>(object_kept) / std::max<size_t>(1, object)},
                        {"fraction_kept_background", static_cast<double>(background_kept) / std::max<size_t>(1, background)},
                        {"fraction_kept_all", static_cast<double>(object_kept + background_kept) / (object + background)},
                        {"plane_sweep", Summary(metrics)}};
  std::cout << dataset << ": " << out.dump() << "\n";
  return out;
}

// The ceiling of the census cost on this machine, from the instruction mix: an evaluation reads
// two 64-bit codes of the neighbour along the epipolar line (four for the bilinear cost; the
// XORs, POPCNTs and weights run on ALU ports beside the loads), and a core issues at most 3 loads
// per cycle (AMD Zen 3 to 5, Intel Golden Cove: 3 load ports), so a core does at most 1.5
// evaluations per cycle (0.75 bilinear). Times the threads and the clock read from /proc/cpuinfo.
nlohmann::json MachineLimit(int threads, const std::string& sampling) {
  double mhz = 0;
  std::string vendor;
  int family = 0;
  std::ifstream cpuinfo("/proc/cpuinfo");
  for (std::string line; std::getline(cpuinfo, line);) {
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    const std::string value = line.substr(colon + 1);
    if (line.rfind("cpu MHz", 0) == 0 && mhz == 0) mhz = std::atof(value.c_str());
    if (line.rfind("vendor_id", 0) == 0 && vendor.empty()) vendor = value.substr(value.find_first_not_of(' '));
    if (line.rfind("cpu family", 0) == 0 && family == 0) family = std::atoi(value.c_str());
  }
  // Loads a core issues per cycle: AMD family 23 (Zen 1 and 2) has two load ports, Zen 3 and later
  // (and Intel since Ice Lake) three.
  const double loads_per_cycle = vendor == "AuthenticAMD" && family <= 23 ? 2 : 3;
  const double loads_per_evaluation = sampling == "bilinear" ? 4 : 2;
  const double limit = threads * mhz * 1e6 * loads_per_cycle / loads_per_evaluation;
  return {{"threads", threads}, {"cpu_mhz", mhz}, {"cpu_vendor", vendor}, {"cpu_family", family},
          {"loads_per_cycle_per_core", loads_per_cycle}, {"loads_per_evaluation", loads_per_evaluation},
          {"evaluations_per_second", limit},
          {"census_sampling", sampling},
          {"derivation", "threads x clock x loads per cycle (2 on AMD family 23, else 3) / neighbour codes per census "
                         "evaluation (2 along the epipolar line, 4 bilinear; load-port bound: the XOR, POPCNT and "
                         "weighting run on other ports)"}};
}

}  // namespace

int main(int argc, char** argv) {
  ibmr::ConfigureHeap(argv);  // as ibmr does (pipeline/core/process_memory.h)
  std::string out = "bench_plane_sweep.json", only, work = (fs::temp_directory_path() / "ibmr_bench_plane_sweep").string();
  int threads = 2;
  double threshold = -1;
  bool portable_too = true;  // templeSparseRing again on the portable build
  bool bilinear_too = true;  // and with the bilinear census cost
  std::string sampling = "epipolar";
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--out") out = argv[i + 1];
    else if (key == "--threads") threads = std::max(1, std::atoi(argv[i + 1]));
    else if (key == "--only") only = argv[i + 1];
    else if (key == "--work") work = argv[i + 1];
    else if (key == "--confidence-threshold") threshold = std::atof(argv[i + 1]);
    else if (key == "--portable-too") portable_too = std::string(argv[i + 1]) != "false";
    else if (key == "--bilinear-too") bilinear_too = std::string(argv[i + 1]) != "false";
    else if (key == "--census-sampling") {
      sampling = argv[i + 1];
      if (sampling != "epipolar" && sampling != "bilinear") {
        std::cerr << "bench_plane_sweep: --census-sampling must be epipolar or bilinear, got '" << sampling << "'\n";
        return 2;
      }
    } else {
      std::cerr << "unknown option " << key << "\nusage: bench_plane_sweep [--out FILE] [--threads N] [--only synth|temple|dino] [--confidence-threshold T] [--work DIR] [--portable-too true|false] [--census-sampling epipolar|bilinear] [--bilinear-too true|false]\n";
      return 2;
    }
  }
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  Runner runner;
  RegisterStage_import(&runner.registry);
  RegisterStage_synth(&runner.registry);
  RegisterStage_plane_sweep(&runner.registry);
  if (threshold < 0) threshold = Defaults(*runner.registry.Find("plane_sweep")).Double("confidence_threshold");
  fs::create_directories(work);
  nlohmann::json report = {{"threads", threads}, {"confidence_threshold", threshold}, {"census_sampling", sampling}};
  try {
    if (only.empty() || only == "synth") report["synth"] = Synth(runner, work, threshold, sampling);
    if (only.empty() || only == "temple") {
      const std::vector<double> box = {-0.073568, 0.021728, -0.012445, 0.028855, 0.181892, 0.062736};
      report["temple"] = Middlebury(runner, work, "middlebury_templeSparseRing", box, threshold, sampling);
      if (portable_too && sweep::ActiveIsa() != sweep::Isa::kPortable) {  // the same run on the portable build
        const sweep::Isa active = sweep::ActiveIsa();
        sweep::SetIsa(sweep::Isa::kPortable);
        const nlohmann::json portable = Middlebury(runner, work, "middlebury_templeSparseRing", box, threshold, sampling);
        sweep::SetIsa(active);
        report["temple"]["portable"] = {{"wall_seconds", portable["wall_seconds"]},
                                        {"evaluations_per_second", portable["plane_sweep"]["evaluations_per_second"]},
                                        {"fraction_kept_object", portable["fraction_kept_object"]}};
      }
      if (bilinear_too && sampling != "bilinear") {  // the same run with the bilinear census cost
        const nlohmann::json bilinear = Middlebury(runner, work, "middlebury_templeSparseRing", box, threshold, "bilinear");
        const double ratio = bilinear["plane_sweep"]["evaluations_per_second"].get<double>() /
                             report["temple"]["plane_sweep"]["evaluations_per_second"].get<double>();
        report["temple"]["bilinear"] = {
            {"wall_seconds", bilinear["wall_seconds"]},
            {"evaluations_per_second", bilinear["plane_sweep"]["evaluations_per_second"]},
            {"evaluations_per_second_all_threads", bilinear["plane_sweep"]["evaluations_per_second_all_threads"]},
            {"fraction_kept_object", bilinear["fraction_kept_object"]},
            {"throughput_ratio_to_epipolar", ratio}};
      }
    }
    if (only.empty() || only == "dino")
      report["dino"] = Middlebury(runner, work, "middlebury_dinoSparseRing",
                                  {-0.061897, -0.018874, -0.057845, 0.010897, 0.068227, 0.015495}, threshold, sampling);
  } catch (const std::exception& e) {
    std::cerr << "bench_plane_sweep: " << e.what() << "\n";
    return 1;
  }
  report["mve_dmrecon_temple_full_seconds"] = 161.6;
  report["isa"] = sweep::IsaName(sweep::ActiveIsa());
  report["machine_limit"] = MachineLimit(threads, sampling);
  WriteFileAtomic(out, report.dump(2) + "\n");
  std::cout << "wrote " << out << "\n";
  return 0;
}
