// Whole-process benchmark: what a user waits for when ibmr runs as a command, against plain OpenCV
// programs in the same run on the same machine (issue 58). Writes JSON:
//  - start: `ibmr --help` against peer_opencv_start (links OpenCV's core and image codecs, exits);
//  - per Middlebury pair (tsukuba, venus, teddy): `ibmr stereo-pair` (read, match, write PFM)
//    against peer_sgbm_pair (read, StereoSGBM blockSize 5, write PFM), with both outputs' bad-1.0
//    against the ground truth (missing counted as bad), read back from the PFMs they wrote.
// Each measure is run by turns with its peer, `repeat` times (a slow spell of a shared machine
// then falls on both), through RunProcess (output read and dropped, for both alike); the record
// holds each one's median wall and CPU (user + system) milliseconds and the median of the
// per-repeat ratios. Timing only: nothing asserted.
//
// Usage: bench_process_start [--data DIR] [--out FILE.json] [--repeat N] [--ibmr PATH]
//   --ibmr: another build's executable (to compare builds in one run; default this build's)
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "pipeline/core/median.h"
#include "pipeline/core/atomic_file.h"
#include "pipeline/core/child_process.h"
#include "pipeline/core/image_io.h"
#include "stages/plane_sweep/bench_disparity_score.h"

namespace {

using ibmr::Median;

// `ours` and `peer` by turns, `repeat` times (after one unrecorded run of each: page cache).
nlohmann::json Compare(const std::vector<std::string>& ours, const std::vector<std::string>& peer, int repeat, bool* ok) {
  std::vector<double> ours_wall, ours_cpu, peer_wall, peer_cpu, ratios;
  const auto run = [](const std::vector<std::string>& args) { return ibmr::RunProcess(args, "", [](const std::string&) {}); };
  run(ours), run(peer);
  for (int r = 0; r < repeat; ++r) {
    const ibmr::ProcessResult a = run(ours), b = run(peer);
    if (a.exit_code != 0 || b.exit_code != 0) {
      std::cerr << "bench_process_start: " << ours[0] << " exited " << a.exit_code << ", " << peer[0] << " exited "
                << b.exit_code << "\n";
      *ok = false;
      return {};
    }
    ours_wall.push_back(1e3 * a.wall_seconds), ours_cpu.push_back(1e3 * a.cpu_seconds);
    peer_wall.push_back(1e3 * b.wall_seconds), peer_cpu.push_back(1e3 * b.cpu_seconds);
    ratios.push_back(a.wall_seconds / b.wall_seconds);
  }
  return {{"ms", Median(ours_wall)}, {"cpu_ms", Median(ours_cpu)}, {"peer_ms", Median(peer_wall)},
          {"peer_cpu_ms", Median(peer_cpu)}, {"ms_above_peer", Median(ours_wall) - Median(peer_wall)},
          {"ratio_to_peer", Median(ratios)}};
}

}  // namespace

int main(int argc, char** argv) {
  std::string data = std::string(IBMR_SHARED_DIR) + "/datasets/middlebury_stereo_classic";
  std::string out = "bench_process_start.json";
  int repeat = 11;
  std::string ibmr = IBMR_BINARY;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--data") data = argv[i + 1];
    else if (key == "--out") out = argv[i + 1];
    else if (key == "--repeat") repeat = std::max(1, std::atoi(argv[i + 1]));
    else if (key == "--ibmr") ibmr = argv[i + 1];
    else {
      std::cerr << "bench_process_start: unknown option " << key << " (--data, --out, --repeat, --ibmr)\n";
      return 2;
    }
  }
  const std::string peer_start = PEER_OPENCV_START, peer_sgbm = PEER_SGBM_PAIR;
  bool ok = true;
  nlohmann::json report;
  report["repeat"] = repeat;
  report["ibmr"] = ibmr;
  report["start"] = Compare({ibmr, "--help"}, {peer_start}, repeat, &ok);
  struct Pair {
    std::string name, left, right, gt;
    double gt_scale;
    int max_disparity;
  };
  const std::vector<Pair> pairs = {
      {"tsukuba", "tsukuba/im3.png", "tsukuba/im4.png", "tsukuba/disp3.pgm", 16.0, 16},
      {"venus", "venus/im2.png", "venus/im6.png", "venus/disp2.pgm", 8.0, 32},
      {"teddy", "teddy/im2.png", "teddy/im6.png", "teddy/disp2.png", 4.0, 64},
  };
  const std::string scratch = out + ".d";
  std::filesystem::create_directories(scratch);
  for (const Pair& pair : pairs) {
    const std::string left = data + "/" + pair.left, right = data + "/" + pair.right;
    if (!std::filesystem::exists(left)) {
      std::cerr << "bench_process_start: " << left << " is missing (../shared/datasets beside the checkout?); pairs skipped\n";
      report["stereo_pair_skipped"] = left + " is missing";
      break;
    }
    const std::string ours_pfm = scratch + "/" + pair.name + "_ibmr.pfm", sgbm_pfm = scratch + "/" + pair.name + "_sgbm.pfm";
    bool pair_ok = true;
    nlohmann::json entry = Compare({ibmr, "stereo-pair", left, right, "--max-disparity", std::to_string(pair.max_disparity),
                                    "--out", ours_pfm},
                                   {peer_sgbm, left, right, std::to_string(pair.max_disparity), sgbm_pfm}, repeat, &pair_ok);
    ok = ok && pair_ok;
    if (!pair_ok) continue;
    const cv::Mat gt = ibmr::ReadImageUnchanged(data + "/" + pair.gt);
    entry["bad1"] = ibmr::ScoreDisparity(ibmr::ReadPfm(ours_pfm), gt, pair.gt_scale).bad1;
    entry["peer_bad1"] = ibmr::ScoreDisparity(ibmr::ReadPfm(sgbm_pfm), gt, pair.gt_scale).bad1;
    report["stereo_pair"][pair.name] = entry;
  }
  std::filesystem::remove_all(scratch);
  ibmr::WriteFileAtomic(out, report.dump(2) + "\n");
  std::cout << report.dump(2) << "\n";
  return ok ? 0 : 1;
}
