// Polygon view maps (see view_maps.h; seed 003 §7-8).
#include "pipeline/core/view_maps.h"

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <algorithm>
#include <cstring>
#include <limits>
#include <stdexcept>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {

namespace {

constexpr char kMagic[8] = {'I', 'B', 'M', 'R', 'V', 'M', '0', '2'};
constexpr double kPi = 3.141592653589793;  // the grid's half-width: every direction, the back hemisphere too

// v[i] = sqrt(v[i]), correctly rounded, four at a time where SSE is there (std::sqrt in a loop
// does not vectorise: it may set errno).
void SqrtInPlace(float* v, int n) {
  int i = 0;
#if defined(__SSE__)
  for (; i + 4 <= n; i += 4) _mm_storeu_ps(v + i, _mm_sqrt_ps(_mm_loadu_ps(v + i)));
#endif
  for (; i < n; ++i) v[i] = std::sqrt(v[i]);
}

double GridCoordinate(int i, int grid) { return -kPi + 2.0 * kPi * i / (grid - 1); }

template <typename T>
void Put(std::string* out, T value) {
  out->append(reinterpret_cast<const char*>(&value), sizeof(T));
}

class Reader {
 public:
  Reader(const std::string& path, std::string bytes) : path_(path), bytes_(std::move(bytes)) {}
  template <typename T>
  T Get(const char* what) {
    if (offset_ + sizeof(T) > bytes_.size()) {
      throw InputError(path_ + ": ends inside " + what + " at byte " + std::to_string(offset_) +
                       " (truncated; run the texture stage again)");
    }
    T value;
    std::memcpy(&value, bytes_.data() + offset_, sizeof(T));
    offset_ += sizeof(T);
    return value;
  }
  std::string Bytes(size_t n, const char* what) {
    if (offset_ + n > bytes_.size()) {
      throw InputError(path_ + ": ends inside " + what + " (truncated; run the texture stage again)");
    }
    std::string s = bytes_.substr(offset_, n);
    offset_ += n;
    return s;
  }
  bool AtEnd() const { return offset_ == bytes_.size(); }

 private:
  std::string path_, bytes_;
  size_t offset_ = 0;
};

}  // namespace

Eigen::Matrix3d FaceFrame(const Eigen::Vector3d& normal) {
  const Eigen::Vector3d n = normal.normalized();
  Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(n);
  if (x.norm() < 1e-6) x = Eigen::Vector3d::UnitX();  // y_W and n collinear (Eq. 1)
  x.normalize();
  const Eigen::Vector3d y = n.cross(x);
  Eigen::Matrix3d frame;
  frame << x, y, n;
  return frame;
}

Eigen::Vector2d MapDirection(const Eigen::Matrix3d& frame, const Eigen::Vector3d& direction) {
  const Eigen::Vector3d n = frame.col(2);
  const Eigen::Vector3d v = direction.normalized();
  const Eigen::Vector3d rotated = n.cross(v).cross(n);  // Eq. 2: v laid into the face's plane
  const double length = rotated.norm();
  if (length < 1e-12) return Eigen::Vector2d::Zero();  // along the normal (or against it)
  const double arc = std::acos(std::clamp(n.dot(v), -1.0, 1.0));
  return arc / length * Eigen::Vector2d(frame.col(0).dot(rotated), frame.col(1).dot(rotated));
}

void BuildGrid(int grid, FaceViewMap* face, const std::vector<float>& penalty) {
  face->nearest.clear();
  if (face->views.size() < 2) return;
  if (face->directions.size() > 256) {  // `nearest` holds entries as bytes
    throw std::invalid_argument("BuildGrid: " + std::to_string(face->directions.size()) + " views, at most 256 fit a grid");
  }
  if (!penalty.empty() && penalty.size() != face->views.size()) {
    throw std::invalid_argument("BuildGrid: " + std::to_string(penalty.size()) + " penalties for " +
                                std::to_string(face->views.size()) + " views");
  }
  face->nearest.resize(static_cast<size_t>(grid) * grid);
  // A row of samples at a time, view by view, in vector arrays with no branch on the comparisons
  // (a per-sample branch was mispredicted half the time): the same float operations per sample as
  // one sample against every view, so the same winners, ties to the first view. The square roots
  // are IEEE ones (SqrtInPlace; Eigen's own float sqrt may be an approximation).
  Eigen::ArrayXf coordinate(grid);
  for (int i = 0; i < grid; ++i) coordinate[i] = static_cast<float>(GridCoordinate(i, grid));
  Eigen::ArrayXf best_distance(grid), best_view(grid), d(grid);
  for (int j = 0; j < grid; ++j) {
    best_distance.setConstant(std::numeric_limits<float>::max());
    best_view.setZero();
    for (size_t k = 0; k < face->directions.size(); ++k) {
      const float dy = face->directions[k].y() - coordinate[j];
      const float add = penalty.empty() ? 0.f : penalty[k];  // d + 0 is d
      d = (face->directions[k].x() - coordinate).square() + dy * dy;
      SqrtInPlace(d.data(), grid);
      d += add;
      best_view = (d < best_distance).select(static_cast<float>(k), best_view);
      best_distance = best_distance.min(d);
    }
    uint8_t* best = face->nearest.data() + static_cast<size_t>(j) * grid;
    for (int i = 0; i < grid; ++i) best[i] = static_cast<uint8_t>(best_view[i]);
  }
}

ViewBlend BlendFor(const ViewMaps& maps, int face_index, const Eigen::Matrix3d& frame,
                   const Eigen::Vector3d& direction) {
  const FaceViewMap& face = maps.faces[face_index];
  // One view (or none) needs no mapping.
  return BlendAt(maps, face_index, face.views.size() >= 2 && !face.nearest.empty() ? MapDirection(frame, direction)
                                                                                    : Eigen::Vector2d::Zero());
}

namespace {

// The grid cell holding mapped direction p: its lower corner (i, j) and p's place inside it.
struct GridCell {
  int i, j;
  double fx, fy;
};

GridCell LocateInGrid(int grid, const Eigen::Vector2d& p) {
  // Continuous grid coordinates, clamped to the grid (directions beyond the horizon take the
  // border's views).
  const double scale = (grid - 1) / (2.0 * kPi);
  const double gx = std::clamp((p.x() + kPi) * scale, 0.0, grid - 1.0);
  const double gy = std::clamp((p.y() + kPi) * scale, 0.0, grid - 1.0);
  GridCell cell;
  cell.i = std::min(static_cast<int>(gx), grid - 2);
  cell.j = std::min(static_cast<int>(gy), grid - 2);
  cell.fx = gx - cell.i;
  cell.fy = gy - cell.j;
  return cell;
}

}  // namespace

void PrefetchBlendAt(const ViewMaps& maps, int face_index, const Eigen::Vector2d& p) {
  const FaceViewMap& face = maps.faces[face_index];
  __builtin_prefetch(face.views.data());
  if (face.views.size() < 2 || face.nearest.empty()) return;
  const GridCell cell = LocateInGrid(maps.grid, p);
  const uint8_t* row = face.nearest.data() + static_cast<size_t>(cell.j) * maps.grid + cell.i;
  __builtin_prefetch(row);
  __builtin_prefetch(row + maps.grid + 1);
}

ViewBlend BlendAt(const ViewMaps& maps, int face_index, const Eigen::Vector2d& p) {
  ViewBlend blend;
  const FaceViewMap& face = maps.faces[face_index];
  if (face.views.empty()) return blend;
  if (face.views.size() == 1 || face.nearest.empty()) {
    blend.count = 1;
    blend.views[0] = face.views[0];
    blend.weights[0] = 1.f;
    return blend;
  }
  const int grid = maps.grid;
  const GridCell cell = LocateInGrid(grid, p);
  const int i = cell.i, j = cell.j;
  const double fx = cell.fx, fy = cell.fy;
  // The cell splits along its diagonal from (i, j) to (i+1, j+1): barycentric weights of the
  // triangle holding (fx, fy).
  std::array<std::pair<int, int>, 3> corners;
  std::array<double, 3> w;
  if (fx >= fy) {
    corners = {{{i, j}, {i + 1, j}, {i + 1, j + 1}}};
    w = {1.0 - fx, fx - fy, fy};
  } else {
    corners = {{{i, j}, {i, j + 1}, {i + 1, j + 1}}};
    w = {1.0 - fy, fy - fx, fx};
  }
  for (int c = 0; c < 3; ++c) {
    const int k = face.nearest[static_cast<size_t>(corners[c].second) * grid + corners[c].first];
    const int view = face.views[k];
    int slot = 0;
    while (slot < blend.count && blend.views[slot] != view) ++slot;
    if (slot == blend.count) {
      blend.views[slot] = view;
      blend.weights[slot] = 0.f;
      ++blend.count;
    }
    blend.weights[slot] += static_cast<float>(w[c]);
  }
  return blend;
}

void WriteViewMaps(const ViewMaps& maps, const std::string& path) {
  // The file's size first: one allocation instead of a string that doubles (and copies, and
  // faults its pages in again) a dozen times on the way to a few hundred megabytes.
  const size_t cells = static_cast<size_t>(maps.grid) * maps.grid;
  size_t bytes = sizeof(kMagic) + 3 * sizeof(uint32_t);
  for (const std::string& name : maps.view_names) bytes += sizeof(uint32_t) + name.size();
  for (const FaceViewMap& face : maps.faces) {
    bytes += sizeof(uint16_t) + face.views.size() * (sizeof(uint16_t) + 2 * sizeof(float)) + (face.views.size() >= 2 ? cells : 0);
  }
  std::string out;
  out.reserve(bytes);
  out.append(kMagic, sizeof(kMagic));
  Put<uint32_t>(&out, static_cast<uint32_t>(maps.faces.size()));
  Put<uint32_t>(&out, static_cast<uint32_t>(maps.view_names.size()));
  Put<uint32_t>(&out, static_cast<uint32_t>(maps.grid));
  for (const std::string& name : maps.view_names) {
    Put<uint32_t>(&out, static_cast<uint32_t>(name.size()));
    out += name;
  }
  for (const FaceViewMap& face : maps.faces) {
    Put<uint16_t>(&out, static_cast<uint16_t>(face.views.size()));
    for (size_t k = 0; k < face.views.size(); ++k) {
      Put<uint16_t>(&out, face.views[k]);
      Put<float>(&out, face.directions[k].x());
      Put<float>(&out, face.directions[k].y());
    }
    if (face.views.size() >= 2) {
      if (face.nearest.size() != cells) throw IoError(path + ": a face's view map grid is not built (internal)");
      out.append(reinterpret_cast<const char*>(face.nearest.data()), cells);
    }
  }
  WriteFileAtomic(path, out);
}

ViewMaps ReadViewMaps(const std::string& path) {
  Reader in(path, ReadFile(path));
  if (in.Bytes(sizeof(kMagic), "the header") != std::string(kMagic, sizeof(kMagic))) {
    throw InputError(path + ": not a view map file (expected IBMRVM02 at the start; run the texture stage again)");
  }
  ViewMaps maps;
  const uint32_t faces = in.Get<uint32_t>("the header");
  const uint32_t views = in.Get<uint32_t>("the header");
  maps.grid = static_cast<int>(in.Get<uint32_t>("the header"));
  if (maps.grid < 2 || maps.grid > 256) {
    throw InputError(path + ": grid " + std::to_string(maps.grid) + " is outside [2, 256]");
  }
  if (views > 65535) throw InputError(path + ": " + std::to_string(views) + " views, more than 65535");
  for (uint32_t v = 0; v < views; ++v) {
    const uint32_t length = in.Get<uint32_t>("a view name");
    if (length > 4096) throw InputError(path + ": view name " + std::to_string(v) + " is " + std::to_string(length) + " bytes long");
    maps.view_names.push_back(in.Bytes(length, "a view name"));
  }
  const size_t cells = static_cast<size_t>(maps.grid) * maps.grid;
  maps.faces.reserve(std::min<uint32_t>(faces, 1u << 24));
  for (uint32_t f = 0; f < faces; ++f) {
    FaceViewMap face;
    const uint16_t count = in.Get<uint16_t>("a face");
    for (uint16_t k = 0; k < count; ++k) {
      const uint16_t view = in.Get<uint16_t>("a face's views");
      if (view >= views) {
        throw InputError(path + ": face " + std::to_string(f) + " names view " + std::to_string(view) + " of " +
                         std::to_string(views));
      }
      const float px = in.Get<float>("a face's views");
      const float py = in.Get<float>("a face's views");
      face.views.push_back(view);
      face.directions.emplace_back(px, py);
    }
    if (count >= 2) {
      const std::string grid = in.Bytes(cells, "a face's grid");
      face.nearest.assign(grid.begin(), grid.end());
      for (uint8_t k : face.nearest) {
        if (k >= count) throw InputError(path + ": face " + std::to_string(f) + "'s grid names entry " + std::to_string(k) + " of " + std::to_string(count));
      }
    }
    maps.faces.push_back(std::move(face));
  }
  if (!in.AtEnd()) throw InputError(path + ": bytes after the last face (a different version? run the texture stage again)");
  return maps;
}

}  // namespace ibmr
