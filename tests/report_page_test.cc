// The report pages as a reader opens them: a small synthetic config (synth -> silhouettes ->
// carve -> render of the plane, the hull and a decimated hull -> score -> select) swept over
// render.supersample; the second variant reuses every upstream stage of the first; `ibmr report`
// on a variant and on the sweep writes pages that headless Chromium (Debian's chromium, installed
// by the test set-up) loads with no script error and with every chart drawn (the page's own
// self-check: canvases with painted pixels); screenshots are saved beside the test for a look.
// Skipped with a message where chromium is not installed.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>

#include "tests/run_command.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace {

// Loads `page` in headless Chromium and returns the self-check line the page writes.
std::string SelfCheck(const fs::path& page, const fs::path& screenshot) {
  const std::string flags = "--headless --no-sandbox --disable-gpu --hide-scrollbars --virtual-time-budget=10000 ";
  const auto dom = ibmr_e2e::RunCommand("chromium " + flags + "--dump-dom 'file://" + page.string() + "' 2>/dev/null");
  ibmr_e2e::RunCommand("chromium " + flags + "--window-size=1400,2000 --screenshot='" + screenshot.string() + "' 'file://" +
                       page.string() + "' 2>/dev/null");
  std::smatch match;
  if (!std::regex_search(dom.output, match, std::regex("<pre id=\"selfcheck\">([^<]*)"))) return "no self-check in the page";
  return match[1];
}

void ExpectAllChartsDrawn(const std::string& check, int min_charts) {
  std::smatch match;
  ASSERT_TRUE(std::regex_search(check, match, std::regex("charts=(\\d+) drawn=(\\d+) errors=(\\d+)"))) << check;
  EXPECT_GE(std::stoi(match[1]), min_charts) << check;
  EXPECT_EQ(match[1], match[2]) << "a chart drew nothing: " << check;
  EXPECT_EQ(match[3], "0") << check;
}

TEST(ReportPage, SweepAndWorkspacePagesLoadAndDrawEveryChart) {
  if (ibmr_e2e::RunCommand("command -v chromium").exit_code != 0) {
    GTEST_SKIP() << "chromium is not installed (scripts/test.sh installs it for the tests); skipping";
  }
  const fs::path root = ibmr_testing::ScratchDir("ibmr_report_page");
  std::ofstream(root / "c.yaml") << "workspace: ws\nholdout: {every: 8}\nstages:\n"
                                    "  - synth: {scene: object_ring, views: 16, width: 240, height: 180}\n"
                                    "  - silhouettes: {mode: threshold, threshold: 0.1}\n"
                                    "  - carve: {levels: 5}\n"
                                    "  - render: {proxies: [plane, hull/hull.ply, \"hull_300=hull/hull.ply@300\"]}\n"
                                    "  - score: {}\n"
                                    "  - select: {}\n";
  const fs::path sweep = root / "sweep";
  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " sweep '" + (root / "c.yaml").string() +
                                        "' --vary render.supersample=1,2 --out '" + sweep.string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;

  // The second variant changed only render: everything before it was linked in, not recomputed.
  for (const std::string stage : {"synth", "silhouettes", "carve"}) {
    nlohmann::json record;
    std::ifstream(sweep / "v01" / "records" / (stage + ".json")) >> record;
    EXPECT_EQ(fs::path(record.value("reused_from", "")).filename(), "v00") << stage;
  }
  nlohmann::json render;
  std::ifstream(sweep / "v01" / "records" / "render.json") >> render;
  EXPECT_FALSE(render.contains("reused_from"));
  nlohmann::json summary;
  std::ifstream(sweep / "sweep.json") >> summary;
  ASSERT_EQ(summary["variants"].size(), 2u);
  EXPECT_FALSE(summary["pareto"].empty());

  const auto variant_page = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " report '" + (sweep / "v01").string() + "'");
  ASSERT_EQ(variant_page.exit_code, 0) << variant_page.output;
  const auto sweep_page = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " report '" + sweep.string() + "'");
  ASSERT_EQ(sweep_page.exit_code, 0) << sweep_page.output;

  const fs::path shots = fs::current_path();
  const std::string variant_check = SelfCheck(sweep / "v01" / "report" / "index.html", shots / "report_workspace.png");
  std::cout << "workspace page: " << variant_check << "; screenshot " << (shots / "report_workspace.png") << "\n";
  ExpectAllChartsDrawn(variant_check, 4);  // stage time, stage memory, model scores, selection
  const std::string sweep_check = SelfCheck(sweep / "report" / "index.html", shots / "report_sweep.png");
  std::cout << "sweep page: " << sweep_check << "; screenshot " << (shots / "report_sweep.png") << "\n";
  ExpectAllChartsDrawn(sweep_check, 2);  // speed-accuracy, time per stage
  EXPECT_TRUE(fs::exists(shots / "report_sweep.png"));

  // Something that is neither a workspace nor a sweep is named.
  const auto wrong = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " report '" + root.string() + "'");
  EXPECT_NE(wrong.exit_code, 0);
  EXPECT_NE(wrong.output.find("neither sweep.json"), std::string::npos) << wrong.output;
}

}  // namespace
