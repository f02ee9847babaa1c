// A synthetic scene exported as transforms.json (`ibmr export-transforms`) and imported again
// (`import: {format: transforms}`) has the same cameras within 1e-9: poses, focal lengths,
// principal points and sizes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/colmap_text_io.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

TEST(NerfRoundTrip, SynthExportedAndReimportedKeepsItsCameras) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_nerf_roundtrip_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root);
  std::ofstream(root / "synth.yaml") << "workspace: a\nstages:\n  - synth: {scene: object_ring, views: 8, width: 80, height: 60}\n";
  std::ofstream(root / "import.yaml") << "workspace: b\ninputs:\n  images: a\nstages:\n  - import: {format: transforms}\n";
  const std::string ibmr = IBMR_BINARY;
  auto run = ibmr_e2e::RunCommand(ibmr + " run " + (root / "synth.yaml").string());
  ASSERT_EQ(run.exit_code, 0) << run.output;
  run = ibmr_e2e::RunCommand(ibmr + " export-transforms " + (root / "a").string());
  ASSERT_EQ(run.exit_code, 0) << run.output;
  ASSERT_TRUE(fs::exists(root / "a" / "transforms.json"));
  run = ibmr_e2e::RunCommand(ibmr + " run " + (root / "import.yaml").string());
  ASSERT_EQ(run.exit_code, 0) << run.output;

  const ibmr::SparseModel a = ibmr::ReadSparseModelText((root / "a" / "sparse").string());
  const ibmr::SparseModel b = ibmr::ReadSparseModelText((root / "b" / "sparse").string());
  ASSERT_EQ(a.images.size(), 8u);
  ASSERT_EQ(b.images.size(), 8u);
  for (const auto& [id, image] : a.images) {
    const ibmr::Image* other = b.FindImage("images/" + image.name);
    ASSERT_NE(other, nullptr) << image.name;
    EXPECT_LT((image.cam_from_world.R() - other->cam_from_world.R()).norm(), 1e-9);
    EXPECT_LT((image.Center() - other->Center()).norm(), 1e-9);
    const ibmr::Camera& ca = a.CameraOf(image);
    const ibmr::Camera& cb = b.CameraOf(*other);
    EXPECT_EQ(ca.width, cb.width);
    EXPECT_EQ(ca.height, cb.height);
    EXPECT_NEAR(ca.FocalX(), cb.FocalX(), 1e-9);
    EXPECT_NEAR(ca.FocalY(), cb.FocalY(), 1e-9);
    EXPECT_NEAR(ca.PrincipalX(), cb.PrincipalX(), 1e-9);
    EXPECT_NEAR(ca.PrincipalY(), cb.PrincipalY(), 1e-9);
    EXPECT_TRUE(fs::exists(root / "b" / "images" / "images" / image.name)) << image.name;
  }
  if (!::testing::Test::HasFailure()) fs::remove_all(root);
}
