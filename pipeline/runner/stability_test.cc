// The stability matrix from collected variants: metrics are found by "stage.key" and
// "models.NAME.key"; quality is relative to the clean variant in the right direction; a method
// breaks at the first strength below 0.8 of clean, with the confidence rho recorded there; a
// config's sweep: block parses, and a malformed one names its key.
#include "pipeline/runner/stability.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "pipeline/runner/fake_stages_for_test.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

nlohmann::json Variant(const std::string& degradation, const std::string& strength, double within, double rho,
                       double psnr) {
  nlohmann::json params = {{"synth.degradation", degradation}};
  if (!strength.empty()) params["synth.strength"] = strength;
  return {{"status", "ok"},
          {"params", params},
          {"stages", {{{"stage", "multi_depth"}, {"metrics", {{"within", within}, {"rho", rho}}}}}},
          {"models", {{"surfels", {{"photo_psnr", psnr}}}}}};
}

SweepPlan Plan() {
  SweepPlan plan;
  plan.degradation_keys = {"synth.degradation"};
  plan.strength_keys = {"synth.strength"};
  plan.methods = {{"stereo", "multi_depth.within", "multi_depth.rho", true}, {"held out", "models.surfels.photo_psnr", "", true}};
  return plan;
}

TEST(Stability, MetricsAreFoundByStageOrModel) {
  const nlohmann::json v = Variant("specular", "0.5", 0.9, -0.4, 30);
  EXPECT_DOUBLE_EQ(VariantMetric(v, "multi_depth.within"), 0.9);
  EXPECT_DOUBLE_EQ(VariantMetric(v, "models.surfels.photo_psnr"), 30);
  EXPECT_TRUE(std::isnan(VariantMetric(v, "multi_depth.missing")));
  EXPECT_TRUE(std::isnan(VariantMetric(v, "fuse.within")));
  EXPECT_TRUE(std::isnan(VariantMetric(v, "models.plane.photo_psnr")));
}

TEST(Stability, RelativeQualityAndWhereEachMethodBreaks) {
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.9, -0.5, 30));
  variants.push_back(Variant("specular", "0.25", 0.85, -0.45, 29.5));
  variants.push_back(Variant("specular", "0.5", 0.6, -0.2, 29));
  variants.push_back(Variant("specular", "1", 0.3, 0.1, 20));
  const nlohmann::json m = StabilityMatrix(variants, Plan());
  EXPECT_DOUBLE_EQ(m["clean"]["stereo"].get<double>(), 0.9);
  ASSERT_EQ(m["cells"].size(), 6u);
  EXPECT_NEAR(m["cells"][1]["relative"].get<double>(), 0.6 / 0.9, 1e-12);
  EXPECT_DOUBLE_EQ(m["cells"][1]["confidence_rho"].get<double>(), -0.2);
  ASSERT_EQ(m["breaks"].size(), 2u);
  EXPECT_DOUBLE_EQ(m["breaks"][0]["breaks_at"].get<double>(), 0.5);  // 0.6 / 0.9 < 0.8
  EXPECT_DOUBLE_EQ(m["breaks"][0]["confidence_rho_at_break"].get<double>(), -0.2);
  EXPECT_DOUBLE_EQ(m["breaks"][1]["breaks_at"].get<double>(), 1.0);  // 20 / 30
  ASSERT_EQ(m["curves"].size(), 1u);
  EXPECT_EQ(m["curves"][0]["strengths"], nlohmann::json({0.0, 0.25, 0.5, 1.0}));
  EXPECT_DOUBLE_EQ(m["curves"][0]["series"][0]["values"][0].get<double>(), 1.0);
}

TEST(Stability, SparsificationRatiosAreRecordedPerCellAtTheBreakAndCharted) {
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.9, -0.5, 30));
  variants.push_back(Variant("specular", "0.5", 0.6, -0.2, 29));
  variants[0]["stages"][0]["metrics"]["auc"] = 1.5;
  variants[1]["stages"][0]["metrics"]["auc"] = 3.0;
  SweepPlan plan = Plan();
  plan.methods[0].sparsification = "multi_depth.auc";
  const nlohmann::json m = StabilityMatrix(variants, plan);
  EXPECT_DOUBLE_EQ(m["cells"][0]["sparsification_auc_ratio"].get<double>(), 3.0);
  EXPECT_TRUE(m["cells"][1]["sparsification_auc_ratio"].is_null());  // held out: no confidence
  EXPECT_DOUBLE_EQ(m["breaks"][0]["sparsification_auc_ratio_at_break"].get<double>(), 3.0);
  ASSERT_EQ(m["sparsification_curves"].size(), 1u);
  const nlohmann::json& series = m["sparsification_curves"][0]["series"];
  ASSERT_EQ(series.size(), 1u);  // only the method with a sparsification metric
  EXPECT_EQ(series[0]["values"], nlohmann::json({1.5, 3.0}));
}

TEST(Stability, AFailedVariantBreaksTheMethodsThatProducedNothing) {
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.9, -0.5, 30));
  nlohmann::json failed = Variant("few_views", "1", 0.5, -0.1, 0);
  failed["status"] = "failed";
  failed["models"] = nlohmann::json::object();  // render never ran
  failed["stages"].push_back({{"stage", "surfels"}, {"status", "failed"}, {"error", "fused.ply holds no point (earlier warnings: ...)"}});
  variants.push_back(failed);
  const nlohmann::json m = StabilityMatrix(variants, Plan());
  EXPECT_FALSE(m["cells"][0].contains("why"));
  EXPECT_EQ(m["cells"][1]["why"], "[surfels] fused.ply holds no point (earlier warnings: ...)");
  ASSERT_EQ(m["cells"].size(), 2u);
  EXPECT_NEAR(m["cells"][0]["relative"].get<double>(), 0.5 / 0.9, 1e-12);  // its stage ran
  EXPECT_EQ(m["cells"][0]["failed"], false);
  EXPECT_DOUBLE_EQ(m["cells"][1]["relative"].get<double>(), 0.0);
  EXPECT_EQ(m["cells"][1]["failed"], true);
  EXPECT_DOUBLE_EQ(m["breaks"][1]["breaks_at"].get<double>(), 1.0);
}

TEST(Stability, SeveralDegradationKeysEachNameTheirCells) {
  SweepPlan plan = Plan();
  plan.degradation_keys.push_back("silhouettes.corrupt");
  plan.strength_keys.push_back("silhouettes.corrupt_strength");
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.9, -0.5, 30));
  nlohmann::json eroded = Variant("none", "", 0.45, -0.3, 25);
  eroded["params"]["silhouettes.corrupt"] = "erode";
  eroded["params"]["silhouettes.corrupt_strength"] = "0.75";
  variants.push_back(eroded);
  const nlohmann::json m = StabilityMatrix(variants, plan);
  ASSERT_EQ(m["cells"].size(), 2u);
  EXPECT_EQ(m["cells"][0]["degradation"], "erode");
  EXPECT_DOUBLE_EQ(m["cells"][0]["strength"].get<double>(), 0.75);
  EXPECT_DOUBLE_EQ(m["cells"][0]["relative"].get<double>(), 0.5);
}

TEST(Stability, LowerIsBetterMetricsInvert) {
  SweepPlan plan = Plan();
  plan.methods = {{"accuracy", "multi_depth.within", "", false}};  // a distance: lower is better
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.01, 0, 0));
  variants.push_back(Variant("exposure", "1", 0.02, 0, 0));
  const nlohmann::json m = StabilityMatrix(variants, plan);
  EXPECT_DOUBLE_EQ(m["cells"][0]["relative"].get<double>(), 0.5);
}

TEST(Stability, AZeroScoreIsBrokenAndAnUnmeasurableMethodIsUnknown) {
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.9, -0.5, 30));
  variants.push_back(Variant("exposure", "0.5", 0.0, 0, 30));  // nothing within tolerance
  SweepPlan plan = Plan();
  plan.methods.push_back({"typo", "multi_depth.withn", "", true});
  const nlohmann::json m = StabilityMatrix(variants, plan);
  EXPECT_DOUBLE_EQ(m["cells"][0]["relative"].get<double>(), 0.0);
  EXPECT_DOUBLE_EQ(m["breaks"][0]["breaks_at"].get<double>(), 0.5);
  EXPECT_TRUE(m["breaks"][1]["breaks_at"].is_null());  // held out: holds
  EXPECT_EQ(m["breaks"][2]["breaks_at"], "unknown");
}

// A detector's precision, recall and false calls per cell, the clean scene first; null where the
// stage recorded null (nothing called out) or nothing.
TEST(Stability, DetectorsArePrecisionAndRecallPerCell) {
  nlohmann::json variants = nlohmann::json::array();
  variants.push_back(Variant("none", "", 0.9, -0.5, 30));
  variants.push_back(Variant("pose_outliers", "0.5", 0.8, -0.4, 28));
  variants.push_back(Variant("pose_outliers", "1", 0.7, -0.4, 26));
  auto& clean = variants[0]["stages"][0]["metrics"];
  clean["precision"] = nullptr, clean["recall"] = nullptr, clean["false"] = 0;
  auto& half = variants[1]["stages"][0]["metrics"];
  half["precision"] = 1.0, half["recall"] = 0.75, half["false"] = 0;
  auto& full = variants[2]["stages"][0]["metrics"];
  full["precision"] = 0.8, full["recall"] = 1.0, full["false"] = 1;
  SweepPlan plan = Plan();
  plan.detectors = {{"view flag", "multi_depth.precision", "multi_depth.recall", "multi_depth.false"}};
  const nlohmann::json m = StabilityMatrix(variants, plan);
  ASSERT_EQ(m["detectors"].size(), 1u);
  EXPECT_EQ(m["detectors"][0]["name"], "view flag");
  const nlohmann::json& cells = m["detectors"][0]["cells"];
  ASSERT_EQ(cells.size(), 3u);
  EXPECT_EQ(cells[0]["degradation"], "none");
  EXPECT_TRUE(cells[0]["precision"].is_null());
  EXPECT_DOUBLE_EQ(cells[0]["false_calls"].get<double>(), 0);
  EXPECT_DOUBLE_EQ(cells[1]["strength"].get<double>(), 0.5);
  EXPECT_DOUBLE_EQ(cells[1]["recall"].get<double>(), 0.75);
  EXPECT_DOUBLE_EQ(cells[2]["precision"].get<double>(), 0.8);
  EXPECT_DOUBLE_EQ(cells[2]["false_calls"].get<double>(), 1);
  EXPECT_TRUE(StabilityMatrix(variants, Plan())["detectors"].empty());
}

TEST(Stability, TheConfigSweepBlockParsesAndNamesBadKeys) {
  const auto dir = ibmr_testing::ScratchDir("ibmr_stability_config");
  StageRegistry registry;
  testing_stages::Register(&registry);
  std::ofstream(dir / "source.txt") << "x";
  std::ofstream(dir / "c.yaml") << "workspace: ws\nstages:\n  - produce\n  - consume\n"
                                   "sweep:\n  vary:\n    produce.value: [1, 2]\n  variants: [\"consume.suffix=z\"]\n"
                                   "  stability:\n    degradation: consume.suffix\n    strength: produce.value\n"
                                   "    methods:\n      - {name: m, metric: produce.bytes, higher_is_better: true,\n"
                                   "         confidence: produce.rho, sparsification: produce.auc}\n"
                                   "    detectors:\n      - {name: flag, precision: produce.p, recall: produce.r}\n";
  const Config config = LoadConfig((dir / "c.yaml").string(), registry);
  ASSERT_EQ(config.sweep.detectors.size(), 1u);
  EXPECT_EQ(config.sweep.detectors[0].recall, "produce.r");
  EXPECT_TRUE(config.sweep.detectors[0].false_calls.empty());
  EXPECT_EQ(config.sweep.vary, std::vector<std::string>{"produce.value=1,2"});
  EXPECT_EQ(config.sweep.variants, std::vector<std::string>{"consume.suffix=z"});
  ASSERT_EQ(config.sweep.methods.size(), 1u);
  EXPECT_TRUE(config.sweep.methods[0].higher_is_better);
  EXPECT_EQ(config.sweep.methods[0].confidence, "produce.rho");
  EXPECT_EQ(config.sweep.methods[0].sparsification, "produce.auc");
  std::ofstream(dir / "bad.yaml") << "workspace: ws\nstages:\n  - produce\nsweep:\n  vari: {produce.value: [1]}\n";
  try {
    LoadConfig((dir / "bad.yaml").string(), registry);
    ADD_FAILURE() << "accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.yaml:5"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("did you mean"), std::string::npos) << e.what();
  }
  // A misspelt method key would silently invert the quality: it is refused, by name.
  std::ofstream(dir / "typo.yaml") << "workspace: ws\nstages:\n  - produce\nsweep:\n  stability:\n"
                                      "    degradation: produce.value\n    strength: produce.value\n"
                                      "    methods:\n      - {name: m, metric: produce.bytes, higher_is_beter: true}\n";
  try {
    LoadConfig((dir / "typo.yaml").string(), registry);
    ADD_FAILURE() << "accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("higher_is_beter"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("did you mean 'higher_is_better'"), std::string::npos) << e.what();
  }
  // A detector without its recall is refused, naming the key.
  std::ofstream(dir / "detector.yaml") << "workspace: ws\nstages:\n  - produce\nsweep:\n  stability:\n"
                                          "    degradation: produce.value\n    strength: produce.value\n"
                                          "    methods:\n      - {name: m, metric: produce.bytes}\n"
                                          "    detectors:\n      - {name: flag, precision: produce.p}\n";
  try {
    LoadConfig((dir / "detector.yaml").string(), registry);
    ADD_FAILURE() << "accepted";
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("sweep.stability.detectors.recall"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace ibmr
