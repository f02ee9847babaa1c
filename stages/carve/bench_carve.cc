// Benchmark of octree carving (seed 000 lines 4136-4258): the synthetic object ring (24 views,
// 320x240, exact masks) carved to levels 5..9. Per run: wall time, nodes per level and their
// ratio (the paper's claim: node count grows like the surface, ~4x per level, not the volume, 8x),
// octree memory and the process's peak resident memory. Writes JSON to the path given as the first
// argument (default: stdout).
//   build-carve/stages/carve/bench_carve bench_carve.json [max_level]
#include <sys/resource.h>

#include <chrono>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "pipeline/core/process_memory.h"
#include "stages/carve/carve.h"
#include "stages/synth/synth.h"

namespace {

double PeakResidentMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;  // Linux: kilobytes
}

}  // namespace

int main(int argc, char** argv) {
  ibmr::ConfigureHeap(argv);  // as ibmr does (pipeline/core/process_memory.h)
  using namespace ibmr;
  if (argc > 1 && argv[1][0] == '-') {
    std::cout << "usage: bench_carve [OUT.json [MAX_LEVEL (9)]]   levels 5..MAX_LEVEL on the synthetic ring\n";
    return std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h" ? 0 : 2;
  }
  const int max_level = argc > 2 ? std::atoi(argv[2]) : 9;
  SynthOptions synth;  // object_ring, 24 views, 320x240
  synth.sparse_points = 0;
  const SynthScene scene = BuildSynthScene(synth);
  std::vector<CarveView> views;
  for (int i = 0; i < static_cast<int>(scene.views.size()); ++i) {
    views.push_back(CarveView{scene.views[i].name, scene.camera, scene.views[i].cam_from_world,
                              RenderSynthView(scene, i, synth).mask});
  }
  const Eigen::AlignedBox3d& box = scene.foreground_bounds;
  const double size = 1.1 * box.sizes().maxCoeff();
  const Eigen::Vector3d origin = box.center() - Eigen::Vector3d::Constant(0.5 * size);
  nlohmann::json runs = nlohmann::json::array();
  for (int level = 5; level <= max_level; ++level) {
    CarveOptions options;
    options.levels = level;
    const auto start = std::chrono::steady_clock::now();
    const CarveResult result = CarveOctree(views, origin, size, options);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    nlohmann::json nodes = nlohmann::json::array(), ratios = nlohmann::json::array(), per_level = nlohmann::json::array();
    size_t total = 0;
    for (const LevelStats& s : result.stats) {
      nodes.push_back(s.nodes);
      total += s.nodes;
      if (s.level > 0) ratios.push_back(static_cast<double>(s.nodes) / result.stats[s.level - 1].nodes);
      per_level.push_back({{"level", s.level}, {"nodes", s.nodes}, {"full", s.full}, {"partial", s.partial},
                           {"empty", s.empty}, {"seconds", s.seconds}});
    }
    const size_t hull_cells = HullCells(result.octree, level).size();
    runs.push_back({{"levels", level},
                    {"seconds", seconds},
                    {"nodes_total", total},
                    {"nodes_per_level", nodes},
                    {"node_ratios", ratios},
                    {"per_level", per_level},
                    {"hull_cells", hull_cells},
                    {"octree_mb", total * sizeof(OctreeNode) / 1048576.0},
                    {"peak_resident_mb_so_far", PeakResidentMb()}});
    std::cerr << "levels " << level << ": " << seconds << " s, " << total << " nodes, last ratio "
              << ratios.back() << std::endl;
  }
  const nlohmann::json out = {{"benchmark", "carve"},
                              {"scene", "synth object_ring, 24 views 320x240, exact masks"},
                              {"root_cube_size", size},
                              {"threads", "TBB default (all cores)"},
                              {"runs", runs}};
  if (argc > 1) {
    std::ofstream(argv[1]) << out.dump(2) << "\n";
  } else {
    std::cout << out.dump(2) << "\n";
  }
  return 0;
}
