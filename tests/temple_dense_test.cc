// End-to-end dense reconstruction on real photographs: five consecutive views of Middlebury
// templeSparseRing (full resolution, known cameras) through import -> silhouettes -> plane_sweep ->
// multi_depth -> fuse -> surfels, as configs/middlebury_temple_sparse.yaml runs all sixteen. The
// fused points must land on the temple: the fraction that projects onto the silhouettes of the
// dark-background threshold masks is read from the fuse record; the surfels and their mesh's
// vertices must land there too (checked here against masks/). Skipped with a message when
// ../shared/datasets is absent.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/surface_accuracy.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

const fs::path kTemple = fs::path(IBMR_SHARED_DIR) / "datasets" / "middlebury_templeSparseRing";

nlohmann::json Metrics(const fs::path& workspace, const std::string& stage) {
  std::ifstream in(workspace / "records" / (stage + ".json"));
  nlohmann::json record;
  in >> record;
  return record.at("metrics");
}

TEST(TempleDense, FusedPointsLandOnTheTemple) {
  if (!fs::exists(kTemple / "templeSR_par.txt")) {
    GTEST_SKIP() << kTemple << " is absent (../shared/datasets not beside the project); skipping";
  }
  const fs::path dir = fs::temp_directory_path() / ("ibmr_temple_dense_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir / "data");
  // A five-view subset: the par file's lines for templeSR0001..0005, images linked.
  std::ifstream par(kTemple / "templeSR_par.txt");
  std::string line;
  std::getline(par, line);  // view count
  std::ostringstream subset;
  int kept = 0;
  while (std::getline(par, line) && kept < 5) {
    const std::string name = line.substr(0, line.find(' '));
    fs::create_symlink(kTemple / name, dir / "data" / name);
    subset << line << "\n";
    ++kept;
  }
  ASSERT_EQ(kept, 5);
  std::ofstream(dir / "data" / "templeSR_par.txt") << kept << "\n" << subset.str();
  std::ofstream(dir / "c.yaml") << "workspace: ws\n"
                                   "stages:\n"
                                   "  - import: {source: data, format: middlebury}\n"
                                   "  - silhouettes: {mode: threshold, threshold: 0.2, dilate_px: 4, erode_px: 2}\n"
                                   "  - plane_sweep:\n"
                                   "      bounding_box: [-0.073568, 0.021728, -0.012445, 0.028855, 0.181892, 0.062736]\n"
                                   "      depth_margin: 0.05\n"
                                   "      num_planes: 96\n"
                                   "  - multi_depth: {min_consistent_views: 2}\n"
                                   "  - fuse: {input_type: geometric, min_views: 2}\n"
                                   "  - surfels: {}\n";
  const ibmr_e2e::CommandResult run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run " + (dir / "c.yaml").string());
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const fs::path ws = dir / "ws";
  for (int i = 1; i <= 5; ++i) {
    const std::string name = "templeSR000" + std::to_string(i) + ".png";
    EXPECT_TRUE(fs::exists(ws / "dense/stereo/depth_maps" / (name + ".geometric.bin"))) << name;
  }
  const nlohmann::json fuse = Metrics(ws, "fuse");
  std::cout << "[temple dense] " << fuse["points"] << " points, on the silhouettes: "
            << fuse["on_silhouette_fraction"] << " (worst view " << fuse["on_silhouette_fraction_min_view"] << ")"
            << std::endl;
  EXPECT_GT(fuse["points"].get<double>(), 20000);
  EXPECT_GE(fuse["on_silhouette_fraction"].get<double>(), 0.9);
  EXPECT_GE(fuse["on_silhouette_fraction_min_view"].get<double>(), 0.85);

  // The surfels and the mesh's vertices, projected into every view, land on its silhouette.
  const nlohmann::json surfels = Metrics(ws, "surfels");
  std::cout << "[temple dense] " << surfels["particles"] << " surfels, " << surfels["mesh_faces"] << " faces" << std::endl;
  EXPECT_GT(surfels["particles"].get<double>(), 3000);
  ibmr::PointCloud particles = ibmr::ReadPointCloudPly((ws / "surfels/surfels.ply").string());
  ibmr::PointCloud vertices;
  vertices.positions = ibmr::ReadMeshPly((ws / "surfels/mesh.ply").string()).vertices;
  EXPECT_GT(particles.size(), 3000u);
  EXPECT_EQ(particles.radius.size(), particles.size());
  const ibmr::SparseModel model = ibmr::ReadSparseModelText((ws / "sparse").string());
  for (const ibmr::PointCloud* cloud : {&particles, &vertices}) {
    ibmr::SilhouetteHits hits;
    for (const auto& [id, image] : model.images) {
      const cv::Mat mask = ibmr::ReadImageUnchanged((ws / "masks" / (image.name + ".png")).string());
      const ibmr::SilhouetteHits view = ibmr::ProjectOntoSilhouette(*cloud, model.CameraOf(image), image.cam_from_world, mask);
      hits.projected += view.projected;
      hits.on_silhouette += view.on_silhouette;
    }
    // 0.85 measured (the fused points: 0.92 by count, but thinning weighs sparse stray clusters
    // as much as the densely seen surface; with five views free space prunes little).
    EXPECT_GE(hits.Fraction(), 0.8) << cloud->size() << " points";
  }
  fs::remove_all(dir);
}

}  // namespace
