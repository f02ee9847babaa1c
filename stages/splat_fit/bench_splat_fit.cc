// Benchmark of the splat rasterizer the fit and the splat_fit render model use
// (pipeline/core/splat_rasterizer.h): seconds of the forward and the backward pass per image
// megapixel per 100k splats, and the process's peak memory, on a given number of threads. Scene:
// `splats` discs of a surface-like density on a sphere of radius 1 (each about 1.5 of its
// neighbours' spacing wide, as the surfels stage makes them), seen from a ring of views at distance
// 4 filling about half the image, as an object capture's views are.
//
//   build/stages/splat_fit/bench_splat_fit [--threads 2] [--width 800] [--height 800]
//                                          [--splats 100000] [--views 8] [--out FILE.json]
//                                          [--ply SPLATS.ply --sparse SPARSE_DIR]
// With --ply and --sparse, a fitted model (splat_fit/splats.ply) is drawn instead into the first
// --views cameras of a COLMAP text model (a workspace's sparse/): the render model's own time per
// megapixel, as the render stage draws it, without the stage's other models sharing the cores.
// Writes JSON (stdout when --out is absent).
#include <tbb/global_control.h>

#include <Eigen/Geometry>
#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/process_memory.h"
#include "pipeline/core/splat_rasterizer.h"

namespace {

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

ibmr::SplatCamera RingCamera(int i, int count, int width, int height) {
  ibmr::SplatCamera camera;
  camera.width = width;
  camera.height = height;
  camera.fx = camera.fy = 1.1f * width;
  camera.cx = 0.5f * width;
  camera.cy = 0.5f * height;
  const float a = 6.2831853f * i / count;
  const Eigen::Vector3f eye(4 * std::cos(a), 4 * std::sin(a), 1.0f);
  const Eigen::Vector3f forward = (-eye).normalized();
  const Eigen::Vector3f right = forward.cross(Eigen::Vector3f::UnitZ()).normalized();
  camera.rotation.row(0) = right;
  camera.rotation.row(1) = forward.cross(right);
  camera.rotation.row(2) = forward;
  camera.translation = -camera.rotation * eye;
  return camera;
}

void Write(const nlohmann::json& result, const std::string& out) {
  if (out.empty()) {
    std::cout << result.dump(2) << "\n";
  } else {
    std::ofstream(out) << result.dump(2) << "\n";
  }
}

// --ply and --sparse: the fitted model drawn into the capture's cameras (forward pass only, as the
// render model draws it).
int DrawFittedModel(const std::string& ply, const std::string& sparse, int views, const std::string& out) {
  if (ply.empty() || sparse.empty()) {
    std::cerr << "--ply and --sparse go together\n";
    return 2;
  }
  try {
    const ibmr::GaussianSplats splats = ibmr::ReadGaussianSplatsPly(ply);
    const ibmr::SparseModel model = ibmr::ReadSparseModelText(sparse);
    ibmr::SplatFrame frame;
    double seconds = 0, megapixels = 0, drawn = 0;
    int drawn_views = 0;
    for (const auto& [id, image] : model.images) {
      if (drawn_views == views) break;
      const ibmr::SplatCamera camera = ibmr::ToSplatCamera(model.cameras.at(image.camera_id), image.cam_from_world);
      const auto start = std::chrono::steady_clock::now();
      ibmr::RenderSplats(splats, camera, ibmr::SplatRasterOptions(), &frame);
      seconds += Seconds(start);
      megapixels += camera.width * camera.height / 1e6;
      drawn += static_cast<double>(frame.drawn);
      ++drawn_views;
    }
    if (drawn_views == 0) throw std::runtime_error(sparse + " holds no image");
    Write({{"benchmark", "fitted splats drawn"},
           {"ply", ply},
           {"splats", splats.size()},
           {"views", drawn_views},
           {"mean_splats_drawn", drawn / drawn_views},
           {"seconds_per_view", seconds / drawn_views},
           {"seconds_per_mpx", seconds / megapixels},
           {"resident_mb", ibmr::ResidentMemoryMb()}},
          out);
    return 0;
  } catch (const std::exception& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 2, width = 800, height = 800, count = 100000, views = 8;
  std::string out, ply, sparse;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string flag = argv[i], value = argv[i + 1];
    if (flag == "--threads") threads = std::stoi(value);
    else if (flag == "--width") width = std::stoi(value);
    else if (flag == "--height") height = std::stoi(value);
    else if (flag == "--splats") count = std::stoi(value);
    else if (flag == "--views") views = std::stoi(value);
    else if (flag == "--out") out = value;
    else if (flag == "--ply") ply = value;
    else if (flag == "--sparse") sparse = value;
    else {
      std::cerr << "unknown option " << flag << "\n";
      return 2;
    }
  }
  tbb::global_control control(tbb::global_control::max_allowed_parallelism, threads);
  if (!ply.empty() || !sparse.empty()) return DrawFittedModel(ply, sparse, views, out);
  std::mt19937 rng(1);
  std::normal_distribution<float> normal(0, 1);
  std::uniform_real_distribution<float> unit(0, 1);
  ibmr::GaussianSplats splats;
  splats.sh_degree = 3;
  const float spacing = std::sqrt(4 * 3.14159265f / count);
  for (int i = 0; i < count; ++i) {
    const Eigen::Vector3f n = Eigen::Vector3f(normal(rng), normal(rng), normal(rng)).normalized();
    splats.Add(n, ibmr::RotationWithNormal(n), Eigen::Vector2f::Constant(std::log(0.75f * spacing)), 0.8f,
               Eigen::Vector3f(unit(rng), unit(rng), unit(rng)));
  }
  ibmr::SplatFrame frame;
  ibmr::SplatGradients gradients;
  gradients.Reset(splats);
  double forward = 0, backward = 0, megapixels = 0, drawn = 0;
  for (int v = 0; v < views; ++v) {
    const ibmr::SplatCamera camera = RingCamera(v, views, width, height);
    auto start = std::chrono::steady_clock::now();
    ibmr::RenderSplats(splats, camera, ibmr::SplatRasterOptions(), &frame);
    forward += Seconds(start);
    cv::Mat d_image(height, width, CV_32FC3, cv::Scalar::all(1e-6));
    start = std::chrono::steady_clock::now();
    ibmr::BackwardSplats(splats, camera, frame, d_image, &gradients);
    backward += Seconds(start);
    megapixels += width * height / 1e6;
    drawn += static_cast<double>(frame.drawn) / views;
  }
  const double per = megapixels * count / 1e5;
  const nlohmann::json result = {
      {"benchmark", "splat rasterizer"},
      {"threads", threads},
      {"width", width},
      {"height", height},
      {"splats", count},
      {"views", views},
      {"mean_splats_drawn", drawn},
      {"forward_seconds_per_mpx_per_100k", forward / per},
      {"backward_seconds_per_mpx_per_100k", backward / per},
      {"forward_seconds_per_view", forward / views},
      {"backward_seconds_per_view", backward / views},
      {"resident_mb", ibmr::ResidentMemoryMb()},
  };
  Write(result, out);
  return 0;
}
