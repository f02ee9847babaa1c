// Tests of polygon view maps (view_maps.h; seed 003 §7): the local frame of Eq. 1, the mapping of
// Eq. 2 with the arc length, the blend of at most three views with barycentric weights summing
// to 1, a view's own direction giving it weight 1, and the file's round trip and failure paths.
#include "pipeline/core/view_maps.h"

#include <gtest/gtest.h>
#include <Eigen/LU>

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>

#include "pipeline/core/errors.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

constexpr double kHalfPi = 1.5707963267948966;

// The unit direction whose map coordinates are `p` (|p| <= pi/2): the inverse of MapDirection.
Eigen::Vector3d DirectionOf(const Eigen::Matrix3d& frame, const Eigen::Vector2d& p) {
  const double arc = p.norm();
  if (arc == 0) return frame.col(2);
  const Eigen::Vector3d in_plane = (p.x() * frame.col(0) + p.y() * frame.col(1)) / arc;
  return std::cos(arc) * frame.col(2) + std::sin(arc) * in_plane;
}

// The map coordinate of grid sample i (the grid spans [-pi, pi]).
double GridCoordinate(int i, int grid) { return -2 * kHalfPi + 4.0 * kHalfPi * i / (grid - 1); }

TEST(ViewMaps, FaceFrameIsOrthonormalWithTheNormalLast) {
  for (const Eigen::Vector3d& n : {Eigen::Vector3d(0, 0, 1), Eigen::Vector3d(1, 2, -3).normalized(),
                                   Eigen::Vector3d(0, 1, 0), Eigen::Vector3d(0, -1, 0)}) {
    const Eigen::Matrix3d frame = FaceFrame(n);
    EXPECT_TRUE((frame.transpose() * frame).isIdentity(1e-12)) << n.transpose();
    EXPECT_NEAR(frame.determinant(), 1.0, 1e-12);  // y = n x x: right-handed
    EXPECT_TRUE(frame.col(2).isApprox(n, 1e-12));
  }
  // Eq. 1: x = y_W x n, and x_W when n is along y_W.
  EXPECT_TRUE(FaceFrame(Eigen::Vector3d(0, 0, 1)).col(0).isApprox(Eigen::Vector3d(1, 0, 0)));
  EXPECT_TRUE(FaceFrame(Eigen::Vector3d(0, 1, 0)).col(0).isApprox(Eigen::Vector3d(1, 0, 0)));
}

TEST(ViewMaps, MapDirectionNormalIsOriginAndArcLengthIsTheAngle) {
  const Eigen::Matrix3d frame = FaceFrame(Eigen::Vector3d(0.3, -0.2, 0.9).normalized());
  EXPECT_LT(MapDirection(frame, frame.col(2)).norm(), 1e-12);
  const double angle = 0.6;
  const Eigen::Vector3d tilted = std::cos(angle) * frame.col(2) + std::sin(angle) * frame.col(0);
  const Eigen::Vector2d p = MapDirection(frame, tilted);
  EXPECT_NEAR(p.x(), angle, 1e-12);
  EXPECT_NEAR(p.y(), 0.0, 1e-12);
  // The horizon lies on the circle of radius pi/2.
  EXPECT_NEAR(MapDirection(frame, frame.col(1)).norm(), kHalfPi, 1e-12);
  // DirectionOf inverts it.
  const Eigen::Vector2d q(-0.4, 0.9);
  EXPECT_TRUE(MapDirection(frame, DirectionOf(frame, q)).isApprox(q, 1e-12));
}

FaceViewMap RandomFace(std::mt19937* rng, int views, int grid) {
  std::uniform_real_distribution<float> coordinate(-1.2f, 1.2f);
  FaceViewMap face;
  for (int k = 0; k < views; ++k) {
    face.views.push_back(static_cast<uint16_t>(3 * k + 1));
    face.directions.emplace_back(coordinate(*rng), coordinate(*rng));
  }
  BuildGrid(grid, &face);
  return face;
}

TEST(ViewMaps, BlendHasAtMostThreeViewsWithWeightsSummingToOne) {
  std::mt19937 rng(7);
  ViewMaps maps;
  maps.grid = 16;
  maps.view_names.resize(20);
  for (int views = 2; views <= 6; ++views) maps.faces.push_back(RandomFace(&rng, views, maps.grid));
  const Eigen::Matrix3d frame = FaceFrame(Eigen::Vector3d(0.1, 0.2, 1).normalized());
  std::uniform_real_distribution<double> coordinate(-1.55, 1.55);
  for (int trial = 0; trial < 2000; ++trial) {
    const int face = trial % static_cast<int>(maps.faces.size());
    Eigen::Vector2d p(coordinate(rng), coordinate(rng));
    if (p.norm() > 1.55) p *= 1.55 / p.norm();
    const ViewBlend blend = BlendFor(maps, face, frame, DirectionOf(frame, p));
    ASSERT_GE(blend.count, 1);
    ASSERT_LE(blend.count, 3);
    float sum = 0;
    for (int i = 0; i < blend.count; ++i) {
      EXPECT_GE(blend.weights[i], -1e-6f);
      sum += blend.weights[i];
      const auto& views = maps.faces[face].views;
      EXPECT_NE(std::find(views.begin(), views.end(), blend.views[i]), views.end());
      for (int j = 0; j < i; ++j) EXPECT_NE(blend.views[i], blend.views[j]);
    }
    EXPECT_NEAR(sum, 1.f, 1e-5);
  }
}

TEST(ViewMaps, ViewDirectionOnAGridSampleGetsWeightOne) {
  const int grid = 16;
  const Eigen::Matrix3d frame = FaceFrame(Eigen::Vector3d(-0.2, 0.5, 0.8).normalized());
  FaceViewMap face;
  // Three views exactly on grid samples, far apart.
  const std::array<std::pair<int, int>, 3> samples = {{{7, 7}, {12, 5}, {3, 11}}};
  for (int k = 0; k < 3; ++k) {
    face.views.push_back(static_cast<uint16_t>(k));
    face.directions.emplace_back(GridCoordinate(samples[k].first, grid), GridCoordinate(samples[k].second, grid));
  }
  BuildGrid(grid, &face);
  ViewMaps maps;
  maps.grid = grid;
  maps.view_names = {"a", "b", "c"};
  maps.faces = {face};
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector2d p = face.directions[k].cast<double>();
    const ViewBlend blend = BlendFor(maps, 0, frame, DirectionOf(frame, p));
    float weight = 0;
    for (int i = 0; i < blend.count; ++i) weight += blend.views[i] == k ? blend.weights[i] : 0.f;
    EXPECT_NEAR(weight, 1.f, 1e-4) << "view " << k;
  }
}

TEST(ViewMaps, FacesSeenByNoneOrOneView) {
  ViewMaps maps;
  maps.view_names = {"a", "b"};
  FaceViewMap none, one;
  one.views = {1};
  one.directions = {Eigen::Vector2f(0.2f, 0.1f)};
  BuildGrid(maps.grid, &one);
  EXPECT_TRUE(one.nearest.empty());
  maps.faces = {none, one};
  const Eigen::Matrix3d frame = FaceFrame(Eigen::Vector3d::UnitZ());
  EXPECT_EQ(BlendFor(maps, 0, frame, Eigen::Vector3d::UnitZ()).count, 0);
  const ViewBlend blend = BlendFor(maps, 1, frame, Eigen::Vector3d(0.5, 0.5, 0.7).normalized());
  ASSERT_EQ(blend.count, 1);
  EXPECT_EQ(blend.views[0], 1);
  EXPECT_FLOAT_EQ(blend.weights[0], 1.f);
}

// A partly seen view holds only the samples nearer to it than any whole view by more than the
// penalty: along the line between a whole view at x = -0.5 and a partly seen one at x = +0.5,
// the boundary moves from x = 0 to x = penalty / 2.
TEST(ViewMaps, PenaltyMovesTheBoundaryTowardThePartlySeenView) {
  const int grid = 65;
  FaceViewMap face;
  face.views = {0, 1};
  face.directions = {Eigen::Vector2f(-0.5f, 0.f), Eigen::Vector2f(0.5f, 0.f)};
  const int row = (grid - 1) / 2;  // y = 0
  const auto boundary = [&](const FaceViewMap& f) {
    for (int i = 0; i < grid; ++i) {
      if (f.nearest[static_cast<size_t>(row) * grid + i] == 1) return GridCoordinate(i, grid);
    }
    return 10.0;
  };
  BuildGrid(grid, &face);
  EXPECT_NEAR(boundary(face), 0.0, 0.1);
  BuildGrid(grid, &face, {0.f, 0.6f});
  EXPECT_NEAR(boundary(face), 0.3, 0.1);
  // Beyond the partly seen view the samples stay its own (a direction no whole view is near).
  EXPECT_EQ(face.nearest[static_cast<size_t>(row) * grid + grid - 1], 1);
  BuildGrid(grid, &face, {0.f, 100.f});  // never nearer: every sample the whole view's
  EXPECT_EQ(std::count(face.nearest.begin(), face.nearest.end(), 1), 0);
  EXPECT_THROW(BuildGrid(grid, &face, {0.f}), std::invalid_argument);
}

// BuildGrid against the grid's definition, sample by sample: each sample takes the view nearest
// to it (plus its penalty), the first one on a tie; random directions with duplicates (exact ties)
// and penalties, 2 to 40 views, odd and even grids.
TEST(BuildGrid, EverySampleTakesTheNearestViewTiesToTheFirst) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> coordinate(-3.2f, 3.2f), extra(0.f, 0.8f);
  for (int round = 0; round < 40; ++round) {
    const int grid = 9 + round % 20, views = 2 + round % 39;
    FaceViewMap face;
    std::vector<float> penalty;
    for (int k = 0; k < views; ++k) {
      face.views.push_back(static_cast<uint16_t>(k));
      if (k > 0 && k % 3 == 0) {
        face.directions.push_back(face.directions[k - 1]);  // the same direction again: a tie
      } else {
        face.directions.emplace_back(coordinate(rng), coordinate(rng));
      }
      penalty.push_back(round % 2 ? extra(rng) : 0.f);
    }
    BuildGrid(grid, &face, round % 4 == 0 ? std::vector<float>{} : penalty);
    ASSERT_EQ(face.nearest.size(), static_cast<size_t>(grid) * grid);
    for (int j = 0; j < grid; ++j) {
      for (int i = 0; i < grid; ++i) {
        const Eigen::Vector2f sample(static_cast<float>(-M_PI + 2 * M_PI * i / (grid - 1)),
                                     static_cast<float>(-M_PI + 2 * M_PI * j / (grid - 1)));
        int best = 0;
        float best_distance = std::numeric_limits<float>::max();
        for (int k = 0; k < views; ++k) {
          float d = (face.directions[k] - sample).norm();
          if (round % 4 != 0) d += penalty[k];
          if (d < best_distance) best_distance = d, best = k;
        }
        ASSERT_EQ(face.nearest[static_cast<size_t>(j) * grid + i], best) << "round " << round << " sample " << i << "," << j;
      }
    }
  }
  FaceViewMap many;
  many.directions.assign(257, Eigen::Vector2f::Zero());
  many.views.assign(257, 0);
  EXPECT_THROW(BuildGrid(8, &many), std::invalid_argument);  // entries are bytes
}

class ViewMapsFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::path(testing::TempDir()) / ("ibmr_view_maps_test_" + std::to_string(::getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

ViewMaps SampleMaps() {
  std::mt19937 rng(3);
  ViewMaps maps;
  maps.grid = 8;
  maps.view_names = {"img 0.jpg", "b.png", "", "d/e.jpg", "f", "g", "h", "i", "j", "k", "l", "m", "n", "o", "p", "q"};
  maps.faces.push_back(FaceViewMap());
  for (int views = 1; views <= 4; ++views) maps.faces.push_back(RandomFace(&rng, views, maps.grid));
  return maps;
}

TEST_F(ViewMapsFile, RoundTrip) {
  const ViewMaps maps = SampleMaps();
  const std::string path = (dir_ / "view_maps.bin").string();
  WriteViewMaps(maps, path);
  const ViewMaps read = ReadViewMaps(path);
  EXPECT_EQ(read.grid, maps.grid);
  EXPECT_EQ(read.view_names, maps.view_names);
  ASSERT_EQ(read.faces.size(), maps.faces.size());
  for (size_t f = 0; f < maps.faces.size(); ++f) {
    EXPECT_EQ(read.faces[f].views, maps.faces[f].views);
    EXPECT_EQ(read.faces[f].nearest, maps.faces[f].nearest);
    ASSERT_EQ(read.faces[f].directions.size(), maps.faces[f].directions.size());
    for (size_t k = 0; k < maps.faces[f].directions.size(); ++k) {
      EXPECT_EQ(read.faces[f].directions[k], maps.faces[f].directions[k]);  // float32 both ways: exact
    }
  }
}

TEST_F(ViewMapsFile, TruncatedFileIsAnInputErrorNamingTheFile) {
  const std::string path = (dir_ / "view_maps.bin").string();
  WriteViewMaps(SampleMaps(), path);
  const auto size = fs::file_size(path);
  for (const uintmax_t keep : {uintmax_t{4}, uintmax_t{20}, size / 2, size - 1}) {
    fs::resize_file(path, keep);
    try {
      ReadViewMaps(path);
      ADD_FAILURE() << "no error for a file cut to " << keep << " bytes";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
    WriteViewMaps(SampleMaps(), path);
  }
}

TEST_F(ViewMapsFile, WrongMagicAndTrailingBytesAreInputErrors) {
  const std::string path = (dir_ / "view_maps.bin").string();
  WriteViewMaps(SampleMaps(), path);
  {
    std::ofstream(path, std::ios::app | std::ios::binary) << "x";
  }
  EXPECT_THROW(ReadViewMaps(path), InputError);
  {
    std::ofstream(path, std::ios::binary) << "NOTAVMAP and more bytes than a header";
  }
  EXPECT_THROW(ReadViewMaps(path), InputError);
}

}  // namespace
}  // namespace ibmr
