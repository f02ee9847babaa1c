// Layered sprites with depth: drawing, compositing and files (layered_sprites.h).
#include "pipeline/core/layered_sprites.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/rasterizer.h"

namespace fs = std::filesystem;

namespace ibmr {

double LayerSet::PlaneDepth(size_t k, double px, double py) const {
  // The ray X = C + z R^T K^-1 p (z the camera depth) meets n.X = d at z = (d - n.C) / (n.R^T K^-1 p).
  const SpriteLayer& layer = layers[k];
  const Eigen::Vector3d ray_cam = camera.CamFromImg(Eigen::Vector2d(px, py));
  const Eigen::Matrix3d world_from_cam = cam_from_world.R().transpose();
  const Eigen::Vector3d centre = -(world_from_cam * cam_from_world.translation);
  const double denominator = layer.normal.dot(world_from_cam * ray_cam);
  if (std::abs(denominator) < 1e-12) return 0;
  const double z = (layer.offset - layer.normal.dot(centre)) / denominator;
  return z > 0 ? z : 0;
}

double LayerSet::Depth(size_t k, int x, int y) const {
  const double z = PlaneDepth(k, x + 0.5, y + 0.5);
  if (z <= 0) return 0;
  const cv::Mat& residual = layers[k].residual;
  const double r = residual.empty() ? 0.0 : residual.at<float>(y, x);
  return z + r > 0 ? z + r : 0;
}

namespace {

// One layer as a triangle mesh in world coordinates, into scratch.mesh with scratch.rgba per
// vertex (premultiplied colour, 0-255, and alpha, 0-1): a vertex per sprite pixel with alpha > 0,
// two triangles per 2x2 block whose corners are all in the sprite and whose depths agree.
void BuildLayerMesh(const LayerSet& set, size_t k, double max_depth_step, CompositeScratch* scratch) {
  const SpriteLayer& layer = set.layers[k];
  const int width = layer.rgba.cols, height = layer.rgba.rows;
  TriangleMesh& mesh = scratch->mesh;
  std::vector<int>& index = scratch->index;
  std::vector<float>& depth = scratch->vertex_depth;
  mesh.vertices.clear();
  mesh.faces.clear();
  scratch->rgba.clear();
  index.assign(static_cast<size_t>(width) * height, -1);
  depth.assign(index.size(), 0.f);
  const Eigen::Matrix3d world_from_cam = set.cam_from_world.R().transpose();
  const Eigen::Vector3d centre = -(world_from_cam * set.cam_from_world.translation);
  for (int y = 0; y < height; ++y) {
    const cv::Vec4b* row = layer.rgba.ptr<cv::Vec4b>(y);
    for (int x = 0; x < width; ++x) {
      if (row[x][3] == 0) continue;
      const double z = set.Depth(k, x, y);
      if (z <= 0) continue;
      const Eigen::Vector3d point = centre + world_from_cam * (z * set.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)));
      index[static_cast<size_t>(y) * width + x] = static_cast<int>(mesh.vertices.size());
      depth[static_cast<size_t>(y) * width + x] = static_cast<float>(z);
      mesh.vertices.push_back(point.cast<float>());
      const float a = row[x][3] / 255.0f;
      scratch->rgba.emplace_back(a * row[x][0], a * row[x][1], a * row[x][2], a);
    }
  }
  auto close = [&](float a, float b) { return std::abs(a - b) <= max_depth_step * std::min(a, b); };
  for (int y = 0; y + 1 < height; ++y) {
    for (int x = 0; x + 1 < width; ++x) {
      const size_t i00 = static_cast<size_t>(y) * width + x, i10 = i00 + 1, i01 = i00 + width, i11 = i01 + 1;
      const int a = index[i00], b = index[i10], c = index[i01], d = index[i11];
      // Two triangles (a, c, d) and (a, d, b) when present and without a depth step.
      if (a >= 0 && c >= 0 && d >= 0 && close(depth[i00], depth[i01]) && close(depth[i00], depth[i11])) {
        mesh.faces.emplace_back(a, c, d);
      }
      if (a >= 0 && d >= 0 && b >= 0 && close(depth[i00], depth[i11]) && close(depth[i00], depth[i10])) {
        mesh.faces.emplace_back(a, d, b);
      }
    }
  }
}

}  // namespace

void CompositeLayerRows(const LayerSet& set, const Camera& camera, const Rigid3d& cam_from_world, double max_depth_step,
                        CompositeScratch* scratch_in, const CompositedRow& row) {
  CompositeScratch own;
  CompositeScratch& scratch = scratch_in != nullptr ? *scratch_in : own;
  const int width = camera.width, height = camera.height;
  const size_t count = set.layers.size();
  // Each layer drawn a window of rows at a time (RasterizeWindows): the raster holds one window,
  // its covered pixels go to that window's fragments of the layer, drawn[w * count + k].
  const int window_rows = std::max(16, static_cast<int>(std::min<int64_t>(height, scratch.window_bytes / (kRasterBytesPerPixel * std::max(1, width)))));
  const int windows = (height + window_rows - 1) / window_rows;
  std::vector<LayerFragments>& drawn = scratch.drawn;
  if (drawn.size() < count * windows) drawn.resize(count * windows);
  for (size_t k = 0; k < count; ++k) {
    BuildLayerMesh(set, k, max_depth_step, &scratch);
    if (scratch.mesh.faces.empty()) {
      for (int w = 0; w < windows; ++w) {
        LayerFragments& layer = drawn[w * count + k];
        layer.row_start.assign(static_cast<size_t>(window_rows) + 1, 0);
        layer.column.clear(), layer.rgba.clear(), layer.depth.clear();
      }
      continue;
    }
    RasterizeWindows(scratch.mesh, camera, cam_from_world, RasterizeOptions(), window_rows, &scratch.raster,
                     [&](int first_row, const RasterResult& raster) {
      LayerFragments& layer = drawn[first_row / window_rows * count + k];
      const int rows = raster.depth.height;
      layer.row_start.assign(static_cast<size_t>(window_rows) + 1, 0);
      // The covered pixels of each row, then their offsets, then the fragments themselves.
      tbb::parallel_for(0, rows, [&](int y) {
        const int* face = raster.face_id.data() + static_cast<size_t>(y) * width;
        layer.row_start[static_cast<size_t>(y) + 1] = static_cast<size_t>(std::count_if(face, face + width, [](int f) { return f >= 0; }));
      });
      for (int y = 0; y < window_rows; ++y) layer.row_start[static_cast<size_t>(y) + 1] += layer.row_start[y];
      const size_t fragments = layer.row_start.back();
      layer.column.resize(fragments);
      layer.rgba.resize(fragments);
      layer.depth.resize(fragments);
      tbb::parallel_for(0, rows, [&](int y) {
        size_t f = layer.row_start[y];
        for (int x = 0; x < width; ++x) {
          if (raster.face_id[static_cast<size_t>(y) * width + x] < 0) continue;
          layer.column[f] = x;
          layer.rgba[f] = InterpolateAttribute(raster, scratch.mesh, scratch.rgba, x, y);
          layer.depth[f] = raster.depth.At(x, y);
          ++f;
        }
      });
    });
  }
  tbb::parallel_for(tbb::blocked_range<int>(0, height), [&](const tbb::blocked_range<int>& rows) {
    std::vector<std::pair<float, int>> order;
    order.reserve(count);
    // Each layer's next fragment on the row, and the fragment it has at the current pixel.
    std::vector<size_t> next(count), at(count);
    std::vector<cv::Vec3f> color(static_cast<size_t>(width));
    std::vector<float> alpha(static_cast<size_t>(width));
    for (int y = rows.begin(); y < rows.end(); ++y) {
      // The window's fragments of each layer, and the row's place in the window.
      const LayerFragments* window = drawn.data() + y / window_rows * count;
      const size_t r = static_cast<size_t>(y % window_rows);
      for (size_t k = 0; k < count; ++k) next[k] = window[k].row_start[r];
      for (int x = 0; x < width; ++x) {
        order.clear();
        for (size_t k = 0; k < count; ++k) {
          const LayerFragments& layer = window[k];
          if (next[k] == layer.row_start[r + 1] || layer.column[next[k]] != x) continue;
          at[k] = next[k]++;
          if (layer.depth[at[k]] > 0) order.emplace_back(layer.depth[at[k]], static_cast<int>(k));
        }
        // Back to front: the farthest first; each nearer layer goes over what is behind it.
        std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
        Eigen::Vector4f acc = Eigen::Vector4f::Zero();
        for (const auto& [z, k] : order) {
          const Eigen::Vector4f& front = window[k].rgba[at[k]];
          const float a = std::clamp(front[3], 0.f, 1.f);
          acc = front + (1.f - a) * acc;
        }
        color[x] = cv::Vec3f(acc[0], acc[1], acc[2]);
        alpha[x] = std::clamp(acc[3], 0.f, 1.f);
      }
      row(y, color.data(), alpha.data());
    }
  });
}

RgbaImage CompositeLayers(const LayerSet& set, const Camera& camera, const Rigid3d& cam_from_world, double max_depth_step,
                          CompositeScratch* scratch) {
  RgbaImage out;
  out.color = cv::Mat(camera.height, camera.width, CV_32FC3);
  out.alpha = cv::Mat(camera.height, camera.width, CV_32F);
  CompositeLayerRows(set, camera, cam_from_world, max_depth_step, scratch, [&](int y, const cv::Vec3f* color, const float* alpha) {
    std::copy(color, color + camera.width, out.color.ptr<cv::Vec3f>(y));
    std::copy(alpha, alpha + camera.width, out.alpha.ptr<float>(y));
  });
  return out;
}

cv::Mat CombinedDepth(const LayerSet& set, cv::Mat* front) {
  const int width = set.camera.width, height = set.camera.height;
  cv::Mat depth(height, width, CV_32F, cv::Scalar::all(0));
  if (front) *front = cv::Mat(height, width, CV_32S, cv::Scalar::all(-1));
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      float best = 0;
      int best_layer = -1;
      for (const int min_alpha : {255, 128}) {  // owned pixels first, then seams
        for (size_t k = 0; k < set.layers.size(); ++k) {
          if (set.layers[k].rgba.at<cv::Vec4b>(y, x)[3] < min_alpha) continue;
          const float z = static_cast<float>(set.Depth(k, x, y));
          if (z > 0 && (best == 0 || z < best)) best = z, best_layer = static_cast<int>(k);
        }
        if (best_layer >= 0) break;
      }
      depth.at<float>(y, x) = best;
      if (front) front->at<int>(y, x) = best_layer;
    }
  }
  return depth;
}

namespace {

FloatMap ToFloatMap(const cv::Mat& m) {
  FloatMap map(m.cols, m.rows, 1);
  for (int y = 0; y < m.rows; ++y)
    for (int x = 0; x < m.cols; ++x) map.At(x, y) = m.at<float>(y, x);
  return map;
}

cv::Mat FromFloatMap(const FloatMap& map) {
  cv::Mat m(map.height, map.width, CV_32F);
  for (int y = 0; y < map.height; ++y)
    for (int x = 0; x < map.width; ++x) m.at<float>(y, x) = map.At(x, y);
  return m;
}

}  // namespace

void WriteLayerSet(const std::string& folder, const LayerSet& set) {
  fs::create_directories(folder);
  nlohmann::json j = set.facts.is_object() ? set.facts : nlohmann::json::object();
  j["image"] = set.image;
  j["width"] = set.camera.width;
  j["height"] = set.camera.height;
  j["camera"] = {set.camera.FocalX(), set.camera.FocalY(), set.camera.PrincipalX(), set.camera.PrincipalY()};
  const Eigen::Quaterniond& q = set.cam_from_world.rotation;
  j["cam_from_world"] = {{"qvec", {q.w(), q.x(), q.y(), q.z()}},
                         {"tvec", {set.cam_from_world.translation.x(), set.cam_from_world.translation.y(),
                                   set.cam_from_world.translation.z()}}};
  nlohmann::json layers = nlohmann::json::array();
  for (size_t k = 0; k < set.layers.size(); ++k) {
    const SpriteLayer& layer = set.layers[k];
    const std::string sprite = "layer_" + std::to_string(k) + ".png";
    const std::string residual = "layer_" + std::to_string(k) + ".residual.bin";
    WriteImage(folder + "/" + sprite, layer.rgba);
    const cv::Mat r = layer.residual.empty() ? cv::Mat(layer.rgba.size(), CV_32F, cv::Scalar::all(0)) : layer.residual;
    WriteColmapArray(folder + "/" + residual, ToFloatMap(r));
    std::vector<cv::Mat> channels;
    cv::split(layer.rgba, channels);
    layers.push_back({{"normal", {layer.normal.x(), layer.normal.y(), layer.normal.z()}},
                      {"offset", layer.offset},
                      {"sprite", sprite},
                      {"residual", residual},
                      {"pixels", cv::countNonZero(channels[3])}});
  }
  j["layers"] = layers;
  j["order"] = "back to front from the reference view";
  WriteColmapArray(folder + "/depth.bin", ToFloatMap(CombinedDepth(set)));
  WriteFileAtomic(folder + "/layers.json", j.dump(2) + "\n");
}

LayerSet ReadLayerSet(const std::string& folder) {
  const std::string path = folder + "/layers.json";
  if (!fs::exists(path)) throw InputError(path + ": missing; run the layered_stereo stage");
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(ReadFile(path));
    LayerSet set;
    set.image = j.at("image").get<std::string>();
    const std::vector<double> k = j.at("camera").get<std::vector<double>>();
    if (k.size() != 4) throw InputError(path + ": \"camera\" must be [fx, fy, cx, cy]");
    set.camera = Camera::Pinhole(j.at("width").get<int>(), j.at("height").get<int>(), k[0], k[1], k[2], k[3]);
    const std::vector<double> q = j.at("cam_from_world").at("qvec").get<std::vector<double>>();
    const std::vector<double> t = j.at("cam_from_world").at("tvec").get<std::vector<double>>();
    if (q.size() != 4 || t.size() != 3) throw InputError(path + ": cam_from_world needs qvec (4) and tvec (3)");
    set.cam_from_world = Rigid3d(Eigen::Quaterniond(q[0], q[1], q[2], q[3]), Eigen::Vector3d(t[0], t[1], t[2]));
    for (const auto& l : j.at("layers")) {
      SpriteLayer layer;
      const std::vector<double> n = l.at("normal").get<std::vector<double>>();
      if (n.size() != 3) throw InputError(path + ": a layer's \"normal\" must have 3 numbers");
      layer.normal = Eigen::Vector3d(n[0], n[1], n[2]).normalized();
      layer.offset = l.at("offset").get<double>();
      const std::string sprite = folder + "/" + l.at("sprite").get<std::string>();
      layer.rgba = ReadImageUnchanged(sprite);
      if (layer.rgba.type() != CV_8UC4 || layer.rgba.cols != set.camera.width || layer.rgba.rows != set.camera.height) {
        throw InputError(sprite + ": a sprite must be 8-bit RGBA of the layers' size (" + std::to_string(set.camera.width) +
                         "x" + std::to_string(set.camera.height) + "); rerun layered_stereo");
      }
      const std::string residual = folder + "/" + l.at("residual").get<std::string>();
      const FloatMap r = ReadColmapArray(residual);
      if (r.width != set.camera.width || r.height != set.camera.height || r.channels != 1) {
        throw InputError(residual + ": the residual depth must be 1 channel of the sprite's size; rerun layered_stereo");
      }
      layer.residual = FromFloatMap(r);
      set.layers.push_back(std::move(layer));
    }
    set.facts = j;
    return set;
  } catch (const nlohmann::json::exception& e) {
    throw InputError(path + ": " + e.what() + "; rerun layered_stereo");
  }
}

}  // namespace ibmr
