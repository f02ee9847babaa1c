// Benchmark of the per-pixel unstructured lumigraph renderer (seed 001 section 4.1; goal
// "real-time" [U 85]): render time per megapixel per source view, on a given number of threads.
// Scene: a textured ground plane seen by a ring of N source cameras; desired views between them;
// proxies: the plane (no visibility maps) and a 2-triangle-per-cell grid mesh of the same plane
// (visibility maps from the rasterizer; their construction is timed apart). Point splatting (seed
// 004) of the sources' depth maps of the plane, all samples and merged by tiles: milliseconds per
// output megapixel per million splats.
//
//   build-x/stages/render/bench_render [--threads 2] [--width 640] [--height 480] [--out FILE.json]
// Writes JSON (stdout when --out is absent).
#include <tbb/global_control.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "pipeline/core/process_memory.h"
#include "stages/render/depth_images.h"
#include "stages/render/render.h"
#include "stages/render/splat.h"

namespace {

using ibmr::Camera;
using ibmr::Rigid3d;
using ibmr::SourceView;

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

SourceView RingView(int i, int count, int width, int height) {
  SourceView view;
  const double a = 2 * M_PI * i / count;
  const Eigen::Vector3d eye(1.5 * std::cos(a), 1.5 * std::sin(a), 3.0);
  view.camera = Camera::Pinhole(width, height, 0.9 * width, 0.9 * width, width / 2.0, height / 2.0);
  view.cam_from_world = ibmr::LookAt(eye, Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
  view.image = cv::Mat(height, width, CV_8UC3);
  const Rigid3d world_from_cam = view.cam_from_world.Inverse();
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const Eigen::Vector3d ray = world_from_cam.rotation * view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
      const double t = -eye.z() / ray.z();
      const double u = eye.x() + t * ray.x(), v = eye.y() + t * ray.y();
      view.image.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uint8_t>(128 + 100 * std::sin(9 * u)),
                                                 cv::saturate_cast<uint8_t>(128 + 100 * std::cos(7 * v)),
                                                 cv::saturate_cast<uint8_t>(128 + 100 * std::sin(5 * (u + v))));
    }
  }
  return view;
}

ibmr::TriangleMesh GridPlane(int cells) {
  ibmr::TriangleMesh mesh;
  for (int j = 0; j <= cells; ++j) {
    for (int i = 0; i <= cells; ++i) mesh.vertices.emplace_back(-3 + 6.f * i / cells, -3 + 6.f * j / cells, 0.f);
  }
  for (int j = 0; j < cells; ++j) {
    for (int i = 0; i < cells; ++i) {
      const int a = j * (cells + 1) + i;
      mesh.faces.emplace_back(a, a + 1, a + cells + 2);
      mesh.faces.emplace_back(a, a + cells + 2, a + cells + 1);
    }
  }
  return mesh;
}

}  // namespace

int main(int argc, char** argv) {
  ibmr::ConfigureHeap(argv);  // as ibmr does (pipeline/core/process_memory.h)
  int threads = 2, width = 640, height = 480;
  std::string out;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i];
    if (key == "--threads") threads = std::stoi(argv[i + 1]);
    else if (key == "--width") width = std::stoi(argv[i + 1]);
    else if (key == "--height") height = std::stoi(argv[i + 1]);
    else if (key == "--out") out = argv[i + 1];
    else {
      std::cerr << "unknown option " << key << "\nusage: bench_render [--threads N] [--width W] [--height H] [--out F]\n";
      return 2;
    }
  }
  tbb::global_control control(tbb::global_control::max_allowed_parallelism, threads);
  const double megapixels = width * height / 1e6;
  const ibmr::TriangleMesh mesh = GridPlane(64);
  nlohmann::json runs = nlohmann::json::array();
  for (int sources_count : {8, 16, 32}) {
    std::vector<SourceView> sources;
    for (int i = 0; i < sources_count; ++i) sources.push_back(RingView(i, sources_count, width, height));
    const int desired_views = 3;
    for (const std::string proxy : {"plane", "mesh"}) {
      std::vector<SourceView> used = sources;
      double visibility_seconds = 0;
      if (proxy == "mesh") {
        const auto start = std::chrono::steady_clock::now();
        for (SourceView& s : used) s.proxy_depth = ibmr::MeshDepth(mesh, s.camera, s.cam_from_world);
        visibility_seconds = Seconds(start);
      }
      const ibmr::UlrRenderer renderer(&used, ibmr::RenderOptions());
      double surface_seconds = 0, render_seconds = 0;
      size_t covered = 0;
      for (int d = 0; d < desired_views; ++d) {
        const double a = 2 * M_PI * (d + 0.37) / desired_views;
        const Rigid3d pose = ibmr::LookAt(Eigen::Vector3d(1.4 * std::cos(a), 1.4 * std::sin(a), 3.1),
                                          Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
        auto start = std::chrono::steady_clock::now();
        const ibmr::ProxySurface surface =
            proxy == "plane" ? ibmr::PlaneSurface({Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ()}, sources[0].camera, pose)
                             : ibmr::MeshSurface(mesh, sources[0].camera, pose);
        surface_seconds += Seconds(start);
        start = std::chrono::steady_clock::now();
        covered += renderer.Render(sources[0].camera, pose, surface).covered_pixels;
        render_seconds += Seconds(start);
      }
      const double per_view = render_seconds / desired_views;
      runs.push_back({{"model", "ulr"},
                      {"proxy", proxy},
                      {"sources", sources_count},
                      {"desired_views", desired_views},
                      {"seconds_per_view", per_view},
                      {"proxy_surface_seconds_per_view", surface_seconds / desired_views},
                      {"visibility_maps_seconds_total", visibility_seconds},
                      {"covered_fraction", covered / (desired_views * width * height * 1.0)},
                      {"ms_per_megapixel", 1e3 * per_view / megapixels},
                      {"ms_per_megapixel_per_source", 1e3 * per_view / megapixels / sources_count}});
    }
    // Splats: each source's depth map of the plane z = 0 (the mesh's depth), then tile merging.
    std::vector<ibmr::DepthImage> images(sources.size());
    for (size_t i = 0; i < sources.size(); ++i) {
      images[i].camera = sources[i].camera;
      images[i].cam_from_world = sources[i].cam_from_world;
      images[i].image = sources[i].image;
      images[i].depth = ibmr::MeshDepth(mesh, sources[i].camera, sources[i].cam_from_world);
      ibmr::FlagSamples(&images[i], 0.0);
    }
    for (const bool merge : {false, true}) {
      auto start = std::chrono::steady_clock::now();
      ibmr::DepthImageOptions depth_options;
      depth_options.merge = merge;
      ibmr::DetectSkins(&images, depth_options);
      if (merge) ibmr::MergeTiles(&images, depth_options);
      const ibmr::SplatCloud cloud = ibmr::CloudFromDepthImages(images);
      const double prepare_seconds = Seconds(start);
      double render_seconds = 0;
      size_t covered = 0;
      for (int d = 0; d < desired_views; ++d) {
        const double a = 2 * M_PI * (d + 0.37) / desired_views;
        const Rigid3d pose = ibmr::LookAt(Eigen::Vector3d(1.4 * std::cos(a), 1.4 * std::sin(a), 3.1),
                                          Eigen::Vector3d::Zero(), Eigen::Vector3d(0, 1, 0));
        start = std::chrono::steady_clock::now();
        covered += ibmr::RenderSplats(cloud, sources[0].camera, pose, ibmr::SplatOptions()).covered_pixels;
        render_seconds += Seconds(start);
      }
      const double per_view = render_seconds / desired_views;
      runs.push_back({{"model", merge ? "splat_depth_merged" : "splat_depth"},
                      {"sources", sources_count},
                      {"desired_views", desired_views},
                      {"splats", cloud.size()},
                      {"prepare_seconds", prepare_seconds},
                      {"seconds_per_view", per_view},
                      {"covered_fraction", covered / (desired_views * width * height * 1.0)},
                      {"ms_per_megapixel", 1e3 * per_view / megapixels},
                      {"ms_per_megapixel_per_million_splats", 1e3 * per_view / megapixels / (cloud.size() * 1e-6)}});
    }
  }
  const nlohmann::json result = {{"benchmark", "render (unstructured lumigraph per pixel; point splatting; CPU)"},
                                 {"threads", threads},
                                 {"width", width},
                                 {"height", height},
                                 {"k", ibmr::RenderOptions().k},
                                 {"runs", runs}};
  if (out.empty()) {
    std::cout << result.dump(2) << "\n";
  } else {
    std::ofstream(out) << result.dump(2) << "\n";
    std::cout << "wrote " << out << "\n";
  }
  return 0;
}
