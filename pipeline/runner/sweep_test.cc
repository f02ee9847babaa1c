// ibmr sweep: variants expand as the product of --vary lists plus listed ones; a variant that
// changes only a downstream stage reuses the upstream outputs of an earlier variant (linked, not
// recomputed) and leaves that variant's files as they were; sweep.json collects every variant;
// the Pareto front keeps exactly the undominated points; malformed arguments are named.
#include "pipeline/runner/sweep.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/runner/fake_stages_for_test.h"
#include "pipeline/runner/record.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

// The fake produce -> consume config in `dir`, its stages registered; options name it.
SweepOptions TwoStageConfig(const fs::path& dir, StageRegistry* registry) {
  testing_stages::Register(registry);
  std::ofstream(dir / "source.txt") << "hello";
  std::ofstream(dir / "c.yaml") << "workspace: ws\nstages:\n  - produce\n  - consume\n";
  SweepOptions options;
  options.config_path = (dir / "c.yaml").string();
  return options;
}

TEST(Sweep, VariantsAreTheProductOfTheListsThenTheListedOnes) {
  const auto variants = ExpandVariants({"a.x=1,2", "b.y=p,q,r"}, {"a.x=7 b.y=s"});
  ASSERT_EQ(variants.size(), 7u);
  EXPECT_EQ(variants[0], (Assignments{{"a.x", "1"}, {"b.y", "p"}}));
  EXPECT_EQ(variants[2], (Assignments{{"a.x", "1"}, {"b.y", "r"}}));
  EXPECT_EQ(variants[3], (Assignments{{"a.x", "2"}, {"b.y", "p"}}));
  EXPECT_EQ(variants[6], (Assignments{{"a.x", "7"}, {"b.y", "s"}}));
  EXPECT_EQ(ExpandVariants({}, {}).size(), 1u);  // the config as it is
  for (const std::string bad : {"novalue", "a.x=", "ax=1"}) {
    try {
      ExpandVariants({bad}, {});
      ADD_FAILURE() << bad << " accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("--vary " + bad), std::string::npos) << e.what();
    }
  }
}

TEST(Sweep, ParetoFrontKeepsTheUndominatedPoints) {
  nlohmann::json points = nlohmann::json::array();
  points.push_back({{"seconds", 10.0}, {"psnr", 20.0}, {"id", "a"}});
  points.push_back({{"seconds", 5.0}, {"psnr", 18.0}, {"id", "b"}});
  points.push_back({{"seconds", 12.0}, {"psnr", 19.0}, {"id", "dominated by a"}});
  points.push_back({{"seconds", 30.0}, {"psnr", 25.0}, {"id", "c"}});
  points.push_back({{"seconds", 5.0}, {"psnr", 17.0}, {"id", "same time as b, worse"}});
  const nlohmann::json front = ParetoFront(points);
  ASSERT_EQ(front.size(), 3u) << front.dump();
  EXPECT_EQ(front[0]["id"], "b");
  EXPECT_EQ(front[1]["id"], "a");
  EXPECT_EQ(front[2]["id"], "c");
}

TEST(Sweep, ADownstreamVariantReusesUpstreamOutputsAndLeavesTheFirstIntact) {
  const fs::path dir = ibmr_testing::ScratchDir("ibmr_sweep_test");
  StageRegistry registry;
  SweepOptions options = TwoStageConfig(dir, &registry);
  options.vary = {"consume.suffix=x,y"};
  options.listed = {"produce.value=5 consume.suffix=x"};
  options.out = (dir / "sweep").string();
  const int produce_before = testing_stages::produce_runs, consume_before = testing_stages::consume_runs;
  ASSERT_EQ(RunSweep(options, registry), 0);
  // v00 computes both; v01 (suffix y) reuses produce; v02 (value 5) computes both again.
  EXPECT_EQ(testing_stages::produce_runs - produce_before, 2);
  EXPECT_EQ(testing_stages::consume_runs - consume_before, 3);
  EXPECT_EQ(ReadFile((dir / "sweep/v00/b.txt").string()), "hello1x");
  EXPECT_EQ(ReadFile((dir / "sweep/v01/b.txt").string()), "hello1y");
  EXPECT_EQ(ReadFile((dir / "sweep/v02/b.txt").string()), "hello5x");
  const auto reused = ReadRecord((dir / "sweep/v01/records/produce.json").string());
  ASSERT_TRUE(reused.has_value());
  EXPECT_EQ(fs::path(reused->reused_from).filename(), "v00");
  // The reused file is a link; a stage rewriting it in v01 (temporary, then rename) leaves v00's.
  WriteFileAtomic((dir / "sweep/v01/a.txt").string(), "rewritten");
  EXPECT_EQ(ReadFile((dir / "sweep/v00/a.txt").string()), "hello1");
  WriteFileAtomic((dir / "sweep/v01/a.txt").string(), "hello1");

  const nlohmann::json sweep = nlohmann::json::parse(ReadFile((dir / "sweep/sweep.json").string()));
  ASSERT_EQ(sweep["variants"].size(), 3u);
  EXPECT_EQ(sweep["variants"][1]["params"]["consume.suffix"], "y");
  EXPECT_EQ(sweep["variants"][1]["stages"][0]["reused"], true);
  EXPECT_EQ(sweep["variants"][1]["stages"][1]["reused"], false);
  EXPECT_EQ(sweep["variants"][2]["stages"][0]["reused"], false);
  // What v01 computed itself is consume's time alone; produce's (reused) is in its total only.
  EXPECT_DOUBLE_EQ(sweep["variants"][1]["computed_wall_seconds"].get<double>(),
                   sweep["variants"][1]["stages"][1]["wall_seconds"].get<double>());
  EXPECT_DOUBLE_EQ(sweep["variants"][1]["wall_seconds"].get<double>(),
                   sweep["variants"][1]["stages"][0]["wall_seconds"].get<double>() +
                       sweep["variants"][1]["stages"][1]["wall_seconds"].get<double>());

  // A second sweep over the same folder runs nothing: every variant is up to date in place.
  const int produce_again = testing_stages::produce_runs, consume_again = testing_stages::consume_runs;
  ASSERT_EQ(RunSweep(options, registry), 0);
  EXPECT_EQ(testing_stages::produce_runs - produce_again, 0);
  EXPECT_EQ(testing_stages::consume_runs - consume_again, 0);
}

TEST(Sweep, AnUnknownParameterFailsBeforeAnythingRuns) {
  const fs::path dir = ibmr_testing::ScratchDir("ibmr_sweep_bad");
  StageRegistry registry;
  SweepOptions options = TwoStageConfig(dir, &registry);
  options.vary = {"consume.suffix=x,y", "consume.sufix=z"};
  options.out = (dir / "sweep").string();
  const int before = testing_stages::produce_runs;
  EXPECT_THROW(RunSweep(options, registry), ConfigError);
  EXPECT_EQ(testing_stages::produce_runs, before);
}

}  // namespace
}  // namespace ibmr
