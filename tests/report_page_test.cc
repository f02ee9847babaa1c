// The report pages as a reader opens them: a small synthetic config (synth -> silhouettes ->
// carve -> render of the plane, the hull and a decimated hull -> score -> select) swept over
// render.supersample; the second variant reuses every upstream stage of the first; `ibmr report`
// on a variant and on the sweep writes pages that headless Chromium (Debian's chromium, installed
// by the test set-up) loads with no script error and with every chart drawn (the page's own
// self-check: canvases with painted pixels); screenshots are saved beside the test for a look.
// The 3D viewer (report_viewer.h) on hand-made workspaces: a textured mesh, only fused points, a
// volume folder, corrupt model files and no model at all; the page's self-check reads the WebGL
// canvas back. Skipped with a message where chromium is not installed.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <regex>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/plane_volume.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/textured_mesh.h"
#include "tests/run_command.h"
#include "tests/scratch_dir.h"

namespace fs = std::filesystem;

namespace {

// Loads `page` in headless Chromium and returns the self-check line the page writes. WebGL runs on
// SwiftShader, Chromium's software renderer: --use-angle=swiftshader --enable-unsafe-swiftshader
// (without the second flag Chromium 156 still falls back to it but warns that the fallback is
// deprecated; --use-gl=swiftshader gives no WebGL at all).
std::string SelfCheck(const fs::path& page, const fs::path& screenshot) {
  const std::string flags = "--headless --no-sandbox --disable-gpu --use-angle=swiftshader --enable-unsafe-swiftshader "
                            "--hide-scrollbars --virtual-time-budget=10000 ";
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
  EXPECT_NE(variant_check.find("viewer=drawn"), std::string::npos) << "the hull in the viewer: " << variant_check;
  const std::string sweep_check = SelfCheck(sweep / "report" / "index.html", shots / "report_sweep.png");
  std::cout << "sweep page: " << sweep_check << "; screenshot " << (shots / "report_sweep.png") << "\n";
  ExpectAllChartsDrawn(sweep_check, 2);  // speed-accuracy, time per stage
  EXPECT_EQ(sweep_check.find("viewer="), std::string::npos) << "a sweep's page has no viewer: " << sweep_check;
  EXPECT_TRUE(fs::exists(shots / "report_sweep.png"));

  // Something that is neither a workspace nor a sweep is named.
  const auto wrong = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " report '" + root.string() + "'");
  EXPECT_NE(wrong.exit_code, 0);
  EXPECT_NE(wrong.output.find("neither sweep.json"), std::string::npos) << wrong.output;
}

// --- The 3D viewer on hand-made workspaces. ---

bool ChromiumMissing() { return ibmr_e2e::RunCommand("command -v chromium").exit_code != 0; }

// Eight cameras on a ring of radius 3 around the origin, looking at it, image up along +z; the
// sixth and eighth held out, scored by a "textured" and a "hull" model.
void WriteRingCameras(const fs::path& ws) {
  ibmr::SparseModel model;
  model.cameras[1] = ibmr::Camera::Pinhole(320, 240, 300, 300, 160, 120);
  for (int id = 1; id <= 8; ++id) {
    ibmr::Image image;
    image.image_id = id;
    image.camera_id = 1;
    image.name = "view" + std::to_string(id) + ".png";
    const double angle = id * M_PI / 4;
    image.cam_from_world = ibmr::LookAt({3 * std::cos(angle), 3 * std::sin(angle), 0.8}, {0, 0, 0}, {0, 0, 1});
    model.images[id] = image;
  }
  ibmr::WriteSparseModelText((ws / "sparse").string(), model);
  const nlohmann::json scores = {
      {"heldout", {"view6.png", "view8.png"}},
      {"proxies", {{"textured", {{"views", {{"view6.png", {{"photo_psnr", 23.5}}}, {"view8.png", {{"photo_psnr", 27.0}}}}}}},
                   {"hull", {{"views", {{"view6.png", {{"photo_psnr", 21.0}}}}}}}}}};
  ibmr::WriteFileAtomic((ws / "scores/heldout.json").string(), scores.dump());
}

// A workspace's records/ (what makes a folder a workspace for `ibmr report`).
fs::path NewWorkspace(const std::string& name) {
  const fs::path ws = ibmr_testing::ScratchDir(name);
  ibmr::WriteFileAtomic((ws / "records/import.json").string(), R"({"stage": "import", "status": "ok", "wall_seconds": 1})");
  return ws;
}

// A unit sphere as a latitude-longitude grid, textured with a checkerboard atlas page.
ibmr::TexturedMesh TexturedSphere() {
  ibmr::TexturedMesh sphere;
  const int rows = 24, cols = 48;
  for (int r = 0; r <= rows; ++r) {
    for (int c = 0; c <= cols; ++c) {
      const double theta = M_PI * r / rows, phi = 2 * M_PI * c / cols;
      sphere.mesh.vertices.emplace_back(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
    }
  }
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const int a = r * (cols + 1) + c, b = a + 1, d = a + cols + 1, e = d + 1;
      for (const Eigen::Vector3i& f : {Eigen::Vector3i(a, d, e), Eigen::Vector3i(a, e, b)}) {
        sphere.mesh.faces.push_back(f);
        Eigen::Matrix<float, 3, 2> uv;
        for (int k = 0; k < 3; ++k) {
          const int v = f[k];
          uv.row(k) << static_cast<float>(v % (cols + 1)) / cols, 1.f - static_cast<float>(v / (cols + 1)) / rows;
        }
        sphere.face_uv.push_back(uv);
        sphere.face_page.push_back(0);
      }
    }
  }
  cv::Mat page(256, 512, CV_8UC3);
  for (int y = 0; y < page.rows; ++y) {
    for (int x = 0; x < page.cols; ++x) {
      page.at<cv::Vec3b>(y, x) = ((x / 32 + y / 32) % 2) ? cv::Vec3b(40, 90, 200) : cv::Vec3b(230, 220, 40);
    }
  }
  sphere.pages = {page};
  return sphere;
}

// Writes the report of `ws`, loads it, returns the self-check (the screenshot beside the test).
std::string ViewerCheck(const fs::path& ws, const std::string& shot, std::string* page_text = nullptr) {
  const auto report = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " report '" + ws.string() + "'");
  EXPECT_EQ(report.exit_code, 0) << report.output;
  const fs::path page = ws / "report" / "index.html";
  if (page_text) *page_text = ibmr::ReadFile(page.string());
  const std::string check = SelfCheck(page, fs::current_path() / shot);
  std::cout << ws.filename() << ": " << check << "; screenshot " << (fs::current_path() / shot) << "\n";
  return check;
}

void ExpectViewer(const std::string& check, const std::string& viewer) {
  std::smatch match;
  ASSERT_TRUE(std::regex_search(check, match, std::regex("errors=(\\d+) viewer=(\\w+)"))) << check;
  EXPECT_EQ(match[1], "0") << "script errors: " << check;
  EXPECT_EQ(match[2], viewer) << check;
}

TEST(ReportViewer, TexturedMeshIsDrawnWithItsCameras) {
  if (ChromiumMissing()) GTEST_SKIP() << "chromium is not installed (scripts/test.sh installs it for the tests); skipping";
  const fs::path ws = NewWorkspace("ibmr_viewer_textured");
  ibmr::WriteTexturedGlb(TexturedSphere(), (ws / "texture/mesh.glb").string());
  WriteRingCameras(ws);
  std::string html;
  const std::string check = ViewerCheck(ws, "report_viewer_textured.png", &html);
  ExpectViewer(check, "drawn");
  // The held-out view8 carries its best model's score (the hover text), and the page loads nothing.
  EXPECT_NE(html.find(R"("model":"textured","name":"view8.png","score":27.0)"), std::string::npos);
  EXPECT_EQ(html.find("src=\"http"), std::string::npos);
  EXPECT_EQ(html.find("<link"), std::string::npos);
}

TEST(ReportViewer, FusedPointsAloneAreDrawn) {
  if (ChromiumMissing()) GTEST_SKIP() << "chromium is not installed (scripts/test.sh installs it for the tests); skipping";
  const fs::path ws = NewWorkspace("ibmr_viewer_points");
  ibmr::PointCloud cloud;
  for (int i = 0; i < 20000; ++i) {  // a Fibonacci sphere, coloured by height
    const double z = 1 - 2 * (i + 0.5) / 20000, r = std::sqrt(1 - z * z), phi = i * 2.399963229728653;
    cloud.positions.emplace_back(r * std::cos(phi), r * std::sin(phi), z);
    cloud.colors.emplace_back(static_cast<uint8_t>(127 + 127 * z), 60, static_cast<uint8_t>(127 - 127 * z));
  }
  ibmr::WritePointCloudPly((ws / "dense/fused.ply").string(), cloud);
  WriteRingCameras(ws);
  ExpectViewer(ViewerCheck(ws, "report_viewer_points.png"), "drawn");
}

TEST(ReportViewer, VolumePlanesAreDrawn) {
  if (ChromiumMissing()) GTEST_SKIP() << "chromium is not installed (scripts/test.sh installs it for the tests); skipping";
  const fs::path ws = NewWorkspace("ibmr_viewer_volume");
  // Four planes in the first ring camera's frame, written as the volume stage writes them.
  ibmr::PlaneVolume volume;
  volume.camera = ibmr::Camera::Pinhole(160, 120, 150.0, 150.0, 80.0, 60.0);
  volume.cam_from_world = ibmr::LookAt({3, 0, 0.8}, {0, 0, 0}, {0, 0, 1});
  volume.depths = {2.5, 2.9, 3.3, 3.7};
  volume.Allocate();
  for (int k = 0; k < 4; ++k) {
    cv::Mat rgba(120, 160, CV_8UC4, cv::Scalar(0, 0, 0, 0));
    cv::circle(rgba, {80, 60}, 20 + 10 * k, cv::Scalar(60 * k, 180, 255 - 60 * k, 200), -1);
    rgba.convertTo(cv::Mat(120, 160, CV_32FC4, volume.Plane(k)), CV_32FC4, 1.0 / 255.0);
  }
  ibmr::WritePlaneVolume((ws / "volume/view1.png").string(), volume);
  WriteRingCameras(ws);
  ExpectViewer(ViewerCheck(ws, "report_viewer_volume.png"), "drawn");
}

TEST(ReportViewer, CorruptModelsAreNamedAndTheNextOneShown) {
  if (ChromiumMissing()) GTEST_SKIP() << "chromium is not installed (scripts/test.sh installs it for the tests); skipping";
  const fs::path ws = NewWorkspace("ibmr_viewer_corrupt");
  ibmr::WriteFileAtomic((ws / "texture/mesh.glb").string(), "glTF\x02 truncated");
  ibmr::TriangleMesh hull;
  hull.vertices = {{-1, -1, -1}, {1, -1, -1}, {0, 1, -1}, {0, 0, 1}};
  hull.faces = {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {2, 0, 3}};
  ibmr::WriteMeshPly((ws / "hull/hull.ply").string(), hull);
  std::string html;
  ExpectViewer(ViewerCheck(ws, "report_viewer_corrupt.png", &html), "drawn");
  EXPECT_NE(html.find("texture/mesh.glb: not a binary glTF file"), std::string::npos);

  // Nothing readable: the page says so, with no script error.
  fs::remove(ws / "hull/hull.ply");
  ibmr::WriteFileAtomic((ws / "dense/fused.ply").string(), "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n");
  ExpectViewer(ViewerCheck(ws, "report_viewer_unreadable.png"), "unreadable");
}

TEST(ReportViewer, NoModelMeansNoViewer) {
  if (ChromiumMissing()) GTEST_SKIP() << "chromium is not installed (scripts/test.sh installs it for the tests); skipping";
  const fs::path ws = NewWorkspace("ibmr_viewer_none");
  WriteRingCameras(ws);
  ExpectViewer(ViewerCheck(ws, "report_viewer_none.png"), "none");
}

}  // namespace
