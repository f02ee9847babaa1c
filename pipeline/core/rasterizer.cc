// Z-buffer triangle rasterizer in the COLMAP pixel convention (pixel (c, r) is sampled at
// (c + 0.5, r + 0.5)).
//
// Per face: transform to the camera frame, clip against the plane z = near_z (giving up to two
// triangles whose vertices carry their weights over the original face's vertices), project,
// then walk the clamped bounding box and test each pixel centre against the three edge
// functions. Watertightness: an edge function is always evaluated from the edge's endpoints in a
// canonical order, so the two faces sharing an edge see bit-identical values of opposite sign,
// and a centre exactly on the edge goes to one side only (a top-left style tie rule on the edge
// direction). Depth and barycentrics are perspective-correct: screen-space weights divided by
// z, renormalised; 1 / sum(weight / z) is exactly the ray-plane intersection depth. Large meshes
// are drawn in strips of rows on several threads, each strip taking every face that reaches it in
// the mesh's order, so that the z-test's ties go the same way as in one pass; the image can be
// drawn a window of rows at a time (RasterizeWindows), each window's strips in turn.
#include "pipeline/core/rasterizer.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

// A vertex of a (possibly clipped) triangle in the camera frame, with its weights over the
// three vertices of the original face.
struct ClipVertex {
  Eigen::Vector3d point;
  Eigen::Vector3d weights;
};

// A strict order on coordinates: shared vertices are bit-identical in every face that uses them,
// so ordering an edge's endpoints by it gives every face the same computation.
bool Before(double ax, double ay, double az, double bx, double by, double bz) {
  if (ax != bx) return ax < bx;
  if (ay != by) return ay < by;
  return az < bz;
}

struct Intrinsics {
  double fx, fy, cx, cy;
  int width, height;
};

// The point where edge (a, b) crosses z = near, computed from the endpoints in canonical order
// so that both faces sharing the edge get exactly the same point.
ClipVertex Intersect(const ClipVertex& a_in, const ClipVertex& b_in, double near_z) {
  const Eigen::Vector3d& pa = a_in.point;
  const Eigen::Vector3d& pb = b_in.point;
  const bool swap = Before(pb.x(), pb.y(), pb.z(), pa.x(), pa.y(), pa.z());
  const ClipVertex& a = swap ? b_in : a_in;
  const ClipVertex& b = swap ? a_in : b_in;
  const double t = (near_z - a.point.z()) / (b.point.z() - a.point.z());
  ClipVertex out;
  out.point = a.point + t * (b.point - a.point);
  out.point.z() = near_z;
  out.weights = a.weights + t * (b.weights - a.weights);
  return out;
}

// Sutherland-Hodgman against z >= near_z. Returns the number of polygon vertices (0, 3 or 4),
// in the input's winding order.
int ClipNear(const ClipVertex in[3], double near_z, ClipVertex out[4]) {
  int n = 0;
  for (int i = 0; i < 3; ++i) {
    const ClipVertex& current = in[i];
    const ClipVertex& next = in[(i + 1) % 3];
    const bool current_in = current.point.z() >= near_z;
    const bool next_in = next.point.z() >= near_z;
    if (current_in) out[n++] = current;
    if (current_in != next_in) out[n++] = Intersect(current, next, near_z);
  }
  return n;
}

struct ScreenVertex {
  double x, y;         // pixel coordinates
  double inv_z;        // 1 / camera-frame depth
};

// One edge's function, evaluated in canonical endpoint order and signed so that the triangle's
// interior is positive.
struct Edge {
  double ax, ay, dx, dy;
  double sign;
  bool owns_ties;  // whether a centre exactly on the edge belongs to this triangle

  double Evaluate(double px, double py) const { return sign * (dx * (py - ay) - dy * (px - ax)); }
  bool Inside(double e) const { return e > 0.0 || (e == 0.0 && owns_ties); }
};

// Edge from `from` to `to` of a triangle whose interior lies on the positive side when
// `orientation` multiplies the edge function taken in that direction.
Edge MakeEdge(const ScreenVertex& from, const ScreenVertex& to, double orientation) {
  const bool canonical = Before(from.x, from.y, from.inv_z, to.x, to.y, to.inv_z);
  const ScreenVertex& a = canonical ? from : to;
  const ScreenVertex& b = canonical ? to : from;
  Edge edge;
  edge.ax = a.x;
  edge.ay = a.y;
  edge.dx = b.x - a.x;
  edge.dy = b.y - a.y;
  edge.sign = canonical ? orientation : -orientation;
  // Direction of the edge with the interior on its positive side; the two faces sharing the
  // edge traverse it in opposite directions, so exactly one of them owns ties.
  const double ux = edge.sign * edge.dx, uy = edge.sign * edge.dy;
  edge.owns_ties = uy > 0.0 || (uy == 0.0 && ux < 0.0);
  return edge;
}

ScreenVertex Project(const ClipVertex& v, const Intrinsics& k) {
  const double inv_z = 1.0 / v.point.z();
  return {k.fx * v.point.x() * inv_z + k.cx, k.fy * v.point.y() * inv_z + k.cy, inv_z};
}

// Rasterizes the rows [row_lo, row_hi) of a projected triangle of face `face_id` into `result`,
// which holds the image's rows from `first_row` on. `tri`: null for the face's own corners, else
// the clipped triangle whose weights map vertex i to the original face's vertices.
void DrawScreenTriangle(const ScreenVertex v[3], const ClipVertex* tri, int face_id, const Intrinsics& k, int row_lo,
                        int row_hi, int first_row, RasterResult* result) {
  const double area = (v[1].x - v[0].x) * (v[2].y - v[0].y) - (v[1].y - v[0].y) * (v[2].x - v[0].x);
  if (!(std::abs(area) > 0.0)) return;  // degenerate (or NaN)
  const double orientation = area > 0.0 ? 1.0 : -1.0;
  // Edge i is opposite vertex i, so its function is proportional to vertex i's weight.
  const Edge edges[3] = {MakeEdge(v[1], v[2], orientation), MakeEdge(v[2], v[0], orientation),
                         MakeEdge(v[0], v[1], orientation)};

  const double min_x = std::min({v[0].x, v[1].x, v[2].x}), max_x = std::max({v[0].x, v[1].x, v[2].x});
  const double min_y = std::min({v[0].y, v[1].y, v[2].y}), max_y = std::max({v[0].y, v[1].y, v[2].y});
  // Pixel c is sampled at c + 0.5: the covered columns are ceil(min - 0.5) .. floor(max - 0.5).
  // Clamped to the image in double before any cast: near the camera plane a vertex can project
  // beyond 2^31 pixels, where the cast to int is undefined (in practice INT_MIN, which made the
  // loop below run ~2^31 columns per row). The negated comparisons also reject NaN bounds.
  const double x0 = std::max(0.0, std::ceil(min_x - 0.5)), x1 = std::min(k.width - 1.0, std::floor(max_x - 0.5));
  const double y0 = std::max<double>(row_lo, std::ceil(min_y - 0.5)), y1 = std::min<double>(row_hi - 1.0, std::floor(max_y - 0.5));
  if (!(x0 <= x1) || !(y0 <= y1)) return;  // off-screen
  const int c0 = static_cast<int>(x0), c1 = static_cast<int>(x1);
  const int r0 = static_cast<int>(y0), r1 = static_cast<int>(y1);

  const bool identity = tri == nullptr || (tri[0].weights == Eigen::Vector3d::UnitX() &&
                                            tri[1].weights == Eigen::Vector3d::UnitY() &&
                                            tri[2].weights == Eigen::Vector3d::UnitZ());
  const size_t plane = static_cast<size_t>(k.width) * result->depth.height;
  float* depth = result->depth.data.data();
  int* ids = result->face_id.data();
  float* bary = result->barycentric.data.data();
  for (int r = r0; r <= r1; ++r) {
    const double py = r + 0.5;
    // Along a row each edge function is monotone in the column (every rounding step of Evaluate
    // is), so the covered centres of a row are one run: the first miss after a hit ends the row.
    bool entered = false;
    for (int c = c0; c <= c1; ++c) {
      const double px = c + 0.5;
      const double e0 = edges[0].Evaluate(px, py), e1 = edges[1].Evaluate(px, py), e2 = edges[2].Evaluate(px, py);
      if (!edges[0].Inside(e0) || !edges[1].Inside(e1) || !edges[2].Inside(e2)) {
        if (entered) break;
        continue;
      }
      entered = true;
      // Screen weights e_i / sum, then divided by z_i for perspective correctness.
      const double w0 = e0 * v[0].inv_z, w1 = e1 * v[1].inv_z, w2 = e2 * v[2].inv_z;
      const double sum_w = w0 + w1 + w2;
      const double sum_e = e0 + e1 + e2;
      if (!(sum_w > 0.0)) continue;
      const double z = sum_e / sum_w;
      const size_t index = static_cast<size_t>(r - first_row) * k.width + c;
      if (ids[index] >= 0 && !(z < depth[index])) continue;
      Eigen::Vector3d b(w0 / sum_w, w1 / sum_w, w2 / sum_w);
      if (!identity) b = b[0] * tri[0].weights + b[1] * tri[1].weights + b[2] * tri[2].weights;
      depth[index] = static_cast<float>(z);
      ids[index] = face_id;
      for (int i = 0; i < 3; ++i) bary[i * plane + index] = static_cast<float>(b[i]);
    }
  }
}

void RasterizeTriangle(const ClipVertex tri[3], int face_id, const Intrinsics& k, int row_lo, int row_hi, int first_row,
                       RasterResult* result) {
  const ScreenVertex v[3] = {Project(tri[0], k), Project(tri[1], k), Project(tri[2], k)};
  DrawScreenTriangle(v, tri, face_id, k, row_lo, row_hi, first_row, result);
}

Intrinsics IntrinsicsOf(const Camera& camera) {
  if (camera.width <= 0 || camera.height <= 0) {
    throw InputError("Rasterize: camera " + std::to_string(camera.camera_id) + " has no image size (" +
                     std::to_string(camera.width) + "x" + std::to_string(camera.height) + ")");
  }
  return {camera.FocalX(), camera.FocalY(), camera.PrincipalX(), camera.PrincipalY(), camera.width, camera.height};
}

}  // namespace

RasterResult Rasterize(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
                       const RasterizeOptions& options) {
  RasterResult result;
  Rasterize(mesh, camera, cam_from_world, options, &result);
  return result;
}

void Rasterize(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
               const RasterizeOptions& options, RasterResult* out) {
  RasterizeWindows(mesh, camera, cam_from_world, options, camera.height, out, [](int, const RasterResult&) {});
}

void RasterizeWindows(const TriangleMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
                      const RasterizeOptions& options, int window_rows, RasterResult* window,
                      const RasterWindowVisitor& visit) {
  if (!(options.near_z > 0.0)) {
    throw InputError("Rasterize: near_z must be > 0 (got " + std::to_string(options.near_z) + ")");
  }
  if (options.row_bands < 0) throw InputError("Rasterize: row_bands must be >= 0 (got " + std::to_string(options.row_bands) + ")");
  if (window_rows < 1) throw InputError("RasterizeWindows: window_rows must be >= 1 (got " + std::to_string(window_rows) + ")");
  const Intrinsics k = IntrinsicsOf(camera);
  window_rows = std::min(window_rows, k.height);
  const int windows = (k.height + window_rows - 1) / window_rows;

  const Eigen::Matrix3d rotation = cam_from_world.R();
  const size_t num_vertices = mesh.vertices.size();
  std::vector<Eigen::Vector3d> points_in_cam(num_vertices);
  // Each vertex projected once (a vertex is a corner of about six faces): the faces in front of the
  // near plane are drawn from these without clipping (the same arithmetic as Project), and its row
  // places a face in the strips below (NaN before the near plane: such faces are never skipped).
  std::vector<ScreenVertex> screen(num_vertices);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, num_vertices, 4096), [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i < range.end(); ++i) {
      points_in_cam[i] = rotation * mesh.vertices[i].cast<double>() + cam_from_world.translation;
      const double z = points_in_cam[i].z();
      screen[i] = Project({points_in_cam[i], Eigen::Vector3d::Zero()}, k);
      if (!(z >= options.near_z)) screen[i].y = std::numeric_limits<double>::quiet_NaN();
    }
  });
  // Face f's rows widened by two, [*lo, *hi], all rows for a face with a vertex before the near
  // plane (it is clipped first); false for an invalid face.
  const auto valid_face = [&](const Eigen::Vector3i& face) {
    return (face.array() >= 0).all() && (face.array() < static_cast<int>(num_vertices)).all();
  };
  // Back faces, when culled, are found once here (not in every strip the face meets), and they
  // are left out of the strips' lists: facing away when the normal of the counter-clockwise face
  // points away from the centre.
  const size_t face_total = mesh.faces.size();
  std::vector<uint8_t> back_face;
  if (options.cull_backfaces) {
    back_face.assign(face_total, 0);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, face_total, 4096), [&](const tbb::blocked_range<size_t>& range) {
      for (size_t f = range.begin(); f < range.end(); ++f) {
        const Eigen::Vector3i& face = mesh.faces[f];
        if (!valid_face(face)) continue;
        const Eigen::Vector3d& a = points_in_cam[face[0]];
        const Eigen::Vector3d normal = (points_in_cam[face[1]] - a).cross(points_in_cam[face[2]] - a);
        back_face[f] = normal.dot(a) >= 0.0;
      }
    });
  }
  const auto face_rows = [&](size_t f, double* lo, double* hi) {
    const Eigen::Vector3i& face = mesh.faces[f];
    if (!valid_face(face) || (!back_face.empty() && back_face[f])) return false;
    const double r0 = screen[face[0]].y, r1 = screen[face[1]].y, r2 = screen[face[2]].y;
    if (std::isnan(r0) || std::isnan(r1) || std::isnan(r2)) {
      *lo = -std::numeric_limits<double>::infinity(), *hi = std::numeric_limits<double>::infinity();
    } else {
      *lo = std::min({r0, r1, r2}) - 2, *hi = std::max({r0, r1, r2}) + 2;
    }
    return true;
  };
  // Strips of rows, drawn in parallel: each window's rows cut into bands (a small mesh or window:
  // one). strip_start[s] is strip s's first row; strip_start.back() the image's height. Automatic:
  // four bands a thread, of 128 rows or more, at least one a thread: a face near a strip's edge is
  // set up in both strips, and strips of 74 rows drew a full-size castle layer's 8 M faces 25%
  // slower than strips of 530.
  const int threads = std::max(1, tbb::this_task_arena::max_concurrency());
  std::vector<int> strip_start, window_strips(static_cast<size_t>(windows) + 1, 0);
  for (int w = 0; w < windows; ++w) {
    const int first_row = w * window_rows, rows = std::min(k.height, first_row + window_rows) - first_row;
    const int automatic = face_total < 4096 || rows < 64 ? 1 : std::min(4 * threads, std::max(threads, rows / 128));
    const int bands = std::min(options.row_bands > 0 ? options.row_bands : automatic, rows);
    for (int b = 0; b < bands; ++b) strip_start.push_back(first_row + static_cast<int>(static_cast<int64_t>(b) * rows / bands));
    window_strips[static_cast<size_t>(w) + 1] = static_cast<int>(strip_start.size());
  }
  const int strips = static_cast<int>(strip_start.size());
  strip_start.push_back(k.height);
  // Each strip's faces, in the mesh's order: a face goes to every strip its widened rows meet
  // (mostly one or two), so that a strip draws its own faces without reading the others'. Blocks of
  // faces on the threads count their faces per strip, then write them from their offsets (a
  // counting sort, which keeps the order). One strip takes every face.
  std::vector<uint32_t> strip_faces;
  std::vector<size_t> strip_offset(static_cast<size_t>(strips) + 1, 0);
  if (strips > 1) {
    std::vector<int> strip_of_row(static_cast<size_t>(k.height));
    for (int s = 0; s < strips; ++s) std::fill(strip_of_row.begin() + strip_start[s], strip_of_row.begin() + strip_start[s + 1], s);
    // Calls add(s) for each strip s face f meets, as one pass over the strip's rows [row_lo, row_hi)
    // would decide (not when hi < row_lo or lo > row_hi); the candidates are the strips of the
    // rows at its bounds, one more either side (bounds clamped in double before any cast).
    const auto for_each_strip = [&](size_t f, const auto& add) {
      double lo, hi;
      if (!face_rows(f, &lo, &hi)) return;
      const int s_lo = std::max(0, strip_of_row[static_cast<size_t>(std::clamp(std::floor(lo), 0.0, k.height - 1.0))] - 1);
      const int s_hi = std::min(strips - 1, strip_of_row[static_cast<size_t>(std::clamp(std::floor(hi), 0.0, k.height - 1.0))] + 1);
      for (int s = s_lo; s <= s_hi; ++s) {
        if (!(hi < strip_start[s] || lo > strip_start[s + 1])) add(s);
      }
    };
    constexpr size_t kBlock = size_t{1} << 16;
    const size_t blocks = (face_total + kBlock - 1) / kBlock;
    std::vector<size_t> offset(blocks * strips, 0);  // block b's first entry in strip s: [b * strips + s]
    tbb::parallel_for(size_t{0}, blocks, [&](size_t b) {
      for (size_t f = b * kBlock; f < std::min(face_total, (b + 1) * kBlock); ++f) {
        for_each_strip(f, [&](int s) { ++offset[b * strips + s]; });
      }
    });
    size_t total = 0;
    for (int s = 0; s < strips; ++s) {
      strip_offset[s] = total;
      for (size_t b = 0; b < blocks; ++b) {
        const size_t count = offset[b * strips + s];
        offset[b * strips + s] = total;
        total += count;
      }
    }
    strip_offset[strips] = total;
    strip_faces.resize(total);
    tbb::parallel_for(size_t{0}, blocks, [&](size_t b) {
      for (size_t f = b * kBlock; f < std::min(face_total, (b + 1) * kBlock); ++f) {
        for_each_strip(f, [&](int s) { strip_faces[offset[b * strips + s]++] = static_cast<uint32_t>(f); });
      }
    });
  }
  RasterResult& result = *window;
  for (int w = 0; w < windows; ++w) {
    const int first_row = w * window_rows, rows = std::min(k.height, first_row + window_rows) - first_row;
    const size_t pixels = static_cast<size_t>(k.width) * rows;
    // Sized and cleared in place: a reused result keeps its buffers.
    const auto clear = [&](FloatMap* map, int channels) {
      map->width = k.width, map->height = rows, map->channels = channels;
      map->data.assign(pixels * channels, 0.f);
    };
    clear(&result.depth, 1);
    clear(&result.barycentric, 3);
    result.face_id.assign(pixels, -1);
    // Strip s's faces in the mesh's order (every face, for one strip), each drawn into the strip's
    // rows: each pixel is written by one strip, which meets the faces in the order one pass over
    // the image does, so the result is the same to the bit (Rasterizer.BandsOfRowsDrawAsOnePass).
    const auto draw_strip = [&](int s) {
      const size_t begin = strips > 1 ? strip_offset[s] : 0, end = strips > 1 ? strip_offset[s + 1] : face_total;
      for (size_t i = begin; i < end; ++i) {
        const size_t f = strips > 1 ? strip_faces[i] : i;
        const Eigen::Vector3i& face = mesh.faces[f];
        if (!valid_face(face) || (!back_face.empty() && back_face[f])) continue;
        if (points_in_cam[face[0]].z() >= options.near_z && points_in_cam[face[1]].z() >= options.near_z &&
            points_in_cam[face[2]].z() >= options.near_z) {  // nothing to clip
          const ScreenVertex v[3] = {screen[face[0]], screen[face[1]], screen[face[2]]};
          DrawScreenTriangle(v, nullptr, static_cast<int>(f), k, strip_start[s], strip_start[s + 1], first_row, &result);
          continue;
        }
        ClipVertex in[3];
        for (int j = 0; j < 3; ++j) in[j] = {points_in_cam[face[j]], Eigen::Vector3d::Unit(j)};
        ClipVertex polygon[4];
        const int n = ClipNear(in, options.near_z, polygon);
        for (int t = 1; t + 1 < n; ++t) {
          const ClipVertex tri[3] = {polygon[0], polygon[t], polygon[t + 1]};
          RasterizeTriangle(tri, static_cast<int>(f), k, strip_start[s], strip_start[s + 1], first_row, &result);
        }
      }
    };
    if (window_strips[w + 1] - window_strips[w] == 1) {
      draw_strip(window_strips[w]);
    } else {
      tbb::parallel_for(window_strips[w], window_strips[w + 1], draw_strip);
    }
    visit(first_row, result);
  }
}

}  // namespace ibmr
