// The texture stage and its two renderers end to end on the synthetic object ring
// (configs/synth_texture.yaml): held-out PSNR of the static atlas and of view-dependent texture
// mapping against the true images, real tools reading the written OBJ and GLB, seam leveling
// under per-view exposure differences, and bad meshes (no faces, degenerate faces, out of view).
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pipeline/core/ply_io.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

class TexturedSynth : public ::testing::Test {
 protected:
  void SetUp() override {
    root_ = fs::temp_directory_path() / ("ibmr_textured_synth_" + std::to_string(::getpid()));
    fs::remove_all(root_);
    fs::create_directories(root_);
  }
  void TearDown() override { fs::remove_all(root_); }

  ibmr_e2e::CommandResult Ibmr(const std::string& args) {
    return ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " " + args + " 2>&1");
  }
  static nlohmann::json Json(const fs::path& path) {
    nlohmann::json json;
    std::ifstream(path) >> json;
    return json;
  }
  fs::path root_;
};

// `assimp info` (Debian assimp-utils) on a file: the faces it counts, -1 when it cannot.
int AssimpFaces(const fs::path& path) {
  const auto run = ibmr_e2e::RunCommand("assimp info '" + path.string() + "' 2>&1");
  std::istringstream lines(run.output);
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("Faces:", 0) == 0) return std::stoi(line.substr(6));
  }
  return -1;
}

TEST_F(TexturedSynth, TheAtlasAndViewDependentTexturingPredictHeldOutViews) {
  const fs::path ws = root_ / "ws";
  const auto run = Ibmr("run '" + std::string(IBMR_SOURCE_DIR) + "/configs/synth_texture.yaml' --workspace '" + ws.string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const nlohmann::json scores = Json(ws / "scores/heldout.json");
  const double ulr = scores["proxies"]["ground_truth_mesh"]["mean"]["psnr"];
  const double textured = scores["proxies"]["textured"]["mean"]["psnr"];
  const double vdtm = scores["proxies"]["vdtm"]["mean"]["psnr"];
  EXPECT_GE(textured, 35.0) << "ULR on the same mesh: " << ulr;
  EXPECT_GE(vdtm, 35.0) << "ULR on the same mesh: " << ulr;

  const nlohmann::json record = Json(ws / "records/texture.json");
  const int faces = record["metrics"]["faces"];
  EXPECT_EQ(faces, 20480);
  EXPECT_GT(record["metrics"]["faces_seen"].get<int>(), faces * 8 / 10);
  const auto energies = record["metrics"]["selection_energies"].get<std::vector<double>>();
  for (size_t i = 1; i < energies.size(); ++i) EXPECT_LE(energies[i], energies[i - 1] + 1e-9);

  // The OBJ's texture coordinates lie in [0, 1]; real tools read both files with every face.
  std::ifstream obj(ws / "texture/mesh.obj");
  size_t vt = 0;
  for (std::string line; std::getline(obj, line);) {
    if (line.rfind("vt ", 0) != 0) continue;
    std::istringstream in(line.substr(3));
    double u = -1, v = -1;
    in >> u >> v;
    EXPECT_TRUE(u >= 0 && u <= 1 && v >= 0 && v <= 1) << line;
    ++vt;
  }
  EXPECT_GT(vt, 0u);
  if (ibmr_e2e::RunCommand("command -v assimp >/dev/null").exit_code != 0) {
    GTEST_SKIP() << "assimp (Debian package assimp-utils, installed by scripts/test.sh) is missing: the OBJ/GLB "
                    "reading check did not run";
  }
  EXPECT_EQ(AssimpFaces(ws / "texture/mesh.obj"), faces);
  EXPECT_EQ(AssimpFaces(ws / "texture/mesh.glb"), faces);
}

// Each view's exposure off by up to 50% (synth's exposure degradation): the gains and the seam
// leveling at least halve the colour step across the patch borders of the atlas.
TEST_F(TexturedSynth, ExposureDifferencesAreLeveledAtTheSeams) {
  std::ofstream(root_ / "c.yaml") << "workspace: ws\nholdout: {every: 8}\nstages:\n"
                                     "  - synth: {scene: object_ring, views: 16, width: 320, height: 240, degradation: exposure, strength: 1}\n"
                                     "  - texture: {mesh: ground_truth/mesh.ply}\n";
  const auto step = [&](bool leveled) {
    const std::string flags = leveled ? "" : " --set texture.gain_compensation=false --set texture.seam_leveling=false";
    const auto run = Ibmr("run '" + (root_ / "c.yaml").string() + "'" + flags);
    EXPECT_EQ(run.exit_code, 0) << run.output;
    return Json(root_ / "ws/records/texture.json")["metrics"]["seam_step_atlas"].get<double>();
  };
  const double without = step(false);
  std::ofstream(root_ / "ws/texture/atlas_7.png") << "a page of an earlier run with more pages";
  const double with = step(true);
  EXPECT_FALSE(fs::exists(root_ / "ws/texture/atlas_7.png")) << "a stale page stayed beside the new atlas";
  EXPECT_GT(without, 5.0) << "the exposure differences show at the seams";
  EXPECT_LE(with, 0.5 * without) << "leveled " << with << " against " << without;
}

// A mesh without faces is refused naming the file; degenerate faces and a mesh no view sees are
// warned about, and the stage still writes an atlas (hole-filled).
TEST_F(TexturedSynth, BadMeshesGetClearMessages) {
  const fs::path ws = root_ / "ws";
  std::ofstream(root_ / "c.yaml") << "workspace: ws\nstages:\n"
                                     "  - synth: {scene: object_ring, views: 6, width: 160, height: 120}\n"
                                     "  - texture: {mesh: user.ply}\n";
  auto run = Ibmr("run '" + (root_ / "c.yaml").string() + "'");
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.output.find("user.ply does not exist"), std::string::npos) << run.output;

  ibmr::TriangleMesh points;
  points.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  ibmr::WriteMeshPly((ws / "user.ply").string(), points);
  run = Ibmr("run '" + (root_ / "c.yaml").string() + "'");
  EXPECT_NE(run.exit_code, 0);
  EXPECT_NE(run.output.find("user.ply: the mesh has no faces"), std::string::npos) << run.output;

  // Far outside every view, with one zero-area face.
  ibmr::TriangleMesh away;
  away.vertices = {{100, 100, 100}, {101, 100, 100}, {100, 101, 100}, {102, 100, 100}};
  away.faces = {{0, 1, 2}, {0, 1, 3}};
  ibmr::WriteMeshPly((ws / "user.ply").string(), away);
  run = Ibmr("run '" + (root_ / "c.yaml").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("1 degenerate face(s)"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("sees no face of the mesh"), std::string::npos) << run.output;
  EXPECT_EQ(Json(ws / "records/texture.json")["metrics"]["faces_unseen"].get<int>(), 2);
  EXPECT_TRUE(fs::exists(ws / "texture/mesh.glb"));
}

}  // namespace
