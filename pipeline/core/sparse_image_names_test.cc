// The cache of a model folder's image names (sparse_image_names.h): names sorted as the model
// orders them, read again when a file changes (an atomic rewrite, a file removed), and errors and
// missing models reported, not cached as names.
#include "pipeline/core/sparse_image_names.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/colmap_text_io.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

SparseModel ModelWithImages(const std::vector<std::string>& names) {
  SparseModel model;
  model.cameras[1] = Camera::Pinhole(64, 48, 50, 50, 32, 24);
  model.cameras[1].camera_id = 1;
  int id = 1;
  for (const std::string& name : names) {
    Image image;
    image.image_id = id++;
    image.camera_id = 1;
    image.name = name;
    model.images[image.image_id] = image;
  }
  return model;
}

TEST(SparseImageNames, ReadAgainWhenTheModelIsRewritten) {
  const fs::path dir = fs::path(::testing::TempDir()) / "sparse_image_names_cache";
  fs::remove_all(dir);
  fs::create_directories(dir);
  WriteSparseModelText(dir.string(), ModelWithImages({"b.png", "a.png"}));
  const SparseImageNames first = ReadSparseImageNamesCached(dir.string());
  ASSERT_TRUE(first.readable) << first.error;
  EXPECT_EQ(first.names, (std::vector<std::string>{"a.png", "b.png"}));
  EXPECT_EQ(ReadSparseImageNamesCached(dir.string()).names, first.names);

  // A new model written the way the stages write (temporary file, then rename): a new version,
  // even within the same clock tick and at the same size.
  WriteSparseModelText(dir.string(), ModelWithImages({"c.png", "d.png"}));
  EXPECT_EQ(ReadSparseImageNamesCached(dir.string()).names, (std::vector<std::string>{"c.png", "d.png"}));

  // A broken images.txt: not readable, with the reader's message; the names are not kept.
  std::ofstream(dir / "images.txt") << "1 not a pose\n";
  const SparseImageNames broken = ReadSparseImageNamesCached(dir.string());
  EXPECT_FALSE(broken.readable);
  EXPECT_TRUE(broken.names.empty());
  EXPECT_NE(broken.error.find("images.txt"), std::string::npos) << broken.error;

  // No images.txt: not readable, and nothing to report.
  fs::remove(dir / "images.txt");
  const SparseImageNames missing = ReadSparseImageNamesCached(dir.string());
  EXPECT_FALSE(missing.readable);
  EXPECT_TRUE(missing.error.empty()) << missing.error;
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ibmr
