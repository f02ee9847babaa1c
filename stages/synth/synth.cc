// Synthetic scenes: options, solid texture and shading, scene assembly, rendering of one view and
// the scene description (see synth.h). Test-data generation; follows no seed-paper section.
#include "stages/synth/synth.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include "pipeline/core/rasterizer.h"
#include "stages/synth/synth_scenes.h"

namespace ibmr {
namespace {

using synth_internal::Mix64;

constexpr int kNoiseOctaves = 5;
constexpr double kPi = 3.14159265358979323846;

// Writes "key must be <constraint>, got <value>" into `error` when `ok` is false.
template <typename T>
bool Require(bool ok, const char* key, const char* constraint, const T& value, std::string* error) {
  if (ok) return true;
  if (error != nullptr) {
    std::ostringstream message;
    message << key << " must be " << constraint << ", got " << value;
    *error = message.str();
  }
  return false;
}

// Three independent lattice values in [0, 1] at integer point (x, y, z).
Eigen::Vector3d LatticeValue(int64_t x, int64_t y, int64_t z, uint64_t seed) {
  const uint64_t h = Mix64(seed ^ Mix64(static_cast<uint64_t>(x) * 0x8DA6B343ull ^
                                        static_cast<uint64_t>(y) * 0xD8163841ull ^
                                        static_cast<uint64_t>(z) * 0xCB1AB31Full));
  constexpr double kScale = 1.0 / 2097151.0;  // 21 bits per channel
  return Eigen::Vector3d(h & 0x1FFFFF, (h >> 21) & 0x1FFFFF, (h >> 42) & 0x1FFFFF) * kScale;
}

// Value noise: trilinear interpolation of lattice values with smoothstep weights.
Eigen::Vector3d ValueNoise(const Eigen::Vector3d& p, uint64_t seed) {
  const Eigen::Vector3d floor(std::floor(p.x()), std::floor(p.y()), std::floor(p.z()));
  const Eigen::Vector3d f = p - floor;
  const Eigen::Vector3d w = f.cwiseProduct(f).cwiseProduct(Eigen::Vector3d::Constant(3.0) - 2.0 * f);
  const int64_t x = static_cast<int64_t>(floor.x()), y = static_cast<int64_t>(floor.y()),
                z = static_cast<int64_t>(floor.z());
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (int corner = 0; corner < 8; ++corner) {
    const int dx = corner & 1, dy = (corner >> 1) & 1, dz = (corner >> 2) & 1;
    const double weight = (dx ? w.x() : 1 - w.x()) * (dy ? w.y() : 1 - w.y()) * (dz ? w.z() : 1 - w.z());
    sum += weight * LatticeValue(x + dx, y + dy, z + dz, seed);
  }
  return sum;
}

// Multi-octave value noise in [0, 1] per channel, contrast stretched so that texture is strong
// at every scale from 1/frequency down to 1/(16 frequency).
Eigen::Vector3d SolidTexture(const Eigen::Vector3d& point, uint64_t seed, double frequency) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double amplitude = 1.0, total = 0.0, scale = frequency;
  for (int octave = 0; octave < kNoiseOctaves; ++octave) {
    sum += amplitude * ValueNoise(point * scale, Mix64(seed + octave));
    total += amplitude;
    amplitude *= 0.8;
    scale *= 2.0;
  }
  const Eigen::Vector3d stretched = (sum / total - Eigen::Vector3d::Constant(0.5)) * 3.0;
  return (stretched + Eigen::Vector3d::Constant(0.5)).cwiseMax(0.0).cwiseMin(1.0);
}

// Per face: unit geometric normal (double).
std::vector<Eigen::Vector3d> FaceNormals(const TriangleMesh& mesh) {
  std::vector<Eigen::Vector3d> normals(mesh.faces.size());
  for (size_t i = 0; i < mesh.faces.size(); ++i) {
    const Eigen::Vector3i& f = mesh.faces[i];
    const Eigen::Vector3d a = mesh.vertices[f[0]].cast<double>(), b = mesh.vertices[f[1]].cast<double>(),
                          c = mesh.vertices[f[2]].cast<double>();
    normals[i] = (b - a).cross(c - a).normalized();
  }
  return normals;
}

// Standard normal samples from a seeded generator (Box-Muller, portable).
class GaussianSource {
 public:
  explicit GaussianSource(uint64_t seed) : rng_(seed) {}
  double Next() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double u1 = std::max(synth_internal::Uniform01(&rng_), 1e-300);
    const double u2 = synth_internal::Uniform01(&rng_);
    const double radius = std::sqrt(-2.0 * std::log(u1));
    spare_ = radius * std::sin(2.0 * kPi * u2);
    has_spare_ = true;
    return radius * std::cos(2.0 * kPi * u2);
  }

 private:
  std::mt19937_64 rng_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

uint8_t ToByte(double value) { return static_cast<uint8_t>(std::lround(std::clamp(value, 0.0, 255.0))); }

}  // namespace

bool SynthSceneKindFromName(const std::string& name, SynthSceneKind* kind) {
  if (name == "object_ring") {
    *kind = SynthSceneKind::kObjectRing;
  } else if (name == "room") {
    *kind = SynthSceneKind::kRoom;
  } else if (name == "forward_facing") {
    *kind = SynthSceneKind::kForwardFacing;
  } else {
    return false;
  }
  return true;
}

std::string SynthSceneKindName(SynthSceneKind kind) {
  return kind == SynthSceneKind::kObjectRing ? "object_ring" : kind == SynthSceneKind::kRoom ? "room" : "forward_facing";
}

bool SynthOptions::Check(std::string* error) const {
  return Require(views >= 2 && views <= 10000, "views", "in [2, 10000]", views, error) &&
         Require(width >= 16 && width <= 8192, "width", "in [16, 8192]", width, error) &&
         Require(height >= 16 && height <= 8192, "height", "in [16, 8192]", height, error) &&
         Require(noise >= 0 && noise <= 64, "noise", "in [0, 64]", noise, error) &&
         Require(seed >= 0, "seed", ">= 0", seed, error) &&
         Require(supersample >= 1 && supersample <= 8, "supersample", "in [1, 8]", supersample, error) &&
         Require(fov_deg == -1.0 || (fov_deg > 1 && fov_deg < 150), "fov_deg", "-1 or in (1, 150)", fov_deg,
                 error) &&
         Require(elevation_deg >= -80 && elevation_deg <= 80, "elevation_deg", "in [-80, 80]", elevation_deg,
                 error) &&
         Require(ring_radius >= 2.5 && ring_radius <= 100, "ring_radius", "in [2.5, 100]", ring_radius, error) &&
         Require(baseline > 0 && baseline <= 4, "baseline", "in (0, 4]", baseline, error) &&
         Require(subdivision >= 1 && subdivision <= 7, "subdivision", "in [1, 7]", subdivision, error) &&
         Require(sparse_points >= 0 && sparse_points <= 1000000, "sparse_points", "in [0, 1000000]",
                 sparse_points, error) &&
         Require(texture_frequency > 0 && texture_frequency <= 64, "texture_frequency", "in (0, 64]",
                 texture_frequency, error) &&
         Require(strength >= 0 && strength <= 1, "strength", "in [0, 1]", strength, error) &&
         Require(thin_parts >= 0 && thin_parts <= 200, "thin_parts", "in [0, 200]", thin_parts, error);
}

double StarShape::Radius(const Eigen::Vector3d& u) const {
  double radius = 1.0;
  for (const Lobe& lobe : lobes) {
    radius += lobe.amplitude * std::exp((u.dot(lobe.direction) - 1.0) / (lobe.width * lobe.width));
  }
  return radius;
}

bool StarShape::Inside(const Eigen::Vector3d& point) const {
  const Eigen::Vector3d q = (point - center) / scale;
  const double t = q.norm();
  return t == 0.0 || t < Radius(q / t);
}

Eigen::Vector3d SurfaceRadiance(const SynthScene& scene, int part, const Eigen::Vector3d& point,
                                const Eigen::Vector3d& normal) {
  const SynthPart& p = scene.parts[part];
  const Eigen::Vector3d variation =
      p.textured ? scene.degradation.Variation(SolidTexture(point, scene.texture_seed, scene.texture_frequency), point,
                                               scene.texture_frequency)
                 : Eigen::Vector3d::Constant(0.7);
  const Eigen::Vector3d albedo = p.tint.cwiseProduct(Eigen::Vector3d::Constant(0.3) + 0.7 * variation);
  const double shade = scene.ambient + (1.0 - scene.ambient) * std::max(0.0, normal.dot(scene.light_direction));
  return albedo * shade;
}

SynthScene BuildSynthScene(const SynthOptions& requested) {
  SynthScene scene;
  scene.degradation = Degradation{requested.degradation, requested.strength,
                                  Mix64(static_cast<uint64_t>(requested.seed) ^ 0xDE6EADull)};
  SynthOptions options = requested;
  options.views = scene.degradation.Views(requested.views);
  scene.kind = options.scene;
  if (options.scene == SynthSceneKind::kObjectRing) {
    synth_internal::BuildObjectRingGeometry(options, &scene);
    scene.background = Eigen::Vector3d(0.04, 0.04, 0.05);
  } else if (options.scene == SynthSceneKind::kRoom) {
    synth_internal::BuildRoomGeometry(options, &scene);
    scene.background = Eigen::Vector3d::Zero();  // never seen: the room is closed
  } else {
    synth_internal::BuildForwardFacingGeometry(options, &scene);
    scene.background = Eigen::Vector3d::Zero();  // never seen: the room is closed
    if (scene.degradation.Active(SynthDegradation::kHandHeld)) {
      // An outdoor capture's sky (hand_held): the back wall is gone and a pale blue lies beyond,
      // where stereo finds no point and no depth.
      int back = -1;
      for (size_t p = 0; p < scene.parts.size(); ++p) {
        if (scene.parts[p].name == "wall_back") back = static_cast<int>(p);
      }
      std::vector<Eigen::Vector3i> faces;
      std::vector<int> parts;
      for (size_t f = 0; f < scene.mesh.faces.size(); ++f) {
        if (scene.face_part[f] == back) continue;
        faces.push_back(scene.mesh.faces[f]);
        parts.push_back(scene.face_part[f]);
      }
      scene.mesh.faces = std::move(faces);
      scene.face_part = std::move(parts);
      scene.background = Eigen::Vector3d(0.55, 0.7, 0.9);
    }
  }
  scene.light_direction = Eigen::Vector3d(0.35, -0.55, 0.76).normalized();
  scene.texture_seed = Mix64(static_cast<uint64_t>(options.seed) ^ 0x7E47E4ull);
  scene.texture_frequency = options.texture_frequency;

  TriangleMesh& mesh = scene.mesh;
  mesh.ComputeVertexNormals();
  // Vertex colour: the radiance at the vertex with the normal of its part's shading.
  std::vector<int> vertex_part(mesh.vertices.size(), 0);
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    for (int k = 0; k < 3; ++k) vertex_part[mesh.faces[f][k]] = scene.face_part[f];
  }
  mesh.colors.resize(mesh.vertices.size());
  for (size_t v = 0; v < mesh.vertices.size(); ++v) {
    const Eigen::Vector3d radiance = SurfaceRadiance(scene, vertex_part[v], mesh.vertices[v].cast<double>(),
                                                     mesh.normals[v].cast<double>().normalized());
    mesh.colors[v] = Color3u8(ToByte(255.0 * radiance[0]), ToByte(255.0 * radiance[1]), ToByte(255.0 * radiance[2]));
  }
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const bool foreground = scene.parts[scene.face_part[f]].foreground;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d v = mesh.vertices[mesh.faces[f][k]].cast<double>();
      scene.scene_bounds.extend(v);
      if (foreground) scene.foreground_bounds.extend(v);
    }
  }
  mesh.comments = {"ibmr synth 1 scene " + SynthSceneKindName(options.scene) + " seed " +
                   std::to_string(options.seed)};
  return scene;
}

SynthView RenderSynthView(const SynthScene& scene, int view_index, const SynthOptions& options) {
  const Image& view = scene.views.at(view_index);
  const int s = options.supersample;
  const Camera& camera = scene.camera;
  // Pixel (c, r) covers [c, c+1) x [r, r+1), so the fine camera is the same one scaled by s.
  const Camera fine = Camera::Pinhole(camera.width * s, camera.height * s, camera.FocalX() * s,
                                      camera.FocalY() * s, camera.PrincipalX() * s, camera.PrincipalY() * s);
  const RasterResult raster = Rasterize(scene.mesh, fine, view.cam_from_world);
  const std::vector<Eigen::Vector3d> face_normals = FaceNormals(scene.mesh);
  const Eigen::Vector3d eye = view.Center();

  const int width = camera.width, height = camera.height;
  std::vector<Eigen::Vector3d> sum(static_cast<size_t>(width) * height, Eigen::Vector3d::Zero());
  std::vector<int> foreground_samples(sum.size(), 0);
  std::vector<Eigen::Vector3d> foreground_sum(sum.size(), Eigen::Vector3d::Zero());
  for (int y = 0; y < fine.height; ++y) {
    for (int x = 0; x < fine.width; ++x) {
      const size_t pixel = static_cast<size_t>(y / s) * width + x / s;
      const int face = raster.face_id[static_cast<size_t>(y) * fine.width + x];
      if (face < 0) {
        sum[pixel] += scene.background;
        continue;
      }
      const Eigen::Vector3i& f = scene.mesh.faces[face];
      Eigen::Vector3d point = Eigen::Vector3d::Zero(), normal = Eigen::Vector3d::Zero();
      for (int k = 0; k < 3; ++k) {
        const double b = raster.barycentric.At(x, y, k);
        point += b * scene.mesh.vertices[f[k]].cast<double>();
        normal += b * scene.mesh.normals[f[k]].cast<double>();
      }
      const int part = scene.face_part[face];
      if (!scene.parts[part].smooth || !(normal.norm() > 1e-12)) normal = face_normals[face];
      normal.normalize();
      Eigen::Vector3d radiance = SurfaceRadiance(scene, part, point, normal);
      const double highlight = scene.degradation.Highlight(normal, scene.light_direction, eye - point);
      if (highlight > 0) radiance += Eigen::Vector3d::Constant(highlight);
      sum[pixel] += radiance;
      if (scene.parts[part].foreground) {
        ++foreground_samples[pixel];
        foreground_sum[pixel] += radiance;
      }
    }
  }

  SynthView result;
  result.image.create(height, width, CV_8UC3);
  result.mask.create(height, width, CV_8UC1);
  result.rgba.create(height, width, CV_8UC4);
  GaussianSource gaussian(Mix64(static_cast<uint64_t>(options.seed) * 0x9E3779B1ull + view_index + 1));
  const double samples = static_cast<double>(s) * s;
  const double gain = scene.degradation.Gain(view_index);
  const double sigma = options.noise + scene.degradation.NoiseSigma();
  size_t foreground_pixels = 0;
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const size_t pixel = static_cast<size_t>(y) * width + x;
      const Eigen::Vector3d rgb = sum[pixel] * (255.0 * gain / samples);
      cv::Vec3b& bgr = result.image.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) {
        const double noise = sigma > 0 ? sigma * gaussian.Next() : 0.0;
        bgr[2 - c] = ToByte(rgb[c] + noise);
      }
      const int hits = foreground_samples[pixel];
      cv::Vec4b& bgra = result.rgba.at<cv::Vec4b>(y, x);
      bgra[3] = ToByte(255.0 * hits / samples);
      const Eigen::Vector3d straight = hits > 0 ? Eigen::Vector3d(foreground_sum[pixel] * (255.0 * gain / hits))
                                                : Eigen::Vector3d::Zero();
      for (int c = 0; c < 3; ++c) bgra[2 - c] = ToByte(straight[c]);
      const bool foreground = 2 * foreground_samples[pixel] >= s * s;
      result.mask.at<uint8_t>(y, x) = foreground ? 255 : 0;
      foreground_pixels += foreground;
    }
  }
  result.foreground_fraction = static_cast<double>(foreground_pixels) / (static_cast<double>(width) * height);
  result.depth = Rasterize(scene.mesh, camera, view.cam_from_world).depth;
  return result;
}

nlohmann::json SynthSceneJson(const SynthScene& scene, const SynthOptions& options) {
  using nlohmann::json;
  auto vec = [](const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); };
  auto box = [&](const Eigen::AlignedBox3d& b) { return json{{"min", vec(b.min())}, {"max", vec(b.max())}}; };
  json j;
  j["generator"] = "ibmr synth";
  j["version"] = 1;
  j["scene"] = SynthSceneKindName(scene.kind);
  j["options"] = {{"scene", SynthSceneKindName(options.scene)}, {"views", options.views},
                  {"width", options.width}, {"height", options.height}, {"noise", options.noise},
                  {"seed", options.seed}, {"supersample", options.supersample}, {"fov_deg", options.fov_deg},
                  {"elevation_deg", options.elevation_deg}, {"ring_radius", options.ring_radius},
                  {"baseline", options.baseline}, {"textureless_wall", options.textureless_wall},
                  {"subdivision", options.subdivision}, {"sparse_points", options.sparse_points},
                  {"texture_frequency", options.texture_frequency},
                  {"degradation", SynthDegradationName(options.degradation)}, {"strength", options.strength},
                  {"thin_parts", options.thin_parts}};
  j["world_up"] = vec(Eigen::Vector3d::UnitZ());
  j["camera"] = {{"model", "PINHOLE"}, {"width", scene.camera.width}, {"height", scene.camera.height},
                 {"params", scene.camera.params}};
  j["object_bounds"] = box(scene.foreground_bounds);
  j["scene_bounds"] = box(scene.scene_bounds);
  if (scene.kind == SynthSceneKind::kObjectRing) {
    j["ring"] = {{"center", vec(Eigen::Vector3d::Zero())}, {"radius", options.ring_radius},
                 {"elevation_deg", options.elevation_deg}};
  } else {
    j["camera_line"] = {{"start", vec(scene.views.front().Center())}, {"end", vec(scene.views.back().Center())},
                        {"baseline", options.baseline}};
  }
  json views = json::array();
  for (const Image& v : scene.views) views.push_back({{"name", v.name}, {"center", vec(v.Center())}});
  j["views"] = views;
  json parts = json::array();
  for (const SynthPart& p : scene.parts) {
    parts.push_back({{"name", p.name}, {"foreground", p.foreground}, {"textured", p.textured}, {"tint", vec(p.tint)}});
  }
  j["parts"] = parts;
  json shapes = json::array();
  for (const StarShape& shape : scene.shapes) {
    json lobes = json::array();
    for (const StarShape::Lobe& lobe : shape.lobes) {
      lobes.push_back({{"direction", vec(lobe.direction)}, {"amplitude", lobe.amplitude}, {"width", lobe.width}});
    }
    shapes.push_back({{"center", vec(shape.center)}, {"scale", shape.scale}, {"lobes", lobes}});
  }
  j["star_shapes"] = shapes;
  j["star_shape_formula"] =
      "inside(p) <=> |q| < 1 + sum_k amplitude_k * exp((u . direction_k - 1) / width_k^2), "
      "q = (p - center) / scale, u = q / |q|; the mesh's vertices lie on this surface";
  j["light"] = {{"direction", vec(scene.light_direction)}, {"ambient", scene.ambient},
                {"model", "radiance = albedo * (ambient + (1 - ambient) * max(0, n . direction))"}};
  j["background_rgb"] = vec(scene.background * 255.0);
  j["mesh"] = {{"path", "ground_truth/mesh.ply"},
               {"vertices", scene.mesh.vertices.size()},
               {"faces", scene.mesh.faces.size()},
               {"closed_parts", "each foreground part is a closed, consistently oriented surface"}};
  j["conventions"] = {
      {"frame", "world +z up; cameras x right, y down, z forward (COLMAP); images.txt holds cam_from_world"},
      {"pixel_centre", "pixel (c, r) is centred at (c + 0.5, r + 0.5)"},
      {"depth", "ground_truth/depth/<image>.bin: COLMAP array, z along the optical axis at pixel centres, "
                "0 = no surface"},
      {"mask", "ground_truth/masks/<image>.png: 255 where at least half of the pixel's supersamples hit a foreground part "
               "(object_ring: the object; room: pillar, objects and box, not walls, floor or ceiling)"},
      {"radiance", "view-independent (Lambertian): every view sees the same colour of a surface point"}};
  return j;
}

}  // namespace ibmr
