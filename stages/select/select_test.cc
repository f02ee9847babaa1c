// Model selection: the smallest model within the tolerance is chosen, not the best; the envelope
// holds exactly the models better than every smaller one; a zero tolerance chooses the best;
// options are checked; an empty list is refused.
#include "stages/select/select.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace ibmr {
namespace {

std::vector<ModelCandidate> Candidates() {
  return {{"mesh_full", "mesh", 5e6, 1e5, 27.0, 0.9},  {"plane", "plane", 32, 1, 17.0, 1.0},
          {"mesh_10k", "mesh", 5e5, 1e4, 26.8, 0.9},   {"mesh_1k", "mesh", 5e4, 1e3, 25.0, 0.9},
          {"splat", "depth_samples", 2e7, 3e6, 26.9, 0.9}};
}

TEST(Select, SmallestWithinToleranceOfTheBestIsChosen) {
  const Selection s = SelectModel(Candidates(), SelectionOptions());
  ASSERT_EQ(s.by_size.size(), 5u);
  EXPECT_EQ(s.by_size.front().name, "plane");
  EXPECT_EQ(s.by_size[s.best].name, "mesh_full");
  EXPECT_EQ(s.by_size[s.chosen].name, "mesh_10k");
  EXPECT_NEAR(s.gap_db, 0.2, 1e-12);
  std::vector<std::string> envelope;
  for (size_t i : s.envelope) envelope.push_back(s.by_size[i].name);
  EXPECT_EQ(envelope, (std::vector<std::string>{"plane", "mesh_1k", "mesh_10k", "mesh_full"}));

  SelectionOptions exact;
  exact.tolerance_db = 0;
  EXPECT_EQ(SelectModel(Candidates(), exact).by_size[SelectModel(Candidates(), exact).chosen].name, "mesh_full");
  SelectionOptions loose;
  loose.tolerance_db = 10;
  const Selection l = SelectModel(Candidates(), loose);
  EXPECT_EQ(l.by_size[l.chosen].name, "plane");
}

TEST(Select, OptionsAreCheckedAndNothingToSelectIsRefused) {
  std::string error;
  SelectionOptions o;
  EXPECT_TRUE(o.Check(&error));
  o.tolerance_db = -1;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("tolerance_db:", 0), 0u) << error;
  o = SelectionOptions();
  o.metric = "";
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("metric:", 0), 0u) << error;
  EXPECT_THROW(SelectModel({}, SelectionOptions()), std::invalid_argument);
}

}  // namespace
}  // namespace ibmr
