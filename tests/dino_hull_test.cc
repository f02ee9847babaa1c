// The shipped dinoSparseRing config's hull mesh fits the silhouettes it was carved from: the carve
// record's mesh_iou_median (hull.ply rasterized into each training view against its mask) is at
// least 0.95, and the mesh still claims to enclose the hull. Skipped with a message when
// ../shared/datasets is absent.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "tests/run_command.h"

namespace fs = std::filesystem;

TEST(DinoHull, MeshFitsTheSilhouettes) {
  const fs::path data = fs::path(IBMR_SHARED_DIR) / "datasets" / "middlebury_dinoSparseRing";
  if (!fs::exists(data)) GTEST_SKIP() << data << " is absent (../shared/datasets not beside the project); skipping";
  const fs::path ws = fs::temp_directory_path() / ("ibmr_dino_hull_" + std::to_string(::getpid()));
  fs::remove_all(ws);
  const auto run = ibmr_e2e::RunCommand("IBMR_WORKSPACE=" + ws.string() + " " + IBMR_BINARY + " run " +
                                        IBMR_SOURCE_DIR + "/configs/middlebury_dino_sparse.yaml");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  nlohmann::json record;
  std::ifstream(ws / "records" / "carve.json") >> record;
  const nlohmann::json& metrics = record.at("metrics");
  std::cout << "dinoSparseRing hull mesh IoU: median " << metrics["mesh_iou_median"] << ", min " << metrics["mesh_iou_min"]
            << "; octree cells " << metrics["training_iou_median_finest"] << "\n";
  EXPECT_GE(metrics["mesh_iou_median"].get<double>(), 0.95);
  EXPECT_GE(metrics["mesh_iou_min"].get<double>(), 0.9);
  std::ifstream mesh(ws / "hull" / "hull.ply");
  std::string header((std::istreambuf_iterator<char>(mesh)), {});
  EXPECT_NE(header.substr(0, 400).find("ibmr conservative_hull 1"), std::string::npos);
  if (!::testing::Test::HasFailure()) fs::remove_all(ws);
}
