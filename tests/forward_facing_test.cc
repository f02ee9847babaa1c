// A forward-facing capture end to end, as a user runs one: the synthetic forward-facing scene
// (the room with thin occluders, a grid of cameras) written as an LLFF folder (images_4/ and
// poses_bounds.npy with each view's near/far bounds), then configs/llff.yaml: import (the bounds
// recorded, no depth range in the config), plane_sweep ... volume, render, score. The volume of
// planes must take its depth range from the capture's bounds and predict the held-out photos
// better than every other model over the full image. Small (168 x 126, 12 views) so that it runs
// in seconds; the acceptance figures at 1008 x 756 are in the closing notes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/nerf_formats.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

std::string Ibmr(const std::string& arguments) { return std::string(IBMR_BINARY) + " " + arguments; }

// An LLFF folder from a synth workspace: images_4/ holds the photos, poses_bounds.npy the cameras
// at 4 times the size and the bounds of the sparse points each view sees.
void WriteLlffFolder(const fs::path& synth, const fs::path& llff) {
  ibmr::SparseModel model = ibmr::ReadSparseModelText((synth / "sparse").string());
  fs::create_directories(llff / "images_4");
  std::vector<std::string> names;
  std::vector<std::pair<double, double>> bounds;
  for (const int id : model.ImageIdsByName()) {
    const ibmr::Image& image = model.images.at(id);
    names.push_back(image.name);
    fs::copy_file(synth / "images" / image.name, llff / "images_4" / image.name);
    double near = 1e300, far = 0;
    for (const auto& [point_id, point] : model.points) {
      const double z = (image.cam_from_world * point.xyz).z();
      if (z > 0) near = std::min(near, z), far = std::max(far, z);
    }
    bounds.emplace_back(0.9 * near, 1.1 * far);
  }
  for (auto& [camera_id, camera] : model.cameras) camera = camera.Scaled(4.0);
  ibmr::WriteFileAtomic((llff / "poses_bounds.npy").string(), ibmr::WritePosesBounds(model, names, bounds));
}

TEST(ForwardFacing, AnLlffFolderRunsToScoresAndTheVolumePredictsBest) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_forward_facing_" + std::to_string(::getpid()));
  fs::remove_all(root);
  const std::string source = IBMR_SOURCE_DIR;
  const auto synth = ibmr_e2e::RunCommand(Ibmr("run '" + source + "/configs/synth_forward.yaml' --workspace '" +
                                               (root / "synth").string() + "' --only synth --set synth.width=168 "
                                               "--set synth.height=126 --set synth.views=12"));
  ASSERT_EQ(synth.exit_code, 0) << synth.output;
  WriteLlffFolder(root / "synth", root / "llff");
  const auto run = ibmr_e2e::RunCommand("IBMR_IMAGES='" + (root / "llff").string() + "' " +
                                        Ibmr("run '" + source + "/configs/llff.yaml' --workspace '" +
                                             (root / "ws").string() + "' --set layered_stereo.max_layers=4 --set splat_fit.iterations=300"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  nlohmann::json record, scores;
  std::ifstream(root / "ws/records/volume.json") >> record;
  std::ifstream(root / "ws/scores/heldout.json") >> scores;
  const nlohmann::json& volume = record["metrics"]["volumes"][0];
  EXPECT_EQ(volume["depth_source"], "sparse/depth_bounds.json") << volume.dump();
  EXPECT_LT(volume["final_data"].get<double>(), volume["initial_data"].get<double>());
  EXPECT_TRUE(fs::exists(root / "ws/volume/mean/plane_000.png"));
  const double volume_psnr = scores["proxies"]["volume"]["mean"]["photo_psnr"];
  for (const auto& [name, model] : scores["proxies"].items()) {
    if (name == "volume" || !model.contains("mean")) continue;  // the models the race left out have no means
    EXPECT_GT(volume_psnr, model["mean"]["photo_psnr"].get<double>()) << "volume against " << name;
  }
  EXPECT_GT(volume_psnr, 27.0);
  // llff.yaml races the models at a quarter of the size first: the volume wins there too, and the
  // stages feeding only the others are left out of the full-size run.
  nlohmann::json race;
  std::ifstream(root / "ws/race.json") >> race;
  EXPECT_EQ(race["best"], "volume") << race.dump();
  EXPECT_FALSE(race["left_out"].empty()) << race.dump();
  EXPECT_TRUE(scores["proxies"]["plane"].contains("mean"));  // drawn from the capture alone: always kept
  // The report shows the planes as a strip (volume/mean/strip.png embedded).
  const auto report = ibmr_e2e::RunCommand(Ibmr("report '" + (root / "ws").string() + "'"));
  ASSERT_EQ(report.exit_code, 0) << report.output;
  std::ifstream page(root / "ws/report/index.html");
  const std::string html((std::istreambuf_iterator<char>(page)), std::istreambuf_iterator<char>());
  EXPECT_NE(html.find("\"volume_strips\":[{\"folder\":\"volume/mean\""), std::string::npos);
  fs::remove_all(root);
}

}  // namespace

// What a user is told when the volume cannot be made: each message names what to set.
TEST(ForwardFacing, TheVolumeStageNamesWhatToSet) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_volume_errors_" + std::to_string(::getpid()));
  fs::remove_all(root);
  const std::string config = "'" + std::string(IBMR_SOURCE_DIR) + "/configs/synth_forward.yaml'";
  const std::string small = " --set synth.width=64 --set synth.height=48 --set synth.views=6";
  const auto volume = [&](const std::string& workspace, const std::string& more) {
    const std::string ws = " --workspace '" + (root / workspace).string() + "'";
    const auto synth = ibmr_e2e::RunCommand(Ibmr("run " + config + ws + " --only synth" + small + more));
    EXPECT_EQ(synth.exit_code, 0) << synth.output;
    return ibmr_e2e::RunCommand(Ibmr("run " + config + ws + " --only volume" + small + more));
  };
  // No sparse points, no bounds file, no range in the config.
  const auto no_range = volume("no_range", " --set synth.sparse_points=0");
  EXPECT_NE(no_range.exit_code, 0);
  EXPECT_NE(no_range.output.find("volume.min_depth"), std::string::npos) << no_range.output;
  // A budget the volume does not fit.
  const auto too_large = volume("too_large", " --set volume.max_memory_mb=1");
  EXPECT_NE(too_large.exit_code, 0);
  EXPECT_NE(too_large.output.find("volume.max_memory_mb"), std::string::npos) << too_large.output;
  EXPECT_NE(too_large.output.find("volume.num_planes"), std::string::npos) << too_large.output;
  // Two views, every 8th held out: one training view.
  const auto one_view = volume("one_view", " --set synth.views=2");
  EXPECT_NE(one_view.exit_code, 0);
  EXPECT_NE(one_view.output.find("at least 2 training views"), std::string::npos) << one_view.output;
  // Both bounds or neither: refused when the config is read.
  const auto half_range = ibmr_e2e::RunCommand(Ibmr("run " + config + " --workspace '" + (root / "half").string() +
                                                    "' --only volume --set volume.min_depth=1"));
  EXPECT_NE(half_range.exit_code, 0);
  EXPECT_NE(half_range.output.find("max_depth"), std::string::npos) << half_range.output;
  // A local volume fitted to one view.
  const auto one_per_volume = ibmr_e2e::RunCommand(Ibmr("run " + config + " --workspace '" + (root / "half").string() +
                                                        "' --only volume --set volume.views_per_volume=1"));
  EXPECT_NE(one_per_volume.exit_code, 0);
  EXPECT_NE(one_per_volume.output.find("views_per_volume"), std::string::npos) << one_per_volume.output;
  fs::remove_all(root);
}
