// Tests for content hashes: format, file == bytes, folder hashes that react to contents and
// names but not to creation order or to temporaries of atomic writes, and "missing".
#include "pipeline/core/content_hash.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_content_hash_" + name); }

TEST(ContentHash, BytesAreHex16AndDiscriminate) {
  const std::string a = HashBytes("hello");
  EXPECT_EQ(a.size(), 16u);
  EXPECT_EQ(a.find_first_not_of("0123456789abcdef"), std::string::npos) << a;
  EXPECT_EQ(a, HashBytes("hello"));
  EXPECT_NE(a, HashBytes("hellp"));
  EXPECT_NE(HashBytes(""), HashBytes(std::string(1, '\0')));
}

TEST(ContentHash, FileEqualsBytesIncludingLargeFiles) {
  const fs::path dir = MakeTestDir("file");
  std::string big(3 * 1024 * 1024 + 17, '\0');
  for (size_t i = 0; i < big.size(); ++i) big[i] = static_cast<char>((i * 2654435761u) >> 13);
  WriteFileAtomic((dir / "big.bin").string(), big);
  EXPECT_EQ(HashPath((dir / "big.bin").string()), HashBytes(big));
  WriteFileAtomic((dir / "small.txt").string(), "abc");
  EXPECT_EQ(HashPath((dir / "small.txt").string()), HashBytes("abc"));
}

TEST(ContentHash, MissingPath) { EXPECT_EQ(HashPath((MakeTestDir("missing") / "none").string()), "missing"); }

TEST(ContentHash, FolderReactsToContentsAndNames) {
  const fs::path one = MakeTestDir("one");
  const fs::path two = MakeTestDir("two");
  // Same files created in a different order give the same hash.
  WriteFileAtomic((one / "a.txt").string(), "A");
  WriteFileAtomic((one / "sub" / "b.txt").string(), "B");
  WriteFileAtomic((two / "sub" / "b.txt").string(), "B");
  WriteFileAtomic((two / "a.txt").string(), "A");
  const std::string base = HashPath(one.string());
  EXPECT_EQ(base, HashPath(two.string()));
  EXPECT_NE(base, "missing");

  WriteFileAtomic((two / "a.txt").string(), "changed");
  EXPECT_NE(HashPath(two.string()), base);
  WriteFileAtomic((two / "a.txt").string(), "A");
  EXPECT_EQ(HashPath(two.string()), base);

  fs::rename(two / "a.txt", two / "c.txt");
  EXPECT_NE(HashPath(two.string()), base) << "renaming a file must change the hash";
  fs::rename(two / "c.txt", two / "a.txt");

  fs::create_directories(two / "empty_subfolder");
  EXPECT_EQ(HashPath(two.string()), base);
  EXPECT_NE(HashPath((two / "empty_subfolder").string()), HashBytes("")) << "an empty folder is not an empty file";
}

TEST(ContentHash, FolderSkipsTemporariesOfAtomicWrites) {
  const fs::path dir = MakeTestDir("tmp");
  WriteFileAtomic((dir / "depth.bin").string(), "D");
  const std::string base = HashPath(dir.string());
  WriteFileAtomic((dir / "depth.bin.tmp.12345").string(), "half");
  WriteFileAtomic((dir / "view.tmp777.png").string(), "half");
  EXPECT_EQ(HashPath(dir.string()), base);
  WriteFileAtomic((dir / "notes.tmp.txt").string(), "real");
  EXPECT_NE(HashPath(dir.string()), base) << "only temporaries with a pid are skipped";
}

// A workspace inside the photo folder it imports: its logs and records changed on every run, so
// the folder's hash did, and import ran again every time.
TEST(ContentHash, FolderLeavesOutTheExcludedSubfolder) {
  const fs::path dir = MakeTestDir("exclude");
  WriteFileAtomic((dir / "a.png").string(), "A");
  const std::string base = HashPath(dir.string());
  WriteFileAtomic((dir / "ibmr_out" / "logs" / "ibmr.log").string(), "run 1");
  EXPECT_EQ(HashPath(dir.string(), (dir / "ibmr_out").string()), base);
  EXPECT_EQ(HashPath(dir.string(), (dir / "ibmr_out/").string()), base) << "a trailing slash names the same folder";
  WriteFileAtomic((dir / "ibmr_out" / "logs" / "ibmr.log").string(), "run 2");
  EXPECT_EQ(HashPath(dir.string(), (dir / "ibmr_out").string()), base);
  EXPECT_NE(HashPath(dir.string()), base) << "without the exclusion the folder's files count";
  EXPECT_NE(HashPath(dir.string(), (dir / "elsewhere").string()), base);
  WriteFileAtomic((dir / "b.png").string(), "B");
  EXPECT_NE(HashPath(dir.string(), (dir / "ibmr_out").string()), base) << "the photos still count";
}

}  // namespace
}  // namespace ibmr
