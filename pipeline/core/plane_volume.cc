// A volume of RGBA planes in a virtual camera: ray sampling, compositing and files (see
// plane_volume.h; seed 000 lines 5526-5610).
#include "pipeline/core/plane_volume.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/plane_homography.h"

namespace fs = std::filesystem;

namespace ibmr {

void PlaneVolume::Allocate() { cells.assign(PlaneFloats() * depths.size(), 0.f); }

VolumeRays::VolumeRays(const PlaneVolume& volume, const Camera& camera, const Rigid3d& cam_from_world) {
  const Rigid3d volume_from_camera = volume.cam_from_world.Compose(cam_from_world.Inverse());
  direction_from_pixel_ = volume_from_camera.R() * camera.K().inverse();
  origin_ = volume_from_camera.translation;
  inverse_depths_.reserve(volume.depths.size());
  for (const double z : volume.depths) inverse_depths_.push_back(1.0 / z);
  fx_ = volume.camera.FocalX();
  fy_ = volume.camera.FocalY();
  cx_ = volume.camera.PrincipalX() - 0.5;  // index coordinates: pixel centres at integers
  cy_ = volume.camera.PrincipalY() - 0.5;
  width_ = volume.Width();
  height_ = volume.Height();
  planes_ = volume.Planes();
}

int VolumeRays::Samples(double u, double v, RaySample* out) const {
  const Ray ray = RayAt(u, v);
  int count = 0;
  for (int i = 0; i < planes_; ++i) count += On(ray, PlaneAt(ray, i), &out[count]) ? 1 : 0;
  return count;
}

void CompositePlaneVolume(const PlaneVolume& volume, const Camera& camera, const Rigid3d& cam_from_world,
                          cv::Mat* colour, cv::Mat* coverage) {
  const VolumeRays rays(volume, camera, cam_from_world);
  *colour = cv::Mat(camera.height, camera.width, CV_32FC3, cv::Scalar::all(0));
  *coverage = cv::Mat(camera.height, camera.width, CV_8UC1, cv::Scalar(0));
  const int planes = volume.Planes();
  tbb::parallel_for(tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      float* out = colour->ptr<float>(y);
      uint8_t* cover = coverage->ptr<uint8_t>(y);
      for (int x = 0; x < camera.width; ++x) {
        const VolumeRays::Ray ray = rays.RayAt(x + 0.5, y + 0.5);
        float c[3] = {0, 0, 0}, transmittance = 1.f;
        for (int i = 0; i < planes && transmittance > kOpaqueTransmittance; ++i) {
          RaySample s;
          if (!rays.On(ray, rays.PlaneAt(ray, i), &s) || !s.inside) continue;
          float cell[4];
          SampleCell(volume.Plane(s.plane), Footprint(volume.Width(), volume.Height(), s.x, s.y), cell);
          const float weight = cell[3] * transmittance;
          for (int ch = 0; ch < 3; ++ch) c[ch] += weight * cell[ch];
          transmittance *= 1.f - cell[3];
        }
        for (int ch = 0; ch < 3; ++ch) out[3 * x + ch] = c[ch];
        cover[x] = rays.ReachesFarPlane(ray) ? 255 : 0;
      }
    }
  });
}

std::vector<cv::Mat> PlaneImages(const PlaneVolume& volume) {
  std::vector<cv::Mat> planes(volume.Planes());
  for (int k = 0; k < volume.Planes(); ++k) {
    const cv::Mat cells(volume.Height(), volume.Width(), CV_32FC4, const_cast<float*>(volume.Plane(k)));
    cells.convertTo(planes[k], CV_8UC4, 255.0);
  }
  return planes;
}

bool CompositePlaneVolumeByWarps(const PlaneVolume& volume, const std::vector<cv::Mat>& planes, const Camera& camera,
                                 const Rigid3d& cam_from_world, cv::Mat* colour, cv::Mat* coverage) {
  // Every ray ahead through every plane: the centre in front of the nearest plane and every ray
  // toward larger z (d_z is affine in the pixel, so its sign at the image corners decides).
  const Rigid3d volume_from_camera = volume.cam_from_world.Compose(cam_from_world.Inverse());
  if (!(volume_from_camera.translation.z() < volume.depths.front())) return false;
  const Eigen::Matrix3d direction = volume_from_camera.R() * camera.K().inverse();
  for (const double u : {0.0, static_cast<double>(camera.width)}) {
    for (const double v : {0.0, static_cast<double>(camera.height)}) {
      if (!((direction * Eigen::Vector3d(u, v, 1.0)).z() > 0)) return false;
    }
  }
  std::vector<double> inverse_depths;
  for (const double z : volume.depths) inverse_depths.push_back(1.0 / z);
  const std::vector<Eigen::Matrix3d> volume_to_camera =
      PlaneHomographies(volume.camera, volume.cam_from_world, camera, cam_from_world, inverse_depths);
  // Index coordinates (pixel centres at integers) on both sides, camera -> volume.
  Eigen::Matrix3d to_pixel = Eigen::Matrix3d::Identity();
  to_pixel(0, 2) = to_pixel(1, 2) = 0.5;
  const Eigen::Matrix3d to_index = to_pixel.inverse();
  *colour = cv::Mat(camera.height, camera.width, CV_32FC3, cv::Scalar::all(0));
  *coverage = cv::Mat(camera.height, camera.width, CV_8UC1, cv::Scalar(0));
  cv::Mat warped(camera.height, camera.width, CV_8UC4);
  for (int k = volume.Planes() - 1; k >= 0; --k) {
    const Eigen::Matrix3d h = to_index * volume_to_camera[k].inverse() * to_pixel;
    cv::Mat map(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) map.at<double>(r, c) = h(r, c);
    cv::warpPerspective(planes[k], warped, map, warped.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                        cv::BORDER_CONSTANT, cv::Scalar::all(0));
    const bool far_plane = k == volume.Planes() - 1;
    tbb::parallel_for(tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
      for (int y = rows.begin(); y < rows.end(); ++y) {
        const uint8_t* in = warped.ptr<uint8_t>(y);
        float* out = colour->ptr<float>(y);
        for (int x = 0; x < camera.width; ++x) {
          const float a = in[4 * x + 3] * (1.f / 255.f);
          for (int ch = 0; ch < 3; ++ch) out[3 * x + ch] = in[4 * x + ch] * (1.f / 255.f) * a + (1.f - a) * out[3 * x + ch];
        }
        if (far_plane) {
          uint8_t* cover = coverage->ptr<uint8_t>(y);
          for (int x = 0; x < camera.width; ++x) cover[x] = in[4 * x + 3] >= 128 ? 255 : 0;
        }
      }
    });
  }
  return true;
}

namespace {

std::string PlaneFile(int k) {
  char name[32];
  std::snprintf(name, sizeof(name), "plane_%03d.png", k);
  return name;
}

}  // namespace

void WritePlaneVolume(const std::string& folder, const PlaneVolume& volume) {
  fs::create_directories(folder);
  nlohmann::json planes = nlohmann::json::array();
  for (int k = 0; k < volume.Planes(); ++k) {
    cv::Mat image(volume.Height(), volume.Width(), CV_8UC4);
    const float* cells = volume.Plane(k);
    for (int y = 0; y < volume.Height(); ++y) {
      uint8_t* row = image.ptr<uint8_t>(y);
      for (int i = 0; i < volume.Width() * 4; ++i) {
        row[i] = static_cast<uint8_t>(std::lround(std::clamp(cells[static_cast<size_t>(y) * volume.Width() * 4 + i], 0.f, 1.f) * 255.f));
      }
    }
    WriteImage(folder + "/" + PlaneFile(k), image);
    planes.push_back(PlaneFile(k));
  }
  const Eigen::Quaterniond& q = volume.cam_from_world.rotation;
  const Eigen::Vector3d& t = volume.cam_from_world.translation;
  const nlohmann::json json = {
      {"format", "ibmr_plane_volume"},
      {"version", 1},
      {"width", volume.Width()},
      {"height", volume.Height()},
      {"camera",
       {{"model", "PINHOLE"},
        {"params", {volume.camera.FocalX(), volume.camera.FocalY(), volume.camera.PrincipalX(), volume.camera.PrincipalY()}}}},
      {"cam_from_world", {{"qvec", {q.w(), q.x(), q.y(), q.z()}}, {"tvec", {t.x(), t.y(), t.z()}}}},
      {"depths", volume.depths},
      {"planes", planes},
      {"premultiplied", false},
  };
  WriteFileAtomic(folder + "/volume.json", json.dump(2) + "\n");
}

PlaneVolume ReadPlaneVolume(const std::string& folder) {
  const std::string json_path = folder + "/volume.json";
  const nlohmann::json json = ReadStageJson(json_path, "volume", "the volume's readers");
  PlaneVolume volume;
  try {
    if (json.value("format", "") != "ibmr_plane_volume") throw IoError("\"format\" is not \"ibmr_plane_volume\"");
    const int width = json.at("width").get<int>(), height = json.at("height").get<int>();
    const std::vector<double> params = json.at("camera").at("params").get<std::vector<double>>();
    if (width < 1 || height < 1 || params.size() != 4 || !(params[0] > 0) || !(params[1] > 0)) {
      throw IoError("\"width\", \"height\" must be >= 1 and \"camera\".\"params\" 4 numbers with fx, fy > 0");
    }
    volume.camera = Camera::Pinhole(width, height, params[0], params[1], params[2], params[3]);
    const std::vector<double> q = json.at("cam_from_world").at("qvec").get<std::vector<double>>();
    const std::vector<double> t = json.at("cam_from_world").at("tvec").get<std::vector<double>>();
    if (q.size() != 4 || t.size() != 3) throw IoError("\"cam_from_world\" needs qvec (4) and tvec (3)");
    volume.cam_from_world = Rigid3d(Eigen::Quaterniond(q[0], q[1], q[2], q[3]), Eigen::Vector3d(t[0], t[1], t[2]));
    volume.depths = json.at("depths").get<std::vector<double>>();
    const std::vector<std::string> planes = json.at("planes").get<std::vector<std::string>>();
    if (volume.depths.size() < 2 || planes.size() != volume.depths.size()) {
      throw IoError("\"depths\" needs at least 2 planes and \"planes\" one file per depth");
    }
    for (size_t k = 0; k < volume.depths.size(); ++k) {
      if (!(volume.depths[k] > 0) || (k > 0 && !(volume.depths[k] > volume.depths[k - 1]))) {
        throw IoError("\"depths\" must be positive and ascending");
      }
    }
    volume.Allocate();
    for (size_t k = 0; k < planes.size(); ++k) {
      const std::string path = folder + "/" + planes[k];
      if (!fs::exists(path)) throw InputError(path + " does not exist (listed in " + json_path + "); re-run the volume stage");
      const cv::Mat image = ReadImageUnchanged(path);
      if (image.cols != width || image.rows != height || image.type() != CV_8UC4) {
        throw IoError(path + ": must be an 8-bit RGBA PNG of " + std::to_string(width) + "x" + std::to_string(height) +
                      " (volume.json); re-run the volume stage");
      }
      float* cells = volume.Plane(static_cast<int>(k));
      for (int y = 0; y < height; ++y) {
        const uint8_t* row = image.ptr<uint8_t>(y);
        for (int i = 0; i < width * 4; ++i) cells[static_cast<size_t>(y) * width * 4 + i] = row[i] / 255.f;
      }
    }
  } catch (const nlohmann::json::exception& e) {
    throw IoError(json_path + ": " + e.what() + "; re-run the volume stage");
  } catch (const IoError& e) {
    const std::string what = e.what();
    if (what.rfind(folder, 0) == 0) throw;
    throw IoError(json_path + ": " + what + "; re-run the volume stage");
  }
  return volume;
}

}  // namespace ibmr
