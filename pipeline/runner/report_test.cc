// The report's data: a file of another shape than the code expects, or not JSON at all, is an
// error naming the file and what to re-run (it was nlohmann's opaque type error, or, for a
// truncated sweep.json, an empty page with exit 0).
#include "pipeline/runner/report.h"

#include <gtest/gtest.h>

#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

// The message of gathering `folder`'s report, or "" when it succeeds.
std::string ErrorOf(const fs::path& folder, bool sweep) {
  try {
    if (sweep) {
      GatherSweepReport(folder.string());
    } else {
      GatherWorkspaceReport(folder.string(), 64);
    }
  } catch (const IoError& e) {
    return e.what();
  }
  return "";
}

TEST(Report, MalformedWorkspaceFilesNameTheFileAndTheStage) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_report_workspace");
  WriteFileAtomic((ws / "records/carve.json").string(), R"({"stage": "carve", "status": "ok", "wall_seconds": 1})");
  EXPECT_EQ(ErrorOf(ws, false), "");
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"scores/heldout.json", "[1]"},
      {"scores/heldout.json", R"({"proxies": {"a": 3}})"},
      {"scores/heldout.json", R"({"proxies": {"a": {"mean": 5}}})"},
      {"scores/heldout.json", R"({"proxies": )"},
      {"scores/selection.json", R"({"metric": 7})"},
      {"records/carve.json", "[1]"},
      {"records/carve.json", R"({"stage": 1})"},
  };
  for (const auto& [file, text] : cases) {
    const std::string path = (ws / file).string();
    const std::string before = ReadFile(fs::exists(path) ? path : (ws / "records/carve.json").string());
    WriteFileAtomic(path, text);
    const std::string error = ErrorOf(ws, false);
    EXPECT_NE(error.find(path + ": "), std::string::npos) << file << " = " << text << ": " << error;
    const std::string stage = file == "scores/heldout.json" ? "score" : file == "scores/selection.json" ? "select" : "carve";
    EXPECT_NE(error.find("re-run the " + stage + " stage"), std::string::npos) << error;
    if (file == "records/carve.json") {
      WriteFileAtomic(path, before);
    } else {
      fs::remove(path);
    }
  }
}

// multi_depth's per-view flag (issue 67) reaches the page's data; a file of another shape names
// the file and the stage to re-run.
TEST(Report, FlaggedViewsFromViewAgreementJson) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_report_view_agreement");
  WriteFileAtomic((ws / "records/multi_depth.json").string(), R"({"stage": "multi_depth", "status": "ok", "wall_seconds": 1})");
  EXPECT_FALSE(GatherWorkspaceReport(ws.string(), 64).contains("view_agreement"));  // not run: no section
  WriteFileAtomic((ws / "dense/stereo/view_agreement.json").string(),
                  R"({"scored": 3, "median": 0.8, "scale": 0.08, "z_threshold": 3.5, "capture_poor": false,
                      "views": [{"name": "a.png", "figure": 0.8, "z": 0, "flagged": false},
                                {"name": "b.png", "figure": 0.2, "z": -7.5, "flagged": true},
                                {"name": "c.png", "figure": null, "z": null, "flagged": false}],
                      "flagged": ["b.png"]})");
  const nlohmann::json report = GatherWorkspaceReport(ws.string(), 64);
  ASSERT_TRUE(report.contains("view_agreement")) << report.dump();
  const nlohmann::json& a = report["view_agreement"];
  ASSERT_EQ(a["flagged"].size(), 1u);
  EXPECT_EQ(a["flagged"][0]["name"], "b.png");
  EXPECT_DOUBLE_EQ(a["flagged"][0]["z"].get<double>(), -7.5);
  EXPECT_DOUBLE_EQ(a["median"].get<double>(), 0.8);
  WriteFileAtomic((ws / "dense/stereo/view_agreement.json").string(), R"({"views": 3})");
  const std::string error = ErrorOf(ws, false);
  EXPECT_NE(error.find("view_agreement.json"), std::string::npos) << error;
  EXPECT_NE(error.find("multi_depth"), std::string::npos) << error;
}

// The capture's kind, the stages the plan skipped with their reasons, and the race's verdict
// (issue 66) reach the page's data.
TEST(Report, CaptureKindSkippedStagesAndRace) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_report_plan");
  WriteFileAtomic((ws / "records/volume.json").string(),
                  R"({"stage": "volume", "status": "skipped", "skipped_because": "volume: skipped, the capture is general"})");
  WriteFileAtomic((ws / "records/surfels.json").string(), R"({"stage": "surfels", "status": "ok", "wall_seconds": 1})");
  nlohmann::json report = GatherWorkspaceReport(ws.string(), 64);
  EXPECT_FALSE(report.contains("capture"));  // no poses yet: no section
  EXPECT_FALSE(report.contains("race"));
  WriteFileAtomic((ws / "capture.json").string(), R"j({"kind": "general", "reason": "general (11 views)", "views": 11})j");
  WriteFileAtomic((ws / "race.json").string(),
                  R"({"scale": 0.25, "validation": ["b.png"], "best": "surfels", "models": {"surfels": 20.5},
                      "winners": ["surfels"], "seconds": 3})");
  report = GatherWorkspaceReport(ws.string(), 64);
  EXPECT_EQ(report["capture"]["kind"], "general");
  EXPECT_EQ(report["race"]["best"], "surfels");
  EXPECT_TRUE(report["race"]["left_out"].is_array());  // filled in where the race left nothing out
  bool found = false;
  for (const nlohmann::json& stage : report["stages"]) {
    if (stage["stage"] == "volume") {
      found = true;
      EXPECT_EQ(stage["status"], "skipped");
      EXPECT_EQ(stage["skipped_because"], "volume: skipped, the capture is general");
    }
  }
  EXPECT_TRUE(found) << report["stages"].dump();
}

TEST(Report, MalformedSweepJsonNamesTheFile) {
  const fs::path folder = ibmr_testing::ScratchDir("ibmr_report_sweep");
  const std::string path = (folder / "sweep.json").string();
  WriteFileAtomic(path, R"({"variants": [{"name": "v00", "stages": [{"stage": "a", "metrics": {}}]}]})");
  EXPECT_EQ(ErrorOf(folder, true), "");
  for (const std::string text : {R"({"variants": [1, 2]})", R"({"variants": [{"name": "v00", "stag)", "[1]"}) {
    WriteFileAtomic(path, text);
    const std::string error = ErrorOf(folder, true);
    EXPECT_NE(error.find(path + ": "), std::string::npos) << text << ": " << error;
    EXPECT_NE(error.find("run the sweep again"), std::string::npos) << error;
  }
}

// A workspace named in another encoding than UTF-8 made the page's JSON throw an opaque
// "incomplete UTF-8 string".
TEST(Report, NonUtf8WorkspaceNameWritesThePage) {
  const fs::path ws = ibmr_testing::ScratchDir("ibmr_report_caf\xe9");
  WriteFileAtomic((ws / "records/carve.json").string(), R"({"stage": "carve", "status": "ok"})");
  ReportOptions options;
  options.path = ws.string();
  options.chart_js = (ws / "chart.js").string();
  WriteFileAtomic(options.chart_js, "// Chart.js stand-in");
  std::string page;
  ASSERT_NO_THROW(page = ReadFile(WriteReport(options)));
  EXPECT_NE(page.find("caf\xef\xbf\xbd"), std::string::npos);
}

}  // namespace
}  // namespace ibmr
