// plane_sweep.max_image_size (COLMAP's name and meaning): views larger than it are matched
// downscaled and their maps written at that size; the stages after it (multi_depth, fuse,
// surfels, render) take each map's camera scaled to the map. On the synthetic ring at 320x240
// matched at 200 px: the maps are 200x150, and the fused points still lie on the true surface (a
// camera not scaled with its map would put them off by whole percents of the object).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/colmap_array_io.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

TEST(ReducedSizeMaps, TheStagesAfterThePlaneSweepUseTheMapsCamera) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_reduced_maps_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root);
  std::ofstream(root / "c.yaml") << "workspace: ws\nstages:\n"
                                    "  - synth: {scene: object_ring, views: 12, width: 320, height: 240}\n"
                                    "  - plane_sweep: {num_planes: 64, max_image_size: 200}\n"
                                    "  - multi_depth: {}\n"
                                    "  - fuse: {}\n"
                                    "  - surfels: {use_hull: false}\n"
                                    "  - render: {proxies: [splat_depth, surfels=surfels/mesh.ply], views: [view_000.png]}\n";
  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run '" + (root / "c.yaml").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const fs::path ws = root / "ws";
  for (const char* kind : {"photometric", "geometric"}) {
    const ibmr::DepthMap depth =
        ibmr::ReadColmapArray((ws / ("dense/stereo/depth_maps/view_001.png." + std::string(kind) + ".bin")).string());
    EXPECT_EQ(depth.width, 200) << kind;
    EXPECT_EQ(depth.height, 150) << kind;
  }
  nlohmann::json fuse;
  std::ifstream(ws / "records/fuse.json") >> fuse;
  // Full size gives 0.0098 (object radius ~1); a 200 px map's pixel is 1.6 times larger.
  EXPECT_LT(fuse["metrics"]["accuracy_90"].get<double>(), 0.025) << fuse["metrics"].dump();
  EXPECT_GT(fuse["metrics"]["points"].get<int>(), 5000);
  EXPECT_TRUE(fs::exists(ws / "renders/splat_depth/view_000.png"));
  fs::remove_all(root);
}

}  // namespace
