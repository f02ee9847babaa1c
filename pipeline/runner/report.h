// ibmr report: one self-contained HTML page (report/index.html; opens from disk, no network) for a
// workspace or a sweep folder. Charts are drawn by Chart.js from Debian's libjs-chart.js, inlined
// into the page with the data as JSON; images are embedded as JPEG data URIs.
//
// A workspace: per-stage wall time, CPU time and peak memory; the held-out scores of every model;
// the selection (scores/selection.json) as a size-error chart with its envelope; per held-out view
// the photo, each model's render and its error (score's side-by-side images).
// A sweep (sweep.json): time against held-out PSNR for every model of every variant with the
// Pareto front; per-stage time per variant; the variants' table; stability curves when the sweep
// varied a degradation's strength.
//
// A workspace's page also shows its model in a 3D viewer (report_viewer.h): the textured mesh,
// surfel mesh, fused points, hull or volume planes, and the cameras, drawn by three.js from
// Debian's libjs-three, inlined like Chart.js.
//
// The page checks itself: when its scripts have run it writes, into <pre id="selfcheck">,
// "charts=N drawn=M errors=E" (how many charts it drew, how many have pixels, how many script
// errors), on a workspace's page " viewer=W" (report_viewer.h: drawn, none, blank, unreadable,
// nowebgl, nothree), then the errors' messages, for headless tests. WebGL in headless Chromium
// runs on SwiftShader: chromium --headless --use-angle=swiftshader --enable-unsafe-swiftshader
// (Chromium 156 still falls back to it without the flags, with a deprecation warning;
// --use-gl=swiftshader leaves the page without WebGL).
#pragma once

#include <nlohmann/json.hpp>
#include <string>

#include "pipeline/runner/report_viewer.h"

namespace ibmr {

// Where Debian's libjs-chart.js puts the UMD build the page inlines.
inline constexpr const char* kChartJsPath = "/usr/share/javascript/chart.js/chart.min.js";

struct ReportOptions {
  std::string path;           // a workspace, or a sweep folder (holding sweep.json)
  std::string out;            // default: <path>/report/index.html
  std::string chart_js = kChartJsPath;
  int image_width = 720;      // embedded side-by-side images are scaled down to this width
  std::string three_js = kThreeJsPath;              // the viewer's three.js and orbit controls; when
  std::string orbit_controls_js = kOrbitControlsPath;  // missing, the page says the viewer needs them
  ViewerOptions viewer;       // report.max_faces and the viewer's other budgets
};

// The data the page charts, gathered from the folder (exposed for tests); `scores` (optional)
// receives scores/heldout.json as read, for the viewer.
nlohmann::json GatherWorkspaceReport(const std::string& workspace, int image_width, nlohmann::json* scores = nullptr);
nlohmann::json GatherSweepReport(const std::string& sweep_folder);

// Writes the page; returns its path. Throws InputError naming what is missing (the folder holds
// neither records/ nor sweep.json; Chart.js is not installed) or an option out of range. A model
// that cannot be read does not stop it: the page says which and why.
std::string WriteReport(const ReportOptions& options);

}  // namespace ibmr
