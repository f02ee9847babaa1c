// Tests for per-view checkpoints: marks count only with the same key, Clear removes them, and a
// default-constructed checkpoint does nothing.
#include "pipeline/core/view_checkpoint.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_view_checkpoint_" + name); }

TEST(ViewCheckpoint, MarksCountOnlyWithTheSameKey) {
  const std::string folder = (MakeTestDir("key") / "records" / "plane_sweep.views").string();
  const ViewCheckpoint checkpoint(folder, "key-1");
  EXPECT_FALSE(checkpoint.Done("img_001.jpg"));
  checkpoint.MarkDone("img_001.jpg");
  EXPECT_TRUE(checkpoint.Done("img_001.jpg"));
  EXPECT_FALSE(checkpoint.Done("img_002.jpg"));
  EXPECT_TRUE(fs::is_regular_file(folder + "/img_001.jpg.done"));

  const ViewCheckpoint changed(folder, "key-2");
  EXPECT_FALSE(changed.Done("img_001.jpg"));
  const ViewCheckpoint prefix(folder, "key-");
  EXPECT_FALSE(prefix.Done("img_001.jpg")) << "the content must equal the key, not start with it";
  changed.MarkDone("img_001.jpg");
  EXPECT_FALSE(checkpoint.Done("img_001.jpg"));
  EXPECT_TRUE(changed.Done("img_001.jpg"));
}

TEST(ViewCheckpoint, KeepsTheViewsPieceExactly) {
  const std::string folder = (MakeTestDir("piece") / "views").string();
  const ViewCheckpoint checkpoint(folder, "k");
  const nlohmann::json piece = {{"valid_fraction", 0.1 + 0.2}, {"pairs", {1e-17, 3.0, -2.5}}, {"from", "hull"}};
  checkpoint.MarkDone("sub/a.png", piece);
  ASSERT_TRUE(checkpoint.Piece("sub/a.png").has_value());
  EXPECT_EQ(*checkpoint.Piece("sub/a.png"), piece) << "doubles must come back bit for bit";
  EXPECT_FALSE(ViewCheckpoint(folder, "other").Piece("sub/a.png").has_value());
  WriteFileAtomic(folder + "/b.done", "k");  // a mark of the old plain-text layout, or garbage
  EXPECT_FALSE(checkpoint.Done("b")) << "an unreadable mark means the view is done again";
}

// A name whose mark would land outside the folder is refused, by name, before anything is written.
TEST(ViewCheckpoint, RefusesNamesThatLeaveTheFolder) {
  const fs::path root = MakeTestDir("escape");
  const ViewCheckpoint checkpoint((root / "records" / "score.views").string(), "k");
  for (const std::string name : {"/abs.png", "../up.png", "sub/../../up.png", ""}) {
    try {
      checkpoint.MarkDone(name);
      ADD_FAILURE() << "'" << name << "' was marked";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("'" + name + "'"), std::string::npos) << e.what();
    }
    EXPECT_THROW(checkpoint.Done(name), InputError) << name;
  }
  EXPECT_FALSE(fs::exists(root / "up.png.done"));
  EXPECT_FALSE(fs::exists(root / "records" / "up.png.done"));
  checkpoint.MarkDone("plane/sub/v0.png");  // folders inside are fine
  EXPECT_TRUE(checkpoint.Done("plane/sub/v0.png"));
}

TEST(ViewCheckpoint, ClearRemovesTheFolder) {
  const fs::path dir = MakeTestDir("clear");
  const std::string folder = (dir / "views").string();
  const ViewCheckpoint checkpoint(folder, "k");
  checkpoint.MarkDone("a");
  checkpoint.MarkDone("b");
  checkpoint.Clear();
  EXPECT_FALSE(fs::exists(folder));
  EXPECT_FALSE(checkpoint.Done("a"));
  checkpoint.Clear();  // clearing twice is fine
}

TEST(ViewCheckpoint, DefaultIsInert) {
  const ViewCheckpoint inert;
  inert.MarkDone("a");
  EXPECT_FALSE(inert.Done("a"));
  EXPECT_FALSE(fs::exists("a.done"));
  inert.Clear();
}

}  // namespace
}  // namespace ibmr
