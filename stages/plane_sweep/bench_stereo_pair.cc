// Two-view benchmark: OpenCV StereoSGBM (blockSize 5), this stage's two-view mode and the
// layered_stereo stage's two-view layered method on every pair of middlebury_stereo_classic, in the
// same run, on the same machine; writes JSON with bad-1.0 and bad-2.0 over pixels with known ground
// truth (missing output counted as bad), the unfilled fraction, the time (median of repeated runs),
// ratios to SGBM (the median of the repeats' ratios, SGBM and this stage run by turns), the
// plane-pixel-neighbour cost evaluations per second, and the portable build's time with a check
// that its disparities are the same. A pair "dominates SGBM" when its bad-1 and its time are both
// at or below SGBM's. Method: see plane_sweep.h (seed 000 lines 5300-5525, 4352-4453). The layered
// method (stages/layered_stereo/layered_pair.h, seed 000 lines 5625-5811) starts from this stage's
// disparity through the two-view registry, which this program fills itself; its time includes that
// initial disparity, and its record the layers (planes) it kept.
//
// Usage: bench_stereo_pair [--data DIR] [--out FILE.json] [--repeat N] [--threads N] [--p1 N] [--p2 N]
//        [--p2-gamma G] [--window-radius R] [--median-radius R] [--sgm-paths 4|8]
//        [--layered KEY=VALUE]... (a layered option, e.g. max_layers=12) [--dump DIR] (writes the layered
//        disparity <pair>_layered.pfm there) [--pair NAME] (only that pair: tsukuba, venus or teddy)
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <thread>

#include "pipeline/core/median.h"
#include "pipeline/core/process_memory.h"
#include "stages/plane_sweep/bench_disparity_score.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/two_view_methods.h"
#include "stages/layered_stereo/layered_pair.h"
#include "stages/plane_sweep/plane_sweep.h"
#include "stages/plane_sweep/sweep_engine.h"

#ifndef IBMR_SHARED_DIR
#define IBMR_SHARED_DIR "../shared"
#endif

namespace {

using ibmr::Median;

struct Pair {
  std::string name, left, right, gt;
  double gt_scale;
  int max_disparity;
};


}  // namespace

int main(int argc, char** argv) {
  ibmr::ConfigureHeap(argv);  // as ibmr does (pipeline/core/process_memory.h)
  std::string data = std::string(IBMR_SHARED_DIR) + "/datasets/middlebury_stereo_classic";
  std::string out = "bench_stereo_pair.json";
  int repeat = 5, threads = 2;
  ibmr::PlaneSweepOptions options;
  ibmr::TwoViewOptions layered_options;
  std::string dump, only;
  const char* usage =
      "usage: bench_stereo_pair [--data DIR] [--out FILE.json] [--repeat N] [--threads N] [--p1 N] [--p2 N]\n"
      "       [--p2-gamma G] [--window-radius R] [--median-radius R] [--sgm-paths 4|8]\n"
      "       [--layered KEY=VALUE]... [--dump DIR] [--pair tsukuba|venus|teddy]\n";
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      std::cout << usage;
      return 0;
    }
  }
  if (argc % 2 == 0) {  // options come in pairs
    std::cerr << "option " << argv[argc - 1] << " without a value\n" << usage;
    return 2;
  }
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--data") data = argv[i + 1];
    else if (key == "--out") out = argv[i + 1];
    else if (key == "--repeat") repeat = std::max(1, std::atoi(argv[i + 1]));
    else if (key == "--threads") threads = std::max(1, std::atoi(argv[i + 1]));
    else if (key == "--p1") options.p1 = std::atoi(argv[i + 1]);
    else if (key == "--p2") options.p2 = std::atoi(argv[i + 1]);
    else if (key == "--p2-gamma") options.p2_gamma = std::atof(argv[i + 1]);
    else if (key == "--window-radius") options.window_radius = std::atoi(argv[i + 1]);
    else if (key == "--median-radius") options.median_radius = std::atoi(argv[i + 1]);
    else if (key == "--sgm-paths") options.sgm_paths = std::atoi(argv[i + 1]);
    else if (key == "--dump") dump = argv[i + 1];
    else if (key == "--pair") only = argv[i + 1];
    else if (key == "--layered" && std::string(argv[i + 1]).find('=') != std::string::npos) {
      const std::string kv = argv[i + 1];
      layered_options[kv.substr(0, kv.find('='))] = kv.substr(kv.find('=') + 1);
    } else {
      std::cerr << "unknown option " << key << "\n" << usage;
      return 2;
    }
  }
  std::string error;
  if (!options.Check(&error)) {
    std::cerr << "bench_stereo_pair: " << error << "\n";
    return 2;
  }
  // The layered method takes its initial disparity from "plane_sweep" in the registry, which the
  // stage's registration would fill; this program registers no stage, so it registers the method:
  // StereoPair with the options above, "fill" and "lr_check" as the stage's (true/false).
  ibmr::RegisterTwoViewMethod("plane_sweep", [options](const cv::Mat& l, const cv::Mat& r, int max_disparity,
                                                       const ibmr::TwoViewOptions& given) {
    ibmr::PlaneSweepOptions o = options;
    for (const auto& [k, v] : given) {
      if (v != "true" && v != "false") throw std::invalid_argument("plane_sweep option " + k + ": true or false");
      if (k == "fill") o.fill_holes = v == "true";
      else if (k == "lr_check") o.lr_check = v == "true";
      else throw std::invalid_argument("plane_sweep: unknown option '" + k + "'");
    }
    const ibmr::StereoPairResult result = ibmr::StereoPair(l, r, max_disparity, o);
    return ibmr::TwoViewOutput{result.disparity, {{"seconds", result.seconds}}};
  });
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
  cv::setNumThreads(threads);
  const std::vector<Pair> pairs = {
      {"tsukuba", "tsukuba/im3.png", "tsukuba/im4.png", "tsukuba/disp3.pgm", 16.0, 16},
      {"venus", "venus/im2.png", "venus/im6.png", "venus/disp2.pgm", 8.0, 32},
      {"teddy", "teddy/im2.png", "teddy/im6.png", "teddy/disp2.png", 4.0, 64},
  };
  nlohmann::json report;
  report["options"] = {{"p1", options.p1}, {"p2", options.p2}, {"p2_gamma", options.p2_gamma},
                       {"window_radius", options.window_radius}, {"median_radius", options.median_radius}};
  report["threads"] = threads;
  report["hardware_threads"] = std::thread::hardware_concurrency();
  report["repeat"] = repeat;
  report["sgbm"] = {{"blockSize", 5}, {"P1", 8 * 25}, {"P2", 32 * 25}, {"mode", "MODE_SGBM"}, {"grey input", true}};
  report["layered_options"] = layered_options;
  bool all_ok = true;
  for (const Pair& pair : pairs) {
    if (!only.empty() && pair.name != only) continue;
    const cv::Mat left = cv::imread(data + "/" + pair.left, cv::IMREAD_GRAYSCALE);
    const cv::Mat right = cv::imread(data + "/" + pair.right, cv::IMREAD_GRAYSCALE);
    const cv::Mat gt = cv::imread(data + "/" + pair.gt, cv::IMREAD_GRAYSCALE);
    if (left.empty() || right.empty() || gt.empty()) {
      std::cerr << data << ": cannot read pair " << pair.name << " (is ../shared/datasets present?)\n";
      return 1;
    }
    // SGBM and ours, run by turns: a slow spell of the machine (a shared virtual machine has them
    // for seconds) then falls on both, not on whichever ran during it. Each repeat gives the
    // ratio of its two times; the record holds the median time of each and the median ratio.
    cv::Ptr<cv::StereoSGBM> sgbm = cv::StereoSGBM::create(0, pair.max_disparity, 5, 8 * 25, 32 * 25);
    cv::Mat raw, sgbm_disparity;
    std::vector<double> sgbm_times, our_times, ratios;
    ibmr::StereoPairResult ours;
    for (int r = 0; r < repeat; ++r) {
      auto t0 = std::chrono::steady_clock::now();
      sgbm->compute(left, right, raw);
      sgbm_times.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      t0 = std::chrono::steady_clock::now();
      ours = ibmr::StereoPair(left, right, pair.max_disparity, options);
      our_times.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      ratios.push_back(our_times.back() / sgbm_times.back());
    }
    raw.convertTo(sgbm_disparity, CV_32F, 1.0 / 16.0);
    // The portable build of the engine on the same pair: its time, and the same disparities.
    std::vector<double> portable_times;
    bool identical = true;
    if (ibmr::sweep::ActiveIsa() != ibmr::sweep::Isa::kPortable) {
      const ibmr::sweep::Isa active = ibmr::sweep::ActiveIsa();
      ibmr::sweep::SetIsa(ibmr::sweep::Isa::kPortable);
      ibmr::StereoPairResult portable;
      for (int r = 0; r < repeat; ++r) {
        const auto t0 = std::chrono::steady_clock::now();
        portable = ibmr::StereoPair(left, right, pair.max_disparity, options);
        portable_times.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
      }
      ibmr::sweep::SetIsa(active);
      identical = cv::norm(portable.disparity, ours.disparity, cv::NORM_INF) == 0;
    }
    // Layered (its time includes the initial plane sweep).
    ibmr::TwoViewOutput layered;
    std::vector<double> layered_times;
    for (int r = 0; r < repeat; ++r) {
      const auto t0 = std::chrono::steady_clock::now();
      layered = ibmr::LayeredTwoView(left, right, pair.max_disparity, layered_options);
      layered_times.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
    if (!dump.empty()) ibmr::WritePfm(dump + "/" + pair.name + "_layered.pfm", layered.disparity);
    const ibmr::DisparityScore s = ibmr::ScoreDisparity(sgbm_disparity, gt, pair.gt_scale);
    const ibmr::DisparityScore o = ibmr::ScoreDisparity(ours.disparity, gt, pair.gt_scale);
    const ibmr::DisparityScore ls = ibmr::ScoreDisparity(layered.disparity, gt, pair.gt_scale);
    const double ts = Median(sgbm_times), to = Median(our_times), tl = Median(layered_times), ratio = Median(ratios);
    const bool ok = o.bad1 <= s.bad1 && ratio <= 1;  // more accurate and no slower: dominates SGBM
    all_ok &= ok;
    report["pairs"][pair.name] = {
        {"width", left.cols}, {"height", left.rows}, {"max_disparity", pair.max_disparity},
        {"sgbm", {{"bad1_percent", s.bad1}, {"bad2_percent", s.bad2}, {"unfilled_fraction", s.unfilled}, {"seconds", ts}}},
        {"plane_sweep", {{"bad1_percent", o.bad1}, {"bad2_percent", o.bad2}, {"unfilled_fraction", o.unfilled},
                         {"seconds", to}, {"evaluations", ours.evaluations},
                         {"evaluations_per_second", ours.evaluations / to}, {"isa", ibmr::sweep::IsaName(ibmr::sweep::ActiveIsa())},
                         {"portable_seconds", portable_times.empty() ? to : Median(portable_times)},
                         {"portable_identical", identical}}},
        {"layered", {{"bad1_percent", ls.bad1}, {"bad2_percent", ls.bad2}, {"unfilled_fraction", ls.unfilled},
                     {"seconds", tl}, {"initial_seconds", layered.facts["initial_seconds"]},
                     {"layers", layered.facts["layers"]}, {"planes", layered.facts["planes"]},
                     {"bad1_ratio_to_sgbm", ls.bad1 / s.bad1}, {"time_ratio_to_sgbm", tl / ts},
                     {"dominates_sgbm", ls.bad1 <= s.bad1 && tl <= ts}}},
        {"bad1_ratio_to_sgbm", o.bad1 / s.bad1}, {"time_ratio_to_sgbm", ratio},
        {"time_ratio_of_medians", to / ts}, {"dominates_sgbm", ok}};
    std::cout << pair.name << ": SGBM bad1 " << s.bad1 << "% " << ts * 1e3 << " ms | plane_sweep bad1 " << o.bad1
              << "% bad2 " << o.bad2 << "% unfilled " << o.unfilled << " " << to * 1e3 << " ms ("
              << ratio << "x) " << ours.evaluations / to / 1e6 << " M eval/s | layered bad1 " << ls.bad1 << "% bad2 "
              << ls.bad2 << "% " << tl * 1e3 << " ms (" << tl / ts << "x) " << layered.facts["layers"] << " layers\n";
  }
  report["all_pairs_dominate_sgbm"] = all_ok;
  ibmr::WriteFileAtomic(out, report.dump(2) + "\n");
  std::cout << "wrote " << out << "\n";
  return 0;
}
