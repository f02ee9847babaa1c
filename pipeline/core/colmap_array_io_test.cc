// Tests for COLMAP's dense array format: round trip, the exact header bytes, planar layout, and
// errors for truncated or malformed files.
#include "pipeline/core/colmap_array_io.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstring>
#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_colmap_array_" + name); }

FloatMap Ramp(int w, int h, int c) {
  FloatMap map(w, h, c);
  for (int k = 0; k < c; ++k)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) map.At(x, y, k) = 100.f * k + 10.f * y + x + 0.25f;
  return map;
}

std::string ExpectIoError(const std::string& path) {
  try {
    ReadColmapArray(path);
  } catch (const IoError& e) {
    return e.what();
  }
  ADD_FAILURE() << "expected IoError for " << path;
  return "";
}

TEST(ColmapArray, RoundTripThreeChannels) {
  const std::string path = (MakeTestDir("rt") / "normal_maps" / "a.jpg.geometric.bin").string();
  const FloatMap map = Ramp(7, 5, 3);
  WriteColmapArray(path, map);
  const FloatMap back = ReadColmapArray(path);
  EXPECT_EQ(back.width, 7);
  EXPECT_EQ(back.height, 5);
  EXPECT_EQ(back.channels, 3);
  EXPECT_EQ(back.data, map.data);
}

TEST(ColmapArray, HeaderAndPlanarLayout) {
  const std::string path = (MakeTestDir("hdr") / "d.bin").string();
  const FloatMap map = Ramp(4, 3, 2);
  WriteColmapArray(path, map);
  const std::string bytes = ReadFile(path);
  ASSERT_EQ(bytes.size(), 6 + 4 * 3 * 2 * sizeof(float));
  EXPECT_EQ(bytes.substr(0, 6), "4&3&2&");
  // Channel-planar: value (x=1, y=2, c=1) sits at ((1 * 3) + 2) * 4 + 1.
  float value;
  std::memcpy(&value, bytes.data() + 6 + ((1 * 3 + 2) * 4 + 1) * sizeof(float), sizeof(float));
  EXPECT_EQ(value, 100.f + 20.f + 1.f + 0.25f);
}

TEST(ColmapArray, TruncatedFileNamesPath) {
  const std::string path = (MakeTestDir("trunc") / "d.bin").string();
  WriteColmapArray(path, Ramp(4, 3, 1));
  std::string bytes = ReadFile(path);
  bytes.pop_back();
  WriteFileAtomic(path, bytes);
  const std::string message = ExpectIoError(path);
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("4&3&1&"), std::string::npos) << message;
}

TEST(ColmapArray, BadHeaderSaysWhatWasExpected) {
  const std::string path = (MakeTestDir("bad") / "d.bin").string();
  WriteFileAtomic(path, "P5\n4 3\n255\n............");
  const std::string message = ExpectIoError(path);
  EXPECT_NE(message.find(path), std::string::npos) << message;
  EXPECT_NE(message.find("WIDTH&HEIGHT&CHANNELS&"), std::string::npos) << message;
  WriteFileAtomic(path, "0&3&1&");
  EXPECT_NE(ExpectIoError(path).find("every dimension"), std::string::npos);
}

TEST(ColmapArray, MissingFileNamesPath) {
  const std::string path = (MakeTestDir("missing") / "none.bin").string();
  EXPECT_NE(ExpectIoError(path).find(path), std::string::npos);
}

}  // namespace
}  // namespace ibmr
