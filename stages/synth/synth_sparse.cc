// The ground-truth sparse model of a synthetic scene: true cameras, and points sampled uniformly
// by area on the surface with their tracks in every view that sees them by the z-buffer (see
// BuildSynthSparseModel in synth.h). Test-data generation; follows no seed-paper section.
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "pipeline/core/rasterizer.h"
#include "stages/synth/synth.h"
#include "stages/synth/synth_scenes.h"

namespace ibmr {
namespace {

// Candidates drawn per requested point: many surface points (backs of walls behind the
// cameras, undersides) are seen by fewer than two views.
constexpr int kCandidatesPerPoint = 4;
// Views must see the surface at less than acos(0.2) = 78 degrees from its normal.
constexpr double kMinCosine = 0.2;
// Relative depth margin of the exact occlusion test (the point's own face is at t = z).
constexpr double kOcclusionMargin = 1e-7;

// A bounding volume hierarchy over the mesh's triangles for exact occlusion queries: the
// z-buffer samples pixel centres only, and a point near an occluding edge may be hidden on its own
// ray while the pixel centre is not (or the reverse).
class TriangleBvh {
 public:
  explicit TriangleBvh(const TriangleMesh& mesh) {
    const size_t n = mesh.faces.size();
    corners_.resize(n);
    std::vector<Eigen::Vector3d> centroids(n);
    for (size_t i = 0; i < n; ++i) {
      for (int k = 0; k < 3; ++k) corners_[i][k] = mesh.vertices[mesh.faces[i][k]].cast<double>();
      centroids[i] = (corners_[i][0] + corners_[i][1] + corners_[i][2]) / 3.0;
    }
    order_.resize(n);
    for (size_t i = 0; i < n; ++i) order_[i] = static_cast<int>(i);
    if (n > 0) Build(0, static_cast<int>(n), centroids);
  }

  // True when the segment from `origin` to origin + t_max * direction crosses a triangle.
  bool Occluded(const Eigen::Vector3d& origin, const Eigen::Vector3d& direction, double t_max) const {
    if (nodes_.empty()) return false;
    const Eigen::Vector3d inverse = direction.cwiseInverse();
    int stack[128];
    int size = 0;
    stack[size++] = 0;
    while (size > 0) {
      const Node& node = nodes_[stack[--size]];
      if (!HitsBox(node.box, origin, inverse, t_max)) continue;
      if (node.left < 0) {
        for (int i = node.begin; i < node.end; ++i) {
          if (HitsTriangle(corners_[order_[i]], origin, direction, t_max)) return true;
        }
      } else if (size + 2 <= 128) {
        stack[size++] = node.left;
        stack[size++] = node.right;
      }
    }
    return false;
  }

 private:
  struct Node {
    Eigen::AlignedBox3d box;
    int left = -1, right = -1;  // children; -1 for a leaf
    int begin = 0, end = 0;     // leaf range in order_
  };

  int Build(int begin, int end, const std::vector<Eigen::Vector3d>& centroids) {
    const int index = static_cast<int>(nodes_.size());
    nodes_.emplace_back();
    Eigen::AlignedBox3d box, centre_box;
    for (int i = begin; i < end; ++i) {
      for (int k = 0; k < 3; ++k) box.extend(corners_[order_[i]][k]);
      centre_box.extend(centroids[order_[i]]);
    }
    nodes_[index].box = box;
    if (end - begin <= 4) {
      nodes_[index].begin = begin;
      nodes_[index].end = end;
      return index;
    }
    int axis = 0;
    centre_box.sizes().maxCoeff(&axis);
    const int middle = (begin + end) / 2;
    std::nth_element(order_.begin() + begin, order_.begin() + middle, order_.begin() + end,
                     [&](int a, int b) { return centroids[a][axis] < centroids[b][axis]; });
    const int left = Build(begin, middle, centroids);
    const int right = Build(middle, end, centroids);
    nodes_[index].left = left;
    nodes_[index].right = right;
    return index;
  }

  static bool HitsBox(const Eigen::AlignedBox3d& box, const Eigen::Vector3d& origin, const Eigen::Vector3d& inverse,
                      double t_max) {
    double t0 = 0, t1 = t_max;
    for (int a = 0; a < 3; ++a) {
      double near = (box.min()[a] - origin[a]) * inverse[a], far = (box.max()[a] - origin[a]) * inverse[a];
      if (near > far) std::swap(near, far);
      t0 = std::max(t0, near);
      t1 = std::min(t1, far);
      if (t0 > t1) return false;
    }
    return true;
  }

  // Moller-Trumbore: a hit with 0 < t < t_max.
  static bool HitsTriangle(const std::array<Eigen::Vector3d, 3>& c, const Eigen::Vector3d& origin,
                           const Eigen::Vector3d& direction, double t_max) {
    const Eigen::Vector3d e1 = c[1] - c[0], e2 = c[2] - c[0];
    const Eigen::Vector3d p = direction.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-300) return false;
    const Eigen::Vector3d s = origin - c[0];
    const double u = s.dot(p) / det;
    if (u < 0 || u > 1) return false;
    const Eigen::Vector3d q = s.cross(e1);
    const double v = direction.dot(q) / det;
    if (v < 0 || u + v > 1) return false;
    const double t = e2.dot(q) / det;
    return t > 0 && t < t_max;
  }

  std::vector<std::array<Eigen::Vector3d, 3>> corners_;
  std::vector<int> order_;
  std::vector<Node> nodes_;
};

struct Candidate {
  Eigen::Vector3d point;
  Eigen::Vector3d face_normal;     // unit, geometric
  Eigen::Vector3d shading_normal;  // unit, as rendered
  int face = 0;
  int part = 0;
};

struct Observation {
  int candidate = 0;
  Eigen::Vector2d xy;
};

// Points uniformly distributed by area on the mesh, in a seeded order.
std::vector<Candidate> SampleSurface(const SynthScene& scene, int count, uint64_t seed) {
  const TriangleMesh& mesh = scene.mesh;
  std::vector<double> cumulative_area(mesh.faces.size());
  double total = 0;
  for (size_t i = 0; i < mesh.faces.size(); ++i) {
    const Eigen::Vector3i& f = mesh.faces[i];
    const Eigen::Vector3d a = mesh.vertices[f[0]].cast<double>();
    total += 0.5 * (mesh.vertices[f[1]].cast<double>() - a).cross(mesh.vertices[f[2]].cast<double>() - a).norm();
    cumulative_area[i] = total;
  }
  std::mt19937_64 rng(seed);
  std::vector<Candidate> candidates(count);
  for (Candidate& c : candidates) {
    const double target = synth_internal::Uniform01(&rng) * total;
    c.face = static_cast<int>(std::upper_bound(cumulative_area.begin(), cumulative_area.end(), target) -
                              cumulative_area.begin());
    c.face = std::min(c.face, static_cast<int>(mesh.faces.size()) - 1);
    c.part = scene.face_part[c.face];
    // Uniform barycentrics: (1 - sqrt(r1), sqrt(r1) (1 - r2), sqrt(r1) r2).
    const double r1 = std::sqrt(synth_internal::Uniform01(&rng)), r2 = synth_internal::Uniform01(&rng);
    const double b[3] = {1.0 - r1, r1 * (1.0 - r2), r1 * r2};
    const Eigen::Vector3i& f = mesh.faces[c.face];
    const Eigen::Vector3d v0 = mesh.vertices[f[0]].cast<double>(), v1 = mesh.vertices[f[1]].cast<double>(),
                          v2 = mesh.vertices[f[2]].cast<double>();
    c.point = b[0] * v0 + b[1] * v1 + b[2] * v2;
    c.face_normal = (v1 - v0).cross(v2 - v0).normalized();
    c.shading_normal = c.face_normal;
    if (scene.parts[c.part].smooth) {
      const Eigen::Vector3d n = b[0] * mesh.normals[f[0]].cast<double>() + b[1] * mesh.normals[f[1]].cast<double>() +
                                b[2] * mesh.normals[f[2]].cast<double>();
      if (n.norm() > 1e-12) c.shading_normal = n.normalized();
    }
  }
  return candidates;
}

// True when `c` is seen by the view: in front, inside the image, facing the camera, nothing on
// its own ray in front of it, and the z-buffer's surface at the pixel holding its projection
// belongs to the same part at the same depth (within what the surface slope allows over the
// offset from the pixel centre).
bool Visible(const Candidate& c, const Image& view, const Camera& camera, const RasterResult& raster,
             const std::vector<int>& face_part, const TriangleBvh& bvh, Eigen::Vector2d* xy) {
  const Eigen::Vector3d in_cam = view.cam_from_world * c.point;
  if (in_cam.z() <= 1e-3) return false;
  const double cosine = c.face_normal.dot((view.Center() - c.point).normalized());
  if (cosine < kMinCosine) return false;
  *xy = camera.ImgFromCam(in_cam);
  if (!(xy->x() >= 0 && xy->y() >= 0 && xy->x() < camera.width && xy->y() < camera.height)) return false;
  const int x = static_cast<int>(xy->x()), y = static_cast<int>(xy->y());
  const int face = raster.face_id[static_cast<size_t>(y) * camera.width + x];
  if (face < 0 || face_part[face] != c.part) return false;
  const double tangent = std::sqrt(1.0 - cosine * cosine) / cosine;
  const double tolerance = 0.002 * in_cam.z() + 1.5 * in_cam.z() / camera.FocalX() * tangent;
  if (std::abs(raster.depth.At(x, y) - in_cam.z()) > tolerance) return false;
  // Ray parameter = z depth: the point itself is at t = z; anything before it occludes.
  const Eigen::Vector3d direction = view.cam_from_world.rotation.conjugate() * camera.CamFromImg(*xy);
  return !bvh.Occluded(view.Center(), direction, in_cam.z() * (1.0 - kOcclusionMargin));
}

}  // namespace

SparseModel BuildSynthSparseModel(const SynthScene& scene, const SynthOptions& options, ProgressReporter* progress) {
  NullProgress null_progress;
  if (progress == nullptr) progress = &null_progress;
  SparseModel model;
  model.cameras[scene.camera.camera_id] = scene.camera;
  for (const Image& view : scene.views) model.images[view.image_id] = view;
  if (options.sparse_points == 0) return model;

  const std::vector<Candidate> candidates =
      SampleSurface(scene, kCandidatesPerPoint * options.sparse_points,
                    synth_internal::Mix64(static_cast<uint64_t>(options.seed) ^ 0x5BA25Eull));
  const TriangleBvh bvh(scene.mesh);
  const int num_views = static_cast<int>(scene.views.size());
  std::vector<std::vector<Observation>> seen(num_views);
  progress->Begin("sparse visibility", num_views);
  tbb::parallel_for(0, num_views, [&](int v) {
    const Image& view = scene.views[v];
    const RasterResult raster = Rasterize(scene.mesh, scene.camera, view.cam_from_world);
    for (int i = 0; i < static_cast<int>(candidates.size()); ++i) {
      Eigen::Vector2d xy;
      if (Visible(candidates[i], view, scene.camera, raster, scene.face_part, bvh, &xy)) seen[v].push_back({i, xy});
    }
    progress->Advance(1, view.name);
  });
  progress->End();

  // Views of each candidate, in view order.
  std::vector<std::vector<std::pair<int, Eigen::Vector2d>>> tracks(candidates.size());
  for (int v = 0; v < num_views; ++v) {
    for (const Observation& o : seen[v]) tracks[o.candidate].emplace_back(v, o.xy);
  }
  int64_t next_id = 1;
  for (size_t i = 0; i < candidates.size() && next_id <= options.sparse_points; ++i) {
    if (tracks[i].size() < 2) continue;
    const Candidate& c = candidates[i];
    Point3D point;
    point.xyz = c.point;
    const Eigen::Vector3d rgb = 255.0 * SurfaceRadiance(scene, c.part, c.point, c.shading_normal);
    for (int k = 0; k < 3; ++k) point.color[k] = static_cast<uint8_t>(std::lround(std::clamp(rgb[k], 0.0, 255.0)));
    point.error = 0.0;
    for (const auto& [v, xy] : tracks[i]) {
      Image& image = model.images.at(scene.views[v].image_id);
      Point2D observation;
      observation.xy = xy;
      observation.point3D_id = next_id;
      image.points2D.push_back(observation);
      point.track.push_back({image.image_id, static_cast<int>(image.points2D.size()) - 1});
    }
    model.points[next_id++] = point;
  }
  return model;
}

}  // namespace ibmr
