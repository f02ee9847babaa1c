// Geometry and cameras of the synthetic scenes: star-shaped solids on subdivided icosahedra,
// welded grid boxes, the object ring and the box room (see synth_scenes.h). Test-data generation;
// follows no seed-paper section.
#include "stages/synth/synth_scenes.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <unordered_map>
#include <utility>

#include "pipeline/core/rigid3.h"

namespace ibmr {
namespace synth_internal {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Unit vector with a rotation-invariant distribution (normalised Gaussian by Box-Muller).
Eigen::Vector3d RandomUnitVector(std::mt19937_64* rng) {
  Eigen::Vector3d v;
  do {
    for (int i = 0; i < 3; ++i) {
      const double u1 = std::max(Uniform01(rng), 1e-300);
      const double u2 = Uniform01(rng);
      v[i] = std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
    }
  } while (v.norm() < 1e-9);
  return v.normalized();
}

double UniformIn(double low, double high, std::mt19937_64* rng) { return low + (high - low) * Uniform01(rng); }

// Makes face `face` counter-clockwise seen from the side `outward` points to.
Eigen::Vector3i Oriented(const Eigen::Vector3i& face, const std::vector<Eigen::Vector3d>& positions,
                         const Eigen::Vector3d& outward) {
  const Eigen::Vector3d normal =
      (positions[face[1]] - positions[face[0]]).cross(positions[face[2]] - positions[face[0]]);
  return normal.dot(outward) >= 0 ? face : Eigen::Vector3i(face[0], face[2], face[1]);
}

// Unit icosphere: vertices on the unit sphere, faces counter-clockwise seen from outside.
void UnitIcosphere(int subdivision, std::vector<Eigen::Vector3d>* vertices, std::vector<Eigen::Vector3i>* faces) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  *vertices = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
               {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (Eigen::Vector3d& v : *vertices) v.normalize();
  const std::vector<Eigen::Vector3i> base = {
      {0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
      {11, 10, 2}, {10, 7, 6}, {7, 1, 8},  {3, 9, 4},  {3, 4, 2},   {3, 2, 6}, {3, 6, 8},
      {3, 8, 9},  {4, 9, 5},  {2, 4, 11}, {6, 2, 10}, {8, 6, 7},   {9, 8, 1}};
  faces->clear();
  for (const Eigen::Vector3i& f : base) {
    const Eigen::Vector3d centroid = ((*vertices)[f[0]] + (*vertices)[f[1]] + (*vertices)[f[2]]) / 3.0;
    faces->push_back(Oriented(f, *vertices, centroid));
  }
  for (int level = 0; level < subdivision; ++level) {
    std::unordered_map<uint64_t, int> midpoints;
    auto midpoint = [&](int a, int b) {
      const uint64_t key = (static_cast<uint64_t>(std::min(a, b)) << 32) | static_cast<uint32_t>(std::max(a, b));
      const auto found = midpoints.find(key);
      if (found != midpoints.end()) return found->second;
      vertices->push_back(((*vertices)[a] + (*vertices)[b]).normalized());
      const int index = static_cast<int>(vertices->size()) - 1;
      midpoints.emplace(key, index);
      return index;
    };
    std::vector<Eigen::Vector3i> finer;
    finer.reserve(faces->size() * 4);
    for (const Eigen::Vector3i& f : *faces) {
      const int ab = midpoint(f[0], f[1]), bc = midpoint(f[1], f[2]), ca = midpoint(f[2], f[0]);
      finer.emplace_back(f[0], ab, ca);
      finer.emplace_back(f[1], bc, ab);
      finer.emplace_back(f[2], ca, bc);
      finer.emplace_back(ab, bc, ca);
    }
    faces->swap(finer);
  }
}

// Appends vertices and faces (already oriented) of one part to the scene's mesh.
void AppendPart(const std::vector<Eigen::Vector3d>& positions, const std::vector<Eigen::Vector3i>& faces,
                const std::vector<int>& parts, SynthScene* scene) {
  const int offset = static_cast<int>(scene->mesh.vertices.size());
  for (const Eigen::Vector3d& p : positions) scene->mesh.vertices.push_back(p.cast<float>());
  for (size_t i = 0; i < faces.size(); ++i) {
    scene->mesh.faces.push_back(faces[i] + Eigen::Vector3i::Constant(offset));
    scene->face_part.push_back(parts[i]);
  }
}

int AddPart(const std::string& name, bool foreground, bool smooth, const Eigen::Vector3d& tint, SynthScene* scene) {
  SynthPart part;
  part.name = name;
  part.foreground = foreground;
  part.smooth = smooth;
  part.tint = tint;
  scene->parts.push_back(part);
  return static_cast<int>(scene->parts.size()) - 1;
}

Camera PinholeFromFov(int width, int height, double fov_deg) {
  const double focal = 0.5 * width / std::tan(0.5 * fov_deg * kPi / 180.0);
  return Camera::Pinhole(width, height, focal, focal, 0.5 * width, 0.5 * height);
}

void AddView(int index, int num_views, const Rigid3d& cam_from_world, SynthScene* scene) {
  Image image;
  image.image_id = index + 1;
  image.camera_id = scene->camera.camera_id;
  image.name = ViewName(index, num_views);
  image.cam_from_world = cam_from_world;
  scene->views.push_back(image);
}

}  // namespace

double Uniform01(std::mt19937_64* rng) { return static_cast<double>((*rng)() >> 11) * 0x1.0p-53; }

uint64_t Mix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

std::string ViewName(int index, int num_views) {
  int digits = 3;
  for (int n = num_views - 1; n >= 1000; n /= 10) ++digits;
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "view_%0*d.png", digits, index);
  return buffer;
}

StarShape RandomStarShape(const Eigen::Vector3d& center, double scale, std::mt19937_64* rng) {
  StarShape shape;
  shape.center = center;
  shape.scale = scale;
  // Cube vertices under a random rotation: eight well separated lobe directions, bumps and dents
  // alternating so that no two dents are neighbours along a cube edge.
  const Eigen::Vector3d axis = RandomUnitVector(rng);
  const Eigen::Matrix3d rotation = Eigen::AngleAxisd(UniformIn(0, 2 * kPi, rng), axis).toRotationMatrix();
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d cube((corner & 1) ? 1 : -1, (corner & 2) ? 1 : -1, (corner & 4) ? 1 : -1);
    const int parity = ((corner & 1) + ((corner >> 1) & 1) + ((corner >> 2) & 1)) % 2;
    StarShape::Lobe lobe;
    lobe.direction = (rotation * cube).normalized();
    if (parity == 0) {
      lobe.amplitude = UniformIn(0.3, 0.5, rng);
      lobe.width = UniformIn(0.3, 0.45, rng);
    } else {
      lobe.amplitude = -UniformIn(0.35, 0.45, rng);
      lobe.width = UniformIn(0.3, 0.4, rng);
    }
    shape.lobes.push_back(lobe);
  }
  return shape;
}

void AppendStarShape(const StarShape& shape, int subdivision, int part, SynthScene* scene) {
  std::vector<Eigen::Vector3d> directions;
  std::vector<Eigen::Vector3i> faces;
  UnitIcosphere(subdivision, &directions, &faces);
  std::vector<Eigen::Vector3d> positions;
  positions.reserve(directions.size());
  for (const Eigen::Vector3d& u : directions) {
    positions.push_back(shape.center + shape.scale * shape.Radius(u) * u);
  }
  // A radial map keeps each face's orientation seen from the centre (det(r0 u0, r1 u1, r2 u2) > 0),
  // so the faces stay counter-clockwise seen from outside and the surface does not intersect itself.
  AppendPart(positions, faces, std::vector<int>(faces.size(), part), scene);
  scene->shapes.push_back(shape);
}

void AppendBox(const Eigen::Vector3d& min, const Eigen::Vector3d& max, double cell, bool inward,
               const std::array<int, 6>& side_parts, SynthScene* scene) {
  const Eigen::Vector3d extent = max - min;
  Eigen::Vector3i cells;
  for (int a = 0; a < 3; ++a) cells[a] = std::max(1, static_cast<int>(std::ceil(extent[a] / cell - 1e-9)));
  // Vertices on the box lattice, welded through their lattice coordinates.
  std::map<std::array<int, 3>, int> index_of;
  std::vector<Eigen::Vector3d> positions;
  auto vertex = [&](const std::array<int, 3>& ijk) {
    const auto found = index_of.find(ijk);
    if (found != index_of.end()) return found->second;
    Eigen::Vector3d p;
    for (int a = 0; a < 3; ++a) p[a] = ijk[a] == cells[a] ? max[a] : min[a] + extent[a] * ijk[a] / cells[a];
    positions.push_back(p);
    index_of.emplace(ijk, static_cast<int>(positions.size()) - 1);
    return static_cast<int>(positions.size()) - 1;
  };
  std::vector<Eigen::Vector3i> faces;
  std::vector<int> parts;
  for (int side = 0; side < 6; ++side) {
    const int axis = side / 2, high = side % 2;
    const int u_axis = (axis + 1) % 3, v_axis = (axis + 2) % 3;
    Eigen::Vector3d outward = Eigen::Vector3d::Zero();
    outward[axis] = (high ? 1.0 : -1.0) * (inward ? -1.0 : 1.0);
    for (int i = 0; i < cells[u_axis]; ++i) {
      for (int j = 0; j < cells[v_axis]; ++j) {
        std::array<int, 4> quad;
        const int corners[4][2] = {{i, j}, {i + 1, j}, {i + 1, j + 1}, {i, j + 1}};
        for (int c = 0; c < 4; ++c) {
          std::array<int, 3> ijk;
          ijk[axis] = high ? cells[axis] : 0;
          ijk[u_axis] = corners[c][0];
          ijk[v_axis] = corners[c][1];
          quad[c] = vertex(ijk);
        }
        faces.push_back(Oriented({quad[0], quad[1], quad[2]}, positions, outward));
        faces.push_back(Oriented({quad[0], quad[2], quad[3]}, positions, outward));
        parts.push_back(side_parts[side]);
        parts.push_back(side_parts[side]);
      }
    }
  }
  AppendPart(positions, faces, parts, scene);
}

// A thin straight blade from `base` to `tip`: a closed box `width` wide at the base tapering to a
// quarter of it at the tip, `thickness` thick, its flat side facing along `facing` (made
// perpendicular to the blade).
void AppendBlade(const Eigen::Vector3d& base, const Eigen::Vector3d& tip, const Eigen::Vector3d& facing, double width,
                 double thickness, int part, SynthScene* scene) {
  const Eigen::Vector3d along = (tip - base).normalized();
  Eigen::Vector3d normal = facing - facing.dot(along) * along;
  if (normal.norm() < 1e-6 * facing.norm()) normal = along.unitOrthogonal();  // facing along the blade
  normal.normalize();
  const Eigen::Vector3d side = along.cross(normal);
  std::vector<Eigen::Vector3d> positions;
  for (int end = 0; end < 2; ++end) {
    const Eigen::Vector3d centre = end == 0 ? base : tip;
    const double half_width = 0.5 * width * (end == 0 ? 1.0 : 0.25);
    for (const double s : {-1.0, 1.0}) {
      for (const double t : {-1.0, 1.0}) positions.push_back(centre + s * half_width * side + t * 0.5 * thickness * normal);
    }
  }
  const Eigen::Vector3d middle = 0.5 * (base + tip);
  const int quads[6][4] = {{0, 1, 3, 2}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 3, 7, 5}};
  std::vector<Eigen::Vector3i> faces;
  for (const auto& q : quads) {
    const Eigen::Vector3d outward = 0.25 * (positions[q[0]] + positions[q[1]] + positions[q[2]] + positions[q[3]]) - middle;
    faces.push_back(Oriented({q[0], q[1], q[2]}, positions, outward));
    faces.push_back(Oriented({q[0], q[2], q[3]}, positions, outward));
  }
  AppendPart(positions, faces, std::vector<int>(faces.size(), part), scene);
}

void BuildObjectRingGeometry(const SynthOptions& options, SynthScene* scene) {
  std::mt19937_64 rng(Mix64(static_cast<uint64_t>(options.seed) ^ 0x0B1EC7A11ull));
  const int object = AddPart("object", /*foreground=*/true, /*smooth=*/true, Eigen::Vector3d::Ones(), scene);
  const StarShape shape = RandomStarShape(Eigen::Vector3d::Zero(), 1.0, &rng);
  AppendStarShape(shape, options.subdivision, object, scene);
  if (options.thin_parts > 0) {
    // Fine structure: blades rooted a little inside the surface, standing out of it along a direction
    // within 35 degrees of the normal-ish radial one, with their own rng (the object unchanged).
    std::mt19937_64 blade_rng(Mix64(static_cast<uint64_t>(options.seed) ^ 0x7B1ADEull));
    const int blades = AddPart("thin_parts", /*foreground=*/true, /*smooth=*/false, {1.0, 0.85, 0.45}, scene);
    for (int i = 0; i < options.thin_parts; ++i) {
      Eigen::Vector3d u(UniformIn(-1, 1, &blade_rng), UniformIn(-1, 1, &blade_rng), UniformIn(-1, 1, &blade_rng));
      if (u.norm() < 1e-3) u = Eigen::Vector3d::UnitZ();
      u.normalize();
      const Eigen::Vector3d base = shape.center + 0.92 * shape.scale * shape.Radius(u) * u;
      Eigen::Vector3d lean(UniformIn(-1, 1, &blade_rng), UniformIn(-1, 1, &blade_rng), UniformIn(-1, 1, &blade_rng));
      const Eigen::Vector3d direction = (u + 0.6 * (lean - lean.dot(u) * u)).normalized();
      const double length = UniformIn(0.25, 0.6, &blade_rng);
      const Eigen::Vector3d facing(UniformIn(-1, 1, &blade_rng), UniformIn(-1, 1, &blade_rng), UniformIn(-1, 1, &blade_rng));
      AppendBlade(base, base + (length + 0.08 * shape.scale * shape.Radius(u)) * direction,
                  facing.norm() > 1e-3 ? facing : Eigen::Vector3d::UnitX(), 0.03, 0.006, blades, scene);
    }
  }

  double bounding_radius = 0;
  for (const Eigen::Vector3f& v : scene->mesh.vertices) bounding_radius = std::max(bounding_radius, double(v.norm()));
  if (options.fov_deg > 0) {
    scene->camera = PinholeFromFov(options.width, options.height, options.fov_deg);
  } else {
    // The bounding sphere, centred on every optical axis, projects to a circle of radius f*tan(a).
    const double half_angle = std::asin(std::min(0.99, bounding_radius / options.ring_radius));
    const double focal = 0.8 * 0.5 * std::min(options.width, options.height) / std::tan(half_angle);
    scene->camera = Camera::Pinhole(options.width, options.height, focal, focal, 0.5 * options.width,
                                    0.5 * options.height);
  }
  const double elevation = options.elevation_deg * kPi / 180.0;
  for (int i = 0; i < options.views; ++i) {
    const double azimuth = 2.0 * kPi * i / options.views;
    const Eigen::Vector3d eye = options.ring_radius * Eigen::Vector3d(std::cos(elevation) * std::cos(azimuth),
                                                                      std::cos(elevation) * std::sin(azimuth),
                                                                      std::sin(elevation));
    AddView(i, options.views, LookAt(eye, Eigen::Vector3d::Zero(), Eigen::Vector3d::UnitZ()), scene);
  }
}

namespace {

// The room's walls, floor, ceiling, pillar, objects and box (shared by the room and the forward-
// facing scene).
void AppendRoomContents(const SynthOptions& options, std::mt19937_64* rng, SynthScene* scene) {
  const int floor = AddPart("floor", false, false, {0.95, 0.8, 0.6}, scene);
  const int ceiling = AddPart("ceiling", false, false, {0.9, 0.9, 0.95}, scene);
  const int wall_left = AddPart("wall_left", false, false, {0.85, 0.9, 1.0}, scene);
  const int wall_right = AddPart("wall_right", false, false, {1.0, 0.9, 0.8}, scene);
  const int wall_back = AddPart("wall_back", false, false, {0.8, 0.95, 0.85}, scene);
  const int wall_front = AddPart("wall_front", false, false, {0.9, 0.85, 0.9}, scene);
  scene->parts[wall_left].textured = !options.textureless_wall;
  // The room, seen from inside: x in [-3, 3], y in [-1.5, 9] (cameras near y = 0 look along +y),
  // z in [0, 3]. Sides in the order -x, +x, -y, +y, -z, +z.
  AppendBox({-3, -1.5, 0}, {3, 9, 3}, 0.5, /*inward=*/true,
            {wall_left, wall_right, wall_front, wall_back, floor, ceiling}, scene);

  const int pillar = AddPart("pillar", true, false, {1.0, 0.7, 0.55}, scene);
  AppendBox({-1.25, 2.0, 0}, {-0.95, 2.3, 2.4}, 0.15, false, {pillar, pillar, pillar, pillar, pillar, pillar}, scene);
  const int near_object = AddPart("object_near", true, true, Eigen::Vector3d::Ones(), scene);
  AppendStarShape(RandomStarShape({0.45, 3.3, 0.8}, 0.45, rng), options.subdivision, near_object, scene);
  const int box = AddPart("box", true, false, {0.65, 1.0, 0.7}, scene);
  AppendBox({0.6, 5.5, 0}, {1.8, 6.5, 1.3}, 0.25, false, {box, box, box, box, box, box}, scene);
  const int far_object = AddPart("object_far", true, true, {1.0, 0.9, 1.0}, scene);
  AppendStarShape(RandomStarShape({-1.2, 6.2, 1.3}, 0.6, rng), options.subdivision, far_object, scene);
}

}  // namespace

void BuildRoomGeometry(const SynthOptions& options, SynthScene* scene) {
  std::mt19937_64 rng(Mix64(static_cast<uint64_t>(options.seed) ^ 0x500Dull));
  AppendRoomContents(options, &rng, scene);
  scene->camera = PinholeFromFov(options.width, options.height, options.fov_deg > 0 ? options.fov_deg : 60.0);
  const Eigen::Vector3d target(0, 5, 1.0);
  for (int i = 0; i < options.views; ++i) {
    const double x = options.baseline * (static_cast<double>(i) / (options.views - 1) - 0.5);
    AddView(i, options.views, LookAt({x, 0, 1.4}, target, Eigen::Vector3d::UnitZ()), scene);
  }
}

void BuildForwardFacingGeometry(const SynthOptions& options, SynthScene* scene) {
  std::mt19937_64 rng(Mix64(static_cast<uint64_t>(options.seed) ^ 0x500Dull));
  AppendRoomContents(options, &rng, scene);
  if (scene->degradation.Active(SynthDegradation::kHandHeld)) {
    // Fine structure (hand_held): a plant of 14 blades fanning up from the floor in front of the
    // near object, 2 cm wide at the base (6-7 px at 1008 wide and 2.6 m away), 5 mm at the tip.
    std::mt19937_64 plant_rng(Mix64(static_cast<uint64_t>(options.seed) ^ 0xF80Dull));
    const int plant = AddPart("fronds", true, false, {0.6, 1.0, 0.5}, scene);
    const Eigen::Vector3d root(0.1, 2.6, 0.0);
    for (int i = 0; i < 14; ++i) {
      const double lean = (static_cast<double>(i) / 13.0 - 0.5) * 100.0 * kPi / 180.0 + UniformIn(-0.08, 0.08, &plant_rng);
      const double depth_lean = UniformIn(-0.35, 0.35, &plant_rng);
      const double length = UniformIn(0.9, 1.4, &plant_rng);
      const Eigen::Vector3d direction = Eigen::Vector3d(std::sin(lean), depth_lean, std::cos(lean)).normalized();
      const Eigen::Vector3d facing(UniformIn(-1, 1, &plant_rng), -1.0, UniformIn(-0.5, 0.5, &plant_rng));
      AppendBlade(root + Eigen::Vector3d(UniformIn(-0.05, 0.05, &plant_rng), UniformIn(-0.05, 0.05, &plant_rng), 0.0),
                  root + length * direction, facing, 0.02, 0.004, plant, scene);
    }
  }
  // Thin occluders near the cameras: two poles and a rail, 3-6 cm thick, in front of everything.
  const int poles = AddPart("thin_occluders", true, false, {0.95, 0.95, 0.6}, scene);
  const std::array<int, 6> all = {poles, poles, poles, poles, poles, poles};
  AppendBox({-0.32, 1.3, 0}, {-0.28, 1.34, 3}, 0.1, false, all, scene);
  AppendBox({0.52, 1.7, 0}, {0.58, 1.76, 3}, 0.1, false, all, scene);
  AppendBox({-3, 2.6, 1.95}, {3, 2.65, 2.0}, 0.1, false, all, scene);
  scene->camera = PinholeFromFov(options.width, options.height, options.fov_deg > 0 ? options.fov_deg : 60.0);
  // A grid of columns x rows cameras (4:3, row by row from the top left), baseline wide and 3/4 of
  // it high, all looking the same way (parallel axes, slightly down), like a hand-held LLFF capture.
  const int columns = std::max(1, static_cast<int>(std::ceil(std::sqrt(options.views * 4.0 / 3.0))));
  const int rows = (options.views + columns - 1) / columns;
  const Eigen::Vector3d centre(0, 0, 1.4), forward = Eigen::Vector3d(0, 5, 1.0 - 1.4).normalized();
  for (int i = 0; i < options.views; ++i) {
    const int c = i % columns, r = i / columns;
    const double x = columns > 1 ? options.baseline * (static_cast<double>(c) / (columns - 1) - 0.5) : 0.0;
    const double z = rows > 1 ? 0.75 * options.baseline * (0.5 - static_cast<double>(r) / (rows - 1)) : 0.0;
    const Eigen::Vector3d eye = centre + Eigen::Vector3d(x, 0, z);
    const Rigid3d parallel = LookAt(eye, eye + forward, Eigen::Vector3d::UnitZ());
    const Eigen::Matrix3d rotation = scene->degradation.AxisTurn(i) * parallel.R();  // hand_held: axes not parallel
    AddView(i, options.views, Rigid3d(rotation, -rotation * eye), scene);
  }
}

}  // namespace synth_internal
}  // namespace ibmr
