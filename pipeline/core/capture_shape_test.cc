// The capture analysis on constructed rigs: each kind, the figures that decide it, and the
// boundaries (too few views, no points, axes that do not converge).
#include "pipeline/core/capture_shape.h"

#include <gtest/gtest.h>

#include "pipeline/core/capture_rigs_for_test.h"

namespace ibmr {
namespace {

TEST(CaptureShape, RingIsAnObject) {
  const CaptureShape shape = AnalyseCapture(capture_rigs::Ring(16), false);
  EXPECT_EQ(shape.kind, "object") << shape.Describe();
  EXPECT_TRUE(shape.converges);
  EXPECT_LT(shape.convergence_residual, 0.01);
  EXPECT_DOUBLE_EQ(shape.in_front, 1.0);
  EXPECT_NEAR(shape.surround_deg, 360 - 360 / 16.0, 1e-6);
  EXPECT_GT(shape.axis_spread_deg, 60);  // the axes tilt down at the object: not 90
  ASSERT_TRUE(shape.near_depth && shape.far_depth);
  EXPECT_GT(*shape.near_depth, 2.0);
  EXPECT_LT(*shape.far_depth, 4.0);
}

TEST(CaptureShape, ForwardGridIsForwardFacingEvenTurned) {
  for (const double turn : {0.0, 6.0, 12.0}) {
    const CaptureShape shape = AnalyseCapture(capture_rigs::ForwardGrid(turn), false);
    EXPECT_EQ(shape.kind, "forward_facing") << turn << ": " << shape.Describe();
    ASSERT_TRUE(shape.baseline_over_near);
    EXPECT_LT(*shape.baseline_over_near, 0.5);
    EXPECT_LT(shape.axis_spread_deg, 20);
  }
}

TEST(CaptureShape, WalksAndArcsAreGeneral) {
  const CaptureShape walk = AnalyseCapture(capture_rigs::FacadeWalk(), false);
  EXPECT_EQ(walk.kind, "general") << walk.Describe();
  ASSERT_TRUE(walk.baseline_over_near);
  EXPECT_GT(*walk.baseline_over_near, 1.0);  // narrow axes, but a long street against the near depth
  const CaptureShape arc = AnalyseCapture(capture_rigs::QuarterArc(), false);
  EXPECT_EQ(arc.kind, "general") << arc.Describe();
  EXPECT_TRUE(arc.converges);
  EXPECT_NEAR(arc.surround_deg, 90, 1);  // converging, but not round the point
}

TEST(CaptureShape, WithoutPointsTheAxesDecide) {
  SparseModel ring = capture_rigs::Ring(24);
  ring.points.clear();
  const CaptureShape shape = AnalyseCapture(ring, true);
  EXPECT_EQ(shape.kind, "object");
  EXPECT_FALSE(shape.baseline_over_near);
  EXPECT_FALSE(shape.near_depth);
  EXPECT_TRUE(shape.silhouettes);
  EXPECT_NE(shape.Describe().find("no points"), std::string::npos) << shape.Describe();
  SparseModel grid = capture_rigs::ForwardGrid(0);
  grid.points.clear();
  EXPECT_EQ(AnalyseCapture(grid, false).kind, "forward_facing");
  EXPECT_FALSE(AnalyseCapture(grid, false).converges);  // parallel axes meet nowhere
}

TEST(CaptureShape, OneViewHasNoKind) {
  SparseModel one = capture_rigs::Ring(1);
  const CaptureShape shape = AnalyseCapture(one, false);
  EXPECT_EQ(shape.kind, "");
  EXPECT_NE(shape.Describe().find("fewer than 2"), std::string::npos) << shape.Describe();
}

TEST(CaptureShape, JsonRoundTrip) {
  CaptureShape shape = AnalyseCapture(capture_rigs::QuarterArc(), true);
  shape.set_by = "plan.kind (the analysis: general)";
  const CaptureShape back = CaptureShape::FromJson(shape.ToJson());
  EXPECT_EQ(back.ToJson(), shape.ToJson());
  EXPECT_EQ(back.Describe(), shape.Describe());
}

}  // namespace
}  // namespace ibmr
