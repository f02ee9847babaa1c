// Benchmark of the volume stage's fitting step (volume_fit.cc): seconds of one step's objective and
// gradient per view megapixel per plane, and of the objective alone, with the process's peak
// memory, on a given number of threads. Scene, as a forward-facing capture's finest level is: a
// volume of `planes` planes in inverse depth from 1.2 to 9.75, its image 1.19 x 1.16 the views'
// (the stage widens it to hold every view), partly transparent textured cells with an opaque far
// plane; `views` cameras on a small grid in front of it, each turned by up to 2 degrees (a hand-held
// capture's axes).
//
//   build/stages/volume/bench_volume [--threads 2] [--width 1008] [--height 756] [--planes 32]
//                                    [--views 6] [--repeats 3] [--out FILE.json]
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

#include "pipeline/core/process_memory.h"
#include "stages/volume/volume.h"

namespace {

double Seconds(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 2, width = 1008, height = 756, planes = 32, views = 6, repeats = 3;
  std::string out;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string flag = argv[i], value = argv[i + 1];
    if (flag == "--threads") threads = std::stoi(value);
    else if (flag == "--width") width = std::stoi(value);
    else if (flag == "--height") height = std::stoi(value);
    else if (flag == "--planes") planes = std::stoi(value);
    else if (flag == "--views") views = std::stoi(value);
    else if (flag == "--repeats") repeats = std::stoi(value);
    else if (flag == "--out") out = value;
    else {
      std::cerr << "unknown option " << flag << "\n";
      return 2;
    }
  }
  if (planes < 2 || views < 1 || repeats < 1 || width < 16 || height < 16) {
    std::cerr << "needs --planes >= 2, --views >= 1, --repeats >= 1, --width and --height >= 16\n";
    return 2;
  }
  tbb::global_control control(tbb::global_control::max_allowed_parallelism, threads);
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> unit(0, 1);

  ibmr::PlaneVolume volume;
  const int volume_width = static_cast<int>(std::lround(1.19 * width));
  const int volume_height = static_cast<int>(std::lround(1.16 * height));
  const double focal = 0.8 * width;
  volume.camera = ibmr::Camera::Pinhole(volume_width, volume_height, focal, focal, 0.5 * volume_width, 0.5 * volume_height);
  volume.cam_from_world = ibmr::Rigid3d(Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero());
  volume.depths = ibmr::PlaneDepths(1.2, 9.75, planes);
  volume.Allocate();
  for (int k = 0; k < planes; ++k) {
    float* plane = volume.Plane(k);
    for (int y = 0; y < volume_height; ++y) {
      for (int x = 0; x < volume_width; ++x) {
        float* cell = plane + (static_cast<size_t>(y) * volume_width + x) * 4;
        for (int c = 0; c < 3; ++c) cell[c] = 0.5f + 0.4f * std::sin(0.05f * x * (c + 1) + 0.07f * y + k);
        const float blob = std::sin(0.02f * x + 0.9f * k) * std::cos(0.025f * y - 0.4f * k);
        cell[3] = k == planes - 1 ? 1.f : blob > 0.8f ? 0.9f : 0.03f;  // mostly clear, some opaque patches
      }
    }
  }

  std::vector<ibmr::LevelView> level_views(views);
  const int columns = std::max(1, static_cast<int>(std::ceil(std::sqrt(views))));
  for (int v = 0; v < views; ++v) {
    ibmr::LevelView& view = level_views[v];
    view.camera = ibmr::Camera::Pinhole(width, height, focal, focal, 0.5 * width, 0.5 * height);
    const Eigen::Vector3d centre(0.08 * (v % columns - 0.5 * (columns - 1)), 0.08 * (v / columns - 0.5), 0.0);
    const Eigen::Vector3d axis = Eigen::Vector3d(unit(rng) - 0.5, unit(rng) - 0.5, unit(rng) - 0.5).normalized();
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(2.0 * M_PI / 180.0 * unit(rng), axis).toRotationMatrix();
    view.cam_from_world = ibmr::Rigid3d(turn, -(turn * centre));
    view.image.create(height, width, CV_32FC3);
    cv::randu(view.image, 0.0, 1.0);
  }

  ibmr::VolumeOptions options;
  options.num_planes = planes;
  std::vector<float> gradient, scratch;
  double with_gradient = 0, objective_only = 0, objective = 0;
  for (int r = 0; r < repeats; ++r) {
    auto start = std::chrono::steady_clock::now();
    objective = ibmr::VolumeObjective(volume, level_views, options, &gradient, nullptr, &scratch);
    with_gradient += Seconds(start) / repeats;
    start = std::chrono::steady_clock::now();
    ibmr::VolumeObjective(volume, level_views, options, nullptr, nullptr, &scratch);
    objective_only += Seconds(start) / repeats;
  }
  const double per = views * (width * height / 1e6) * planes;
  const nlohmann::json result = {
      {"benchmark", "volume fitting step"},
      {"threads", threads},
      {"width", width},
      {"height", height},
      {"volume_width", volume_width},
      {"volume_height", volume_height},
      {"planes", planes},
      {"views", views},
      {"objective", objective},
      {"step_seconds", with_gradient},
      {"objective_seconds", objective_only},
      {"step_seconds_per_mpx_per_plane", with_gradient / per},
      {"objective_seconds_per_mpx_per_plane", objective_only / per},
      {"resident_mb", ibmr::ResidentMemoryMb()},
  };
  if (out.empty()) {
    std::cout << result.dump(2) << "\n";
  } else {
    std::ofstream(out) << result.dump(2) << "\n";
  }
  return 0;
}
