// Octree carving from silhouettes with the O(1) distance-map cube test (seed 000 lines 4136-4258,
// Szeliski 1993), the brute-force reference on a dense grid, hull projection, depth bounds and the
// octree file format. See carve.h.
#include "stages/carve/carve.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace ibmr {

namespace {

enum class Verdict { kEmpty, kFull, kUnknown, kPartial };

// A view with its projection and the two chessboard distance maps of the O(1) test.
struct PreparedView {
  const CarveView* view = nullptr;
  Eigen::Matrix3d rotation;
  Eigen::Vector3d translation;
  bool pinhole = true;
  double fx = 1, fy = 1, cx = 0, cy = 0;
  int width = 0, height = 0;
  bool outside_empty = true;
  cv::Mat dist_to_silhouette;  // CV_32F: chessboard distance to the nearest silhouette pixel
  cv::Mat dist_to_background;  // CV_32F: ... to the nearest background pixel
  cv::Mat silhouette;          // CV_8UC1 0/1
};

// Throws std::invalid_argument naming the view when its mask does not match its camera.
void CheckMask(const CarveView& view) {
  if (view.mask.empty() || view.mask.type() != CV_8UC1 || view.mask.cols != view.camera.width ||
      view.mask.rows != view.camera.height) {
    throw std::invalid_argument("view " + view.name + ": the mask is " + std::to_string(view.mask.cols) + "x" +
                                std::to_string(view.mask.rows) + " (8-bit, one channel expected) but the camera is " +
                                std::to_string(view.camera.width) + "x" + std::to_string(view.camera.height));
  }
}

PreparedView Prepare(const CarveView& view, bool outside_empty, bool with_distance_maps) {
  CheckMask(view);
  PreparedView p;
  p.view = &view;
  p.rotation = view.cam_from_world.rotation.toRotationMatrix();
  p.translation = view.cam_from_world.translation;
  p.pinhole = !view.camera.HasDistortion();
  p.fx = view.camera.FocalX();
  p.fy = view.camera.FocalY();
  p.cx = view.camera.PrincipalX();
  p.cy = view.camera.PrincipalY();
  p.width = view.camera.width;
  p.height = view.camera.height;
  p.outside_empty = outside_empty;
  p.silhouette = (view.mask != 0) / 255;  // 0/1
  if (with_distance_maps) {
    // distanceTransform measures the distance to the nearest zero pixel.
    cv::distanceTransform(p.silhouette == 0, p.dist_to_silhouette, cv::DIST_C, cv::DIST_MASK_3, CV_32F);
    cv::distanceTransform(p.silhouette, p.dist_to_background, cv::DIST_C, cv::DIST_MASK_3, CV_32F);
  }
  return p;
}

struct PixelRect {
  int c0, c1, r0, r1;  // inclusive
};

// True when every pixel of `rect` is farther than 0 from the distance map's target set: the rect is
// covered by odd-sided squares of the shorter side, each tested in O(1) at its centre pixel.
bool NoTargetInRect(const cv::Mat& distance, const PixelRect& rect) {
  const int w = rect.c1 - rect.c0 + 1, h = rect.r1 - rect.r0 + 1;
  int side = std::min(w, h);
  if (side % 2 == 0) --side;
  const int radius = (side - 1) / 2;
  for (int r = rect.r0;; r += side) {
    const int top = std::min(r, rect.r1 - side + 1);
    const float* row = distance.ptr<float>(top + radius);
    for (int c = rect.c0;; c += side) {
      const int left = std::min(c, rect.c1 - side + 1);
      if (row[left + radius] <= radius) return false;
      if (left + side - 1 >= rect.c1) break;
    }
    if (top + side - 1 >= rect.r1) break;
  }
  return true;
}

// Brute force: scans every pixel of the rect.
bool NoValueInRect(const cv::Mat& silhouette, const PixelRect& rect, uint8_t value) {
  for (int r = rect.r0; r <= rect.r1; ++r) {
    const uint8_t* row = silhouette.ptr<uint8_t>(r);
    for (int c = rect.c0; c <= rect.c1; ++c) {
      if (row[c] == value) return false;
    }
  }
  return true;
}

constexpr double kBig = 1e9;

// The 8 corners of a cube in a camera's frame, from its min corner there and its edges (columns):
// corner i adds edge a when bit a of i is set (every caller sums in this order: the same values).
std::array<Eigen::Vector3d, 8> CubeCorners(const Eigen::Vector3d& base, const Eigen::Matrix3d& steps) {
  std::array<Eigen::Vector3d, 8> corners;
  for (int i = 0; i < 8; ++i) {
    Eigen::Vector3d x = base;
    if (i & 1) x += steps.col(0);
    if (i & 2) x += steps.col(1);
    if (i & 4) x += steps.col(2);
    corners[i] = x;
  }
  return corners;
}

// The per-view verdict on the cube [min, min + size]^3 (see carve.h for the rules).
template <bool kBruteForce>
Verdict ClassifyInView(const PreparedView& v, const Eigen::Vector3d& min, double size) {
  double u0 = kBig, u1 = -kBig, w0 = kBig, w1 = -kBig;
  int behind = 0;
  const Eigen::Vector3d base = v.rotation * min + v.translation;
  const Eigen::Matrix3d steps = v.rotation * size;
  const std::array<Eigen::Vector3d, 8> cube = CubeCorners(base, steps);
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d& x = cube[i];
    if (x.z() <= 1e-12) {
      ++behind;
      continue;
    }
    double u, w;
    if (v.pinhole) {
      u = v.fx * x.x() / x.z() + v.cx;
      w = v.fy * x.y() / x.z() + v.cy;
    } else {
      const Eigen::Vector2d pixel = v.view->camera.ImgFromCam(x);
      u = pixel.x();
      w = pixel.y();
    }
    u0 = std::min(u0, u);
    u1 = std::max(u1, u);
    w0 = std::min(w0, w);
    w1 = std::max(w1, w);
  }
  if (behind == 8) return v.outside_empty ? Verdict::kEmpty : Verdict::kUnknown;
  if (behind > 0) return Verdict::kPartial;
  const auto to_pixel = [](double value) { return static_cast<int>(std::floor(std::clamp(value, -kBig, kBig))); };
  PixelRect rect{to_pixel(u0), to_pixel(u1), to_pixel(w0), to_pixel(w1)};
  const bool inside = rect.c0 >= 0 && rect.r0 >= 0 && rect.c1 < v.width && rect.r1 < v.height;
  rect.c0 = std::max(rect.c0, 0);
  rect.r0 = std::max(rect.r0, 0);
  rect.c1 = std::min(rect.c1, v.width - 1);
  rect.r1 = std::min(rect.r1, v.height - 1);
  if (rect.c0 > rect.c1 || rect.r0 > rect.r1) return v.outside_empty ? Verdict::kEmpty : Verdict::kUnknown;
  const bool all_background = kBruteForce ? NoValueInRect(v.silhouette, rect, 1)
                                          : NoTargetInRect(v.dist_to_silhouette, rect);
  if (all_background) return (inside || v.outside_empty) ? Verdict::kEmpty : Verdict::kPartial;
  const bool all_silhouette = kBruteForce ? NoValueInRect(v.silhouette, rect, 0)
                                          : NoTargetInRect(v.dist_to_background, rect);
  if (all_silhouette) return (inside || !v.outside_empty) ? Verdict::kFull : Verdict::kPartial;
  return Verdict::kPartial;
}

// The node's state from every view's verdict: empty if any view says so, else partial if any
// view sees it partly. The verdicts do not depend on the order the views are asked in, so
// `rejecting` (optional) names the view to ask first and is set to the view that found a node
// empty: nodes next to each other are mostly emptied by the same view.
template <bool kBruteForce>
NodeState Classify(const std::vector<PreparedView>& views, const Eigen::Vector3d& min, double size, bool* unseen,
                   size_t* rejecting = nullptr) {
  bool any_full = false, any_partial = false;
  const size_t first = rejecting != nullptr && *rejecting < views.size() ? *rejecting : 0;
  for (size_t k = 0; k < views.size(); ++k) {
    const size_t index = first + k < views.size() ? first + k : first + k - views.size();
    switch (ClassifyInView<kBruteForce>(views[index], min, size)) {
      case Verdict::kEmpty:
        if (rejecting != nullptr) *rejecting = index;
        return NodeState::kEmpty;
      case Verdict::kFull: any_full = true; break;
      case Verdict::kPartial: any_partial = true; break;
      case Verdict::kUnknown: break;
    }
  }
  *unseen = !any_full && !any_partial;
  return any_partial ? NodeState::kPartial : NodeState::kFull;
}

// The visual-hull test of one point against discrete silhouettes: in every view, one of the 2x2
// pixels whose centres surround the projection is silhouette (out of an image, or behind a camera:
// kept unless that view's outside is known empty). Taking the pixel that contains the projection
// instead would drop points of the object whose projection falls in a pixel whose centre, the
// mask's sample, lies just outside the silhouette; the 2x2 neighbourhood keeps them at the cost of
// at most half a pixel of extra hull.
bool PointInAllSilhouettes(const std::vector<PreparedView>& views, const Eigen::Vector3d& point) {
  for (const PreparedView& v : views) {
    const Eigen::Vector3d x = v.rotation * point + v.translation;
    if (x.z() <= 1e-12) {
      if (v.outside_empty) return false;
      continue;
    }
    const Eigen::Vector2d pixel = v.pinhole ? Eigen::Vector2d(v.fx * x.x() / x.z() + v.cx, v.fy * x.y() / x.z() + v.cy)
                                            : v.view->camera.ImgFromCam(x);
    // Pixel centres are at +0.5: the 2x2 block starts at floor(p - 0.5).
    const int c0 = static_cast<int>(std::floor(std::clamp(pixel.x() - 0.5, -kBig, kBig)));
    const int r0 = static_cast<int>(std::floor(std::clamp(pixel.y() - 0.5, -kBig, kBig)));
    bool inside = false;
    for (int r = r0; r <= r0 + 1 && !inside; ++r) {
      for (int c = c0; c <= c0 + 1 && !inside; ++c) {
        const bool in_image = c >= 0 && r >= 0 && c < v.width && r < v.height;
        inside = in_image ? v.silhouette.at<uint8_t>(r, c) != 0 : !v.outside_empty;
      }
    }
    if (!inside) return false;
  }
  return true;
}

// The rect of the root cube is non-empty and not entirely behind the camera.
bool SeesCube(const PreparedView& view, const Eigen::Vector3d& min, double size) {
  PreparedView unknown_outside = view;
  unknown_outside.outside_empty = false;
  return ClassifyInView<true>(unknown_outside, min, size) != Verdict::kUnknown;
}

bool OutsideEmpty(const CarveView& view, OutsideImage outside) {
  if (outside != OutsideImage::kAuto) return outside == OutsideImage::kEmpty;
  const cv::Mat& m = view.mask;
  return cv::countNonZero(m.row(0)) == 0 && cv::countNonZero(m.row(m.rows - 1)) == 0 &&
         cv::countNonZero(m.col(0)) == 0 && cv::countNonZero(m.col(m.cols - 1)) == 0;
}

template <typename T>
void Put(std::string* out, const T& value) {
  out->append(reinterpret_cast<const char*>(&value), sizeof(T));
}

template <typename T>
T Get(const std::string& bytes, size_t* offset) {
  if (*offset + sizeof(T) > bytes.size()) throw std::runtime_error("octree file is truncated at byte " + std::to_string(*offset));
  T value;
  std::memcpy(&value, bytes.data() + *offset, sizeof(T));
  *offset += sizeof(T);
  return value;
}

}  // namespace

bool CarveOptions::Check(std::string* error) const {
  if (levels < 1 || levels > 10) {
    *error = "levels: must be in [1, 10], got " + std::to_string(levels);
  } else if (smooth_iterations < 0 || smooth_iterations > 1000) {
    *error = "smooth_iterations: must be in [0, 1000], got " + std::to_string(smooth_iterations);
  } else if (!(smooth_lambda > 0 && smooth_lambda < 1)) {
    *error = "smooth_lambda: must be in (0, 1), got " + std::to_string(smooth_lambda);
  } else if (!(smooth_mu > -1 && smooth_mu < 0 && -smooth_mu > smooth_lambda)) {
    *error = "smooth_mu: must be in (-1, 0) with |mu| > lambda, got " + std::to_string(smooth_mu);
  } else if (!(max_displacement >= 0 && max_displacement < 1)) {
    *error = "max_displacement: must be in [0, 1) cells, got " + std::to_string(max_displacement);
  } else if (max_mesh_level < 1 || max_mesh_level > 9) {
    *error = "max_mesh_level: must be in [1, 9], got " + std::to_string(max_mesh_level);
  } else if (mesh_dilation < 0 || mesh_dilation > 2) {
    *error = "mesh_dilation: must be in [0, 2], got " + std::to_string(mesh_dilation);
  } else if (!(level_tolerance >= 0 && level_tolerance <= 1)) {
    *error = "level_tolerance: must be in [0, 1], got " + std::to_string(level_tolerance);
  } else {
    return true;
  }
  return false;
}

CarveResult CarveOctree(const std::vector<CarveView>& views, const Eigen::Vector3d& origin, double size,
                        const CarveOptions& options, ProgressReporter* progress) {
  NullProgress null_progress;
  if (!progress) progress = &null_progress;
  CarveResult result;
  result.octree.origin = origin;
  result.octree.size = size;
  // The views' distance maps on the threads, then kept in the views' order.
  std::vector<PreparedView> all(views.size());
  std::vector<uint8_t> sees(views.size(), 0);
  for (const CarveView& view : views) {
    CheckMask(view);  // in the views' order: the first bad mask is the one named
    result.outside_empty.push_back(OutsideEmpty(view, options.outside));
  }
  tbb::parallel_for(size_t{0}, views.size(), [&](size_t i) {
    all[i] = Prepare(views[i], result.outside_empty[i], true);
    sees[i] = SeesCube(all[i], origin, size);
  });
  std::vector<PreparedView> prepared;
  for (size_t i = 0; i < views.size(); ++i) {
    // A view that does not see the volume would carve all of it (outside empty) or nothing.
    if (!sees[i]) {
      result.views_not_seeing_volume.push_back(views[i].name);
      all[i] = PreparedView();  // its distance maps are not needed
      continue;
    }
    prepared.push_back(std::move(all[i]));
  }
  progress->Begin("octree levels", options.levels + 1);
  result.octree.levels.push_back({OctreeNode{}});
  for (int level = 0; level <= options.levels; ++level) {
    const auto start = std::chrono::steady_clock::now();
    std::vector<OctreeNode>& nodes = result.octree.levels[level];
    std::vector<uint8_t> unseen(nodes.size(), 0);
    std::vector<uint8_t> by_centre(nodes.size(), 0);  // partial nodes: 1 kept, 2 dropped by the centre test
    const double cell = result.octree.CellSize(level);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, nodes.size(), 256), [&](const tbb::blocked_range<size_t>& range) {
      size_t rejecting = 0;  // the view that emptied the last empty node of this range
      for (size_t i = range.begin(); i != range.end(); ++i) {
        bool is_unseen = false;
        nodes[i].state = prepared.empty() ? NodeState::kEmpty
                                          : Classify<false>(prepared, result.octree.CellMin(level, nodes[i]), cell,
                                                            &is_unseen, &rejecting);
        unseen[i] = is_unseen;
        if (options.leaf_test == LeafTest::kCentre && nodes[i].state == NodeState::kPartial) {
          const Eigen::Vector3d centre = result.octree.CellMin(level, nodes[i]) + Eigen::Vector3d::Constant(0.5 * cell);
          by_centre[i] = PointInAllSilhouettes(prepared, centre) ? 1 : 2;
          // The finest level's partial leaves are decided here; coarser ones are refined further.
          if (level == options.levels) nodes[i].state = by_centre[i] == 1 ? NodeState::kFull : NodeState::kEmpty;
        }
      }
    });
    LevelStats stats;
    stats.level = level;
    stats.nodes = nodes.size();
    std::vector<OctreeNode> children;
    for (size_t i = 0; i < nodes.size(); ++i) {
      const OctreeNode& node = nodes[i];
      stats.unseen += unseen[i];
      if (level == options.levels) {
        stats.leaves_kept_by_centre += by_centre[i] == 1;
        stats.leaves_dropped_by_centre += by_centre[i] == 2;
      }
      if (node.state == NodeState::kEmpty) ++stats.empty;
      if (node.state == NodeState::kFull) ++stats.full;
      if (node.state != NodeState::kPartial) continue;
      ++stats.partial;
      if (level == options.levels) continue;
      for (int c = 0; c < 8; ++c) {
        children.push_back(OctreeNode{static_cast<uint16_t>(2 * node.x + (c & 1)),
                                      static_cast<uint16_t>(2 * node.y + ((c >> 1) & 1)),
                                      static_cast<uint16_t>(2 * node.z + ((c >> 2) & 1)), NodeState::kPartial});
      }
    }
    if (options.leaf_test == LeafTest::kCentre) {
      for (uint8_t& flag : by_centre) flag = flag == 1;
      result.octree.centre_kept.push_back(std::move(by_centre));
    }
    stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    result.stats.push_back(stats);
    if (level < options.levels) result.octree.levels.push_back(std::move(children));
    progress->Advance(1, "level " + std::to_string(level));
  }
  progress->End();
  return result;
}

std::vector<uint8_t> CarveBruteForce(const std::vector<CarveView>& views, const std::vector<bool>& outside_empty,
                                     const Eigen::Vector3d& origin, double size, int level) {
  std::vector<PreparedView> prepared;
  for (size_t i = 0; i < views.size(); ++i) {
    PreparedView p = Prepare(views[i], outside_empty.at(i), false);
    if (SeesCube(p, origin, size)) prepared.push_back(std::move(p));
  }
  const int n = 1 << level;
  const double cell = size / n;
  std::vector<uint8_t> grid(static_cast<size_t>(n) * n * n, 0);
  tbb::parallel_for(0, n, [&](int z) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        bool unseen = false;
        const Eigen::Vector3d min = origin + cell * Eigen::Vector3d(x, y, z);
        const bool kept = !prepared.empty() && Classify<true>(prepared, min, cell, &unseen) != NodeState::kEmpty;
        grid[(static_cast<size_t>(z) * n + y) * n + x] = kept;
      }
    }
  });
  return grid;
}

namespace {

// Node i of level l belongs to the hull at `level` (see HullCells).
bool InHull(const Octree& octree, int l, int level, size_t i) {
  const NodeState state = octree.levels[l][i].state;
  if (state == NodeState::kFull) return true;
  if (l != level || state != NodeState::kPartial) return false;
  return static_cast<size_t>(l) >= octree.centre_kept.size() || octree.centre_kept[l].empty() || octree.centre_kept[l][i];
}

}  // namespace

std::vector<HullCell> HullCells(const Octree& octree, int level) {
  std::vector<HullCell> cells;
  for (int l = 0; l <= std::min(level, octree.MaxLevel()); ++l) {
    for (size_t i = 0; i < octree.levels[l].size(); ++i) {
      if (InHull(octree, l, level, i)) cells.push_back(HullCell{octree.CellMin(l, octree.levels[l][i]), octree.CellSize(l)});
    }
  }
  return cells;
}

std::vector<HullCell> SurfaceHullCells(const Octree& octree, int level) {
  level = std::min(level, octree.MaxLevel());
  if (level > 8) return HullCells(octree, level);
  const std::vector<uint8_t> dense = DenseHull(octree, level);
  const int64_t n = int64_t{1} << level;
  const auto occupied = [&](int64_t x, int64_t y, int64_t z) {
    return x >= 0 && y >= 0 && z >= 0 && x < n && y < n && z < n && dense[static_cast<size_t>((z * n + y) * n + x)];
  };
  // The cell's faces with a voxel beside them (outside the cell) that is not in the hull.
  const auto open_faces = [&](const OctreeNode& node, int64_t span) {
    const int64_t x0 = node.x * span, y0 = node.y * span, z0 = node.z * span;
    uint8_t open = 0;
    for (int64_t a = 0; a < span; ++a) {
      for (int64_t b = 0; b < span; ++b) {
        open |= !occupied(x0 - 1, y0 + a, z0 + b) << 0 | !occupied(x0 + span, y0 + a, z0 + b) << 1 |
                !occupied(x0 + a, y0 - 1, z0 + b) << 2 | !occupied(x0 + a, y0 + span, z0 + b) << 3 |
                !occupied(x0 + a, y0 + b, z0 - 1) << 4 | !occupied(x0 + a, y0 + b, z0 + span) << 5;
      }
    }
    return open;
  };
  std::vector<HullCell> cells;
  for (int l = 0; l <= level; ++l) {
    const int64_t span = int64_t{1} << (level - l);
    for (size_t i = 0; i < octree.levels[l].size(); ++i) {
      if (!InHull(octree, l, level, i)) continue;
      const uint8_t open = open_faces(octree.levels[l][i], span);
      if (open != 0) cells.push_back(HullCell{octree.CellMin(l, octree.levels[l][i]), octree.CellSize(l), open});
    }
  }
  return cells;
}

std::vector<uint8_t> DenseHull(const Octree& octree, int level) {
  const size_t n = size_t{1} << level;
  std::vector<uint8_t> grid(n * n * n, 0);
  for (int l = 0; l <= std::min(level, octree.MaxLevel()); ++l) {
    const size_t span = size_t{1} << (level - l);
    for (size_t i = 0; i < octree.levels[l].size(); ++i) {
      if (!InHull(octree, l, level, i)) continue;
      const OctreeNode& node = octree.levels[l][i];
      for (size_t z = node.z * span; z < (node.z + 1) * span; ++z) {
        for (size_t y = node.y * span; y < (node.y + 1) * span; ++y) {
          std::fill_n(grid.begin() + (z * n + y) * n + node.x * span, span, 1);
        }
      }
    }
  }
  return grid;
}

namespace {

// Camera::ImgFromCam with the intrinsics read once: for a camera without distortion the same
// arithmetic inline (the same pixel to the bit), which the per-corner loops below call millions
// of times; other models go through the camera.
class CornerProjector {
 public:
  explicit CornerProjector(const Camera& camera)
      : camera_(camera), pinhole_(!camera.HasDistortion()), fx_(camera.FocalX()), fy_(camera.FocalY()),
        cx_(camera.PrincipalX()), cy_(camera.PrincipalY()) {}
  Eigen::Vector2d operator()(const Eigen::Vector3d& point_in_cam) const {
    if (!pinhole_) return camera_.ImgFromCam(point_in_cam);
    const Eigen::Vector2d d = point_in_cam.hnormalized();
    return {fx_ * d.x() + cx_, fy_ * d.y() + cy_};
  }

 private:
  const Camera& camera_;
  bool pinhole_;
  double fx_, fy_, cx_, cy_;
};

}  // namespace

cv::Mat ProjectHull(const std::vector<HullCell>& cells, const Camera& camera, const Rigid3d& cam_from_world) {
  const CornerProjector project(camera);
  cv::Mat mask = cv::Mat::zeros(camera.height, camera.width, CV_8UC1);
  const Eigen::Matrix3d rotation = cam_from_world.rotation.toRotationMatrix();
  constexpr int kShift = 8;
  constexpr double kScale = 1 << kShift;
  const double limit = 4.0 * std::max(camera.width, camera.height) + 1e4;
  std::vector<cv::Point> corners(8), hull;
  const Eigen::Vector3d center = cam_from_world.Inverse().translation;
  for (const HullCell& cell : cells) {
    // The faces on whose outer side the camera is: those it could see.
    uint8_t facing = 0;
    for (int a = 0; a < 3; ++a) {
      facing |= (center[a] < cell.min[a]) << (2 * a) | (center[a] > cell.min[a] + cell.size) << (2 * a + 1);
    }
    if ((facing & cell.open_faces) == 0) continue;
    const Eigen::Vector3d base = rotation * cell.min + cam_from_world.translation;
    const Eigen::Matrix3d steps = rotation * cell.size;
    bool drawable = true;
    const std::array<Eigen::Vector3d, 8> cube = CubeCorners(base, steps);
    for (int i = 0; i < 8 && drawable; ++i) {
      const Eigen::Vector3d& x = cube[i];
      if (x.z() <= 1e-12) {
        drawable = false;
        break;
      }
      const Eigen::Vector2d pixel = project(x);
      if (std::abs(pixel.x()) > limit || std::abs(pixel.y()) > limit) {
        drawable = false;
        break;
      }
      // OpenCV draws with pixel centres at integers; ours are at +0.5.
      corners[i] = cv::Point(static_cast<int>(std::lround((pixel.x() - 0.5) * kScale)),
                             static_cast<int>(std::lround((pixel.y() - 0.5) * kScale)));
    }
    if (!drawable) continue;
    // Nothing to add where every pixel of the cell's box (one pixel wider than its corners' box)
    // is drawn already, as inside the silhouette after its neighbours: the convex hull and fill,
    // most of a cell's cost, are skipped there.
    int x0 = corners[0].x, x1 = x0, y0 = corners[0].y, y1 = y0;
    for (const cv::Point& c : corners) x0 = std::min(x0, c.x), x1 = std::max(x1, c.x), y0 = std::min(y0, c.y), y1 = std::max(y1, c.y);
    x0 = std::max(0, (x0 >> kShift) - 1), y0 = std::max(0, (y0 >> kShift) - 1);
    x1 = std::min(mask.cols - 1, (x1 >> kShift) + 2), y1 = std::min(mask.rows - 1, (y1 >> kShift) + 2);
    if (x0 > x1 || y0 > y1) continue;  // off the image
    bool covered = true;
    for (int y = y0; y <= y1 && covered; ++y) {
      const uint8_t* row = mask.ptr<uint8_t>(y);
      for (int x = x0; x <= x1 && covered; ++x) covered = row[x] != 0;
    }
    if (covered) continue;
    cv::convexHull(corners, hull);
    cv::fillConvexPoly(mask, hull, cv::Scalar(255), cv::LINE_8, kShift);
  }
  return mask;
}

cv::Mat ProjectHullSurface(const Octree& octree, int level, const std::vector<HullCell>& surface, const Camera& camera,
                           const Rigid3d& cam_from_world) {
  const CornerProjector project(camera);
  const Eigen::Matrix3d rotation = cam_from_world.rotation.toRotationMatrix();
  const Eigen::Vector3d base = rotation * octree.origin + cam_from_world.translation;
  const Eigen::Matrix3d steps = rotation * octree.size;
  // Margins well above ProjectHull's (z > 1e-12, |pixel| <= limit): a cell corner, a point of the
  // cube, is then in front and in reach however its own sums round.
  const double reach = 2.0 * std::max(camera.width, camera.height) + 5e3;
  bool whole_cube_drawable = true;
  const std::array<Eigen::Vector3d, 8> cube = CubeCorners(base, steps);
  for (int i = 0; i < 8 && whole_cube_drawable; ++i) {
    const Eigen::Vector3d& x = cube[i];
    const Eigen::Vector2d pixel = x.z() > 1e-6 * octree.size ? project(x) : Eigen::Vector2d::Constant(2 * reach);
    whole_cube_drawable = std::abs(pixel.x()) < reach && std::abs(pixel.y()) < reach;
  }
  return ProjectHull(whole_cube_drawable ? surface : HullCells(octree, level), camera, cam_from_world);
}

double MaskIou(const cv::Mat& a, const cv::Mat& b) {
  const int intersection = cv::countNonZero((a != 0) & (b != 0));
  const int united = cv::countNonZero((a != 0) | (b != 0));
  return united == 0 ? 1.0 : static_cast<double>(intersection) / united;
}

bool HullDepthBounds(const std::vector<HullCell>& cells, const Camera& camera, const Rigid3d& cam_from_world,
                     double* near_z, double* far_z) {
  const CornerProjector project(camera);
  const Eigen::Matrix3d rotation = cam_from_world.rotation.toRotationMatrix();
  double near_value = std::numeric_limits<double>::infinity(), far_value = 0.0;
  for (const HullCell& cell : cells) {
    const Eigen::Vector3d base = rotation * cell.min + cam_from_world.translation;
    const Eigen::Matrix3d steps = rotation * cell.size;
    const std::array<Eigen::Vector3d, 8> cube = CubeCorners(base, steps);
    double z0 = kBig, z1 = -kBig;
    for (const Eigen::Vector3d& x : cube) z0 = std::min(z0, x.z()), z1 = std::max(z1, x.z());
    if (z1 <= 1e-12) continue;
    // A cell that can move neither bound needs no projection.
    if (!(std::max(z0, 1e-9 * cell.size) < near_value || z1 > far_value)) continue;
    double u0 = kBig, u1 = -kBig, w0 = kBig, w1 = -kBig;
    bool straddles = false;
    for (int i = 0; i < 8; ++i) {
      const Eigen::Vector3d& x = cube[i];
      if (x.z() <= 1e-12) {
        straddles = true;
        continue;
      }
      const Eigen::Vector2d pixel = project(x);
      u0 = std::min(u0, pixel.x());
      u1 = std::max(u1, pixel.x());
      w0 = std::min(w0, pixel.y());
      w1 = std::max(w1, pixel.y());
    }
    if (!straddles && (u1 < 0 || w1 < 0 || u0 > camera.width || w0 > camera.height)) continue;
    near_value = std::min(near_value, std::max(z0, 1e-9 * cell.size));
    far_value = std::max(far_value, z1);
  }
  if (!(far_value > 0)) return false;
  *near_z = near_value;
  *far_z = far_value;
  return true;
}

std::string SerializeOctree(const Octree& octree) {
  std::string out("IBMROCT1", 8);
  Put<uint32_t>(&out, 1);
  Put<uint32_t>(&out, static_cast<uint32_t>(octree.MaxLevel()));
  for (int i = 0; i < 3; ++i) Put<double>(&out, octree.origin[i]);
  Put<double>(&out, octree.size);
  for (const auto& level : octree.levels) Put<uint64_t>(&out, level.size());
  for (const auto& level : octree.levels) {
    for (const OctreeNode& node : level) Put<uint8_t>(&out, static_cast<uint8_t>(node.state));
  }
  return out;
}

Octree DeserializeOctree(const std::string& bytes) {
  if (bytes.size() < 8 || bytes.compare(0, 8, "IBMROCT1") != 0) throw std::runtime_error("not an ibmr octree (magic IBMROCT1 missing)");
  size_t offset = 8;
  if (Get<uint32_t>(bytes, &offset) != 1) throw std::runtime_error("unsupported octree version");
  const uint32_t max_level = Get<uint32_t>(bytes, &offset);
  if (max_level > 15) throw std::runtime_error("octree level " + std::to_string(max_level) + " out of range");
  Octree octree;
  for (int i = 0; i < 3; ++i) octree.origin[i] = Get<double>(bytes, &offset);
  octree.size = Get<double>(bytes, &offset);
  std::vector<uint64_t> counts(max_level + 1);
  for (auto& count : counts) count = Get<uint64_t>(bytes, &offset);
  if (counts[0] != 1) throw std::runtime_error("octree level 0 must hold one node");
  octree.levels.resize(max_level + 1);
  octree.levels[0].push_back(OctreeNode{});
  for (uint32_t level = 0; level <= max_level; ++level) {
    auto& nodes = octree.levels[level];
    if (nodes.size() != counts[level]) {
      throw std::runtime_error("octree level " + std::to_string(level) + " holds " + std::to_string(counts[level]) +
                               " nodes but its parents imply " + std::to_string(nodes.size()));
    }
    for (OctreeNode& node : nodes) {
      const uint8_t state = Get<uint8_t>(bytes, &offset);
      if (state > 2) throw std::runtime_error("octree node state " + std::to_string(state) + " is not 0, 1 or 2");
      node.state = static_cast<NodeState>(state);
      if (node.state != NodeState::kPartial || level == max_level) continue;
      if (level + 1 <= max_level) {
        for (int c = 0; c < 8; ++c) {
          octree.levels[level + 1].push_back(OctreeNode{static_cast<uint16_t>(2 * node.x + (c & 1)),
                                                        static_cast<uint16_t>(2 * node.y + ((c >> 1) & 1)),
                                                        static_cast<uint16_t>(2 * node.z + ((c >> 2) & 1)),
                                                        NodeState::kPartial});
        }
      }
    }
  }
  if (offset != bytes.size()) throw std::runtime_error("octree file has trailing bytes");
  return octree;
}

}  // namespace ibmr
