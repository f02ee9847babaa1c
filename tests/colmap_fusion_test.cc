// COLMAP's own tools run on the project's dense workspace: after synth -> undistort -> plane_sweep
// -> multi_depth, dense/ holds images/, sparse/ (with triangulated points, so that COLMAP finds
// overlapping views), stereo/{depth,normal}_maps/ and the patch-match.cfg and fusion.cfg that
// COLMAP reads; `colmap stereo_fusion --workspace_path dense` fuses points, and they lie on the
// synthetic object; and on templeSparseRing's imported cameras once sfm.known_poses has
// triangulated points for them. Skipped where COLMAP is not installed.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "pipeline/core/ply_io.h"
#include "pipeline/core/surface_accuracy.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

// Runs `stages` (YAML lines) in a fresh workspace under a temporary root, with `inputs` (YAML
// lines, may be empty); returns the root (ws/ inside it) or an empty path when the run failed.
fs::path RunPipeline(const std::string& name, const std::string& inputs, const std::string& stages) {
  const fs::path root = fs::temp_directory_path() / (name + "_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root);
  std::ofstream(root / "c.yaml") << "workspace: ws\n" << inputs << "stages:\n" << stages;
  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run '" + (root / "c.yaml").string() + "'");
  EXPECT_EQ(run.exit_code, 0) << run.output;
  return run.exit_code == 0 ? root : fs::path();
}

TEST(ColmapFusion, StereoFusionFusesTheProjectsDepthMaps) {
  if (ibmr_e2e::RunCommand("command -v colmap").exit_code != 0) {
    GTEST_SKIP() << "colmap is not installed (scripts/setup installs it); skipped";
  }
  const fs::path root = RunPipeline("ibmr_colmap_fusion", "",
                                    "  - synth: {scene: object_ring, views: 12, width: 320, height: 240}\n"
                                    "  - undistort: {}\n"
                                    "  - plane_sweep: {num_planes: 64}\n"
                                    "  - multi_depth: {}\n");
  ASSERT_FALSE(root.empty());
  const fs::path dense = root / "ws/dense";
  for (const char* file : {"stereo/patch-match.cfg", "stereo/fusion.cfg", "sparse/points3D.txt"}) {
    ASSERT_TRUE(fs::exists(dense / file)) << file;
  }
  // Each view's depth map is seen by few others in a ring of 12, so two consistent pixels suffice.
  const fs::path fused = root / "colmap_fused.ply";
  const auto fusion = ibmr_e2e::RunCommand("colmap stereo_fusion --workspace_path '" + dense.string() +
                                           "' --input_type geometric --StereoFusion.min_num_pixels 2 --output_path '" +
                                           fused.string() + "'");
  ASSERT_EQ(fusion.exit_code, 0) << fusion.output;
  const ibmr::PointCloud cloud = ibmr::ReadPointCloudPly(fused.string());
  EXPECT_GT(cloud.size(), 2000u) << fusion.output;
  // On the object (radius ~1): 90% of COLMAP's points within 2% of its radius of the true surface.
  const ibmr::TriangleMesh truth = ibmr::ReadMeshPly((root / "ws/ground_truth/mesh.ply").string());
  const ibmr::PointSetAccuracy accuracy =
      ibmr::EvaluatePointSet(cloud, truth, ibmr::SampleSurface(truth, 20000), 0.02);
  EXPECT_LT(accuracy.accuracy_90, 0.02) << "median " << accuracy.accuracy_median;
  std::cout << "colmap stereo_fusion: " << cloud.size() << " points, 90% within " << accuracy.accuracy_90
            << " of the true surface (median " << accuracy.accuracy_median << ")\n";
  fs::remove_all(root);
}

// Imported cameras (Middlebury's, no sparse points): sfm.known_poses keeps them and triangulates
// points with COLMAP, so that stereo_fusion finds the overlapping views of the project's maps.
TEST(ColmapFusion, KnownPosesGetPointsSoThatStereoFusionFuses) {
  const fs::path temple = fs::path(IBMR_SOURCE_DIR) / "../shared/datasets/middlebury_templeSparseRing";
  if (ibmr_e2e::RunCommand("command -v colmap").exit_code != 0) GTEST_SKIP() << "colmap is not installed; skipped";
  if (!fs::exists(temple)) GTEST_SKIP() << temple << " is absent; real-data test skipped";
  const fs::path root = RunPipeline("ibmr_colmap_known_poses", "inputs:\n  images: " + temple.string() + "\n",
                                    "  - import: {format: middlebury}\n"
                                    "  - sfm: {known_poses: true, max_image_size: 640}\n"
                                    "  - undistort: {}\n"
                                    "  - plane_sweep: {num_planes: 64}\n"
                                    "  - multi_depth: {}\n");
  ASSERT_FALSE(root.empty());
  const fs::path dense = root / "ws/dense";
  std::ifstream points(dense / "sparse/points3D.txt");
  size_t lines = 0;
  for (std::string line; std::getline(points, line);) lines += !line.empty() && line[0] != '#';
  EXPECT_GT(lines, 500u);
  const fs::path fused = root / "colmap_fused.ply";
  const auto fusion = ibmr_e2e::RunCommand("colmap stereo_fusion --workspace_path '" + dense.string() +
                                           "' --input_type geometric --output_path '" + fused.string() + "'");
  ASSERT_EQ(fusion.exit_code, 0) << fusion.output;
  const size_t fused_points = ibmr::ReadPointCloudPly(fused.string()).size();
  EXPECT_GT(fused_points, 1000u) << fusion.output;  // none without the sparse points
  std::cout << "templeSparseRing, known poses: " << lines << " sparse points, colmap stereo_fusion " << fused_points
            << " points\n";
  fs::remove_all(root);
}

}  // namespace
