// Octree visual-hull carving from silhouettes. Follows seed 000, Szeliski's "Rapid octree
// construction from image sequences" as summarised in section 2 of the course paper (lines
// 4136-4258; slides 3895-3920): the octree is refined coarse to fine, one level at a time over all
// views ("the octree is completely constructed at one resolution before refining the next one");
// each cube is tested by "a bounding box for the eight projected corners" against "a distance map
// [that] provides the minimum distance from any image point to the silhouette", so the test is O(1)
// instead of O(s) per cube. The Lumigraph (lines 14700-14740) uses the same octree as a
// conservative geometric proxy: its external polygons, smoothed, enclose the object.
//
// The O(1) test: per view, two chessboard (L-infinity) distance maps from cv::distanceTransform:
// to the nearest silhouette pixel and to the nearest background pixel. The projected cube's pixel
// bounding box is covered by at most a few odd-sided squares (side = its shorter side); a square
// of radius k around pixel p is all background when dist_to_silhouette(p) > k, all silhouette when
// dist_to_background(p) > k. This is exactly the "any silhouette pixel in the bounding box" test,
// so the octree equals the brute-force per-voxel bounding-box test (CarveBruteForce).
//
// Per view, a cube is:
//   empty    its bounding box is all background (out-of-image parts count as background only when
//            the view's outside is known empty), or it lies entirely behind a camera whose outside
//            is known empty;
//   full     its in-image bounding box is all silhouette and (when the outside is known empty) lies
//            inside the image;
//   unknown  it projects entirely out of the image (or behind) a view whose outside is unknown;
//   partial  otherwise (mixed, straddling the image border, or straddling the camera plane).
// Outside the image is "unknown", not "empty", for a view whose silhouette touches the image
// border (the object may extend out of view); for the others it is empty (the whole object is in
// view). A cube is empty when any view says empty; full when every view says full or unknown and
// one says full; unseen (kept as full, counted) when every view says unknown; else partial, and
// subdivided at the next level. Partial leaves of the finest level are decided by `leaf_test`:
//   centre (default)  the leaf is kept when its centre projects into every silhouette (one of the
//                     2x2 pixels around the projection is silhouette; outside an
//                     image: kept unless that view's outside is known empty), the textbook visual
//                     hull on the finest grid; coarser full and empty nodes agree with it, since every
//                     centre below a full node lies in every silhouette and every centre below an
//                     empty node lies in some view's background. The hull mesh is the boundary of
//                     these cells dilated by one cell, so it still encloses the conservative hull
//                     except where the object is thinner than a cell.
//   box               every partial leaf is kept: the hull is conservative, it contains the visual
//                     hull of the silhouettes (and is up to one cell fatter).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/progress.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

enum class OutsideImage { kAuto, kUnknown, kEmpty };
enum class LeafTest { kCentre, kBox };

struct CarveOptions {
  int levels = 7;                      // finest octree level (root cube = level 0), in [1, 10]
  OutsideImage outside = OutsideImage::kAuto;  // auto: empty unless the silhouette touches the border
  LeafTest leaf_test = LeafTest::kCentre;      // how partial leaves of the finest level are decided
  // Mesh: boundary faces of the hull dilated by one cell, then Taubin lambda|mu smoothing (the
  // Lumigraph's "Taubin's polyhedral smoothing") with each vertex kept within
  // `max_displacement` cells of its start, so the undilated hull stays inside the mesh.
  int smooth_iterations = 10;          // lambda|mu pairs, in [0, 1000]
  double smooth_lambda = 0.5;          // in (0, 1)
  double smooth_mu = -0.53;            // in (-1, 0), |mu| > lambda
  double max_displacement = 0.5;       // cells, in [0, 1)
  int max_mesh_level = 8;              // mesh at min(level, this); dense grid of 8^level bytes, in [1, 9]
  int mesh_dilation = 1;               // cells the hull is dilated by before meshing, in [0, 2]: 1 keeps the
                                       // whole hull inside the smoothed mesh; 0 fits the silhouettes
                                       // closer, cutting partial cells by at most max_displacement
  bool mesh_at_finest = false;         // mesh at the finest level instead of the chosen one
  double level_tolerance = 0.005;      // held-out IoU tolerance of the automatic level choice, in [0, 1]

  // Returns false and sets `error` (starting with the YAML key) when a value is out of range.
  bool Check(std::string* error) const;
};

// One view as carving sees it.
struct CarveView {
  std::string name;
  Camera camera;
  Rigid3d cam_from_world;
  cv::Mat mask;  // CV_8UC1, 0 background, nonzero silhouette, camera.width x camera.height
};

enum class NodeState : uint8_t { kEmpty = 0, kFull = 1, kPartial = 2 };

// A node at level l: integer cell coordinates in [0, 2^l)^3 of the root cube.
struct OctreeNode {
  uint16_t x = 0, y = 0, z = 0;
  NodeState state = NodeState::kPartial;
};

// Linear octree: levels[l] holds every node evaluated at level l; the children of the partial
// nodes of level l (in order, 8 each, child index = dx | dy << 1 | dz << 2) make up level l + 1.
struct Octree {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  // min corner of the root cube, world units
  double size = 1.0;                                 // root cube side, world units
  std::vector<std::vector<OctreeNode>> levels;
  // With LeafTest::kCentre, per level, per node: 1 when the node is partial and its centre passes
  // the centre test, so that a coarser level's hull can be cut by the same rule as the finest one
  // (the held-out level choice compares like with like). Empty per level when not computed (box
  // test, or an octree read from a file): partial nodes then count as kept.
  std::vector<std::vector<uint8_t>> centre_kept;

  int MaxLevel() const { return static_cast<int>(levels.size()) - 1; }
  double CellSize(int level) const { return size / static_cast<double>(1 << level); }
  Eigen::Vector3d CellMin(int level, const OctreeNode& node) const {
    return origin + CellSize(level) * Eigen::Vector3d(node.x, node.y, node.z);
  }
};

// An axis-aligned cell of the hull: level and its min corner / size in world units.
struct HullCell {
  Eigen::Vector3d min = Eigen::Vector3d::Zero();
  double size = 0.0;
  // The faces not shared with the hull (bit 2a: the face at min along axis a, bit 2a+1: at
  // min + size); all six unless SurfaceHullCells found the neighbours.
  uint8_t open_faces = 0x3f;
};

// The hull at `level` (<= MaxLevel): full nodes of levels <= level and partial nodes of `level`
// (only those whose centre passes the centre test, when Octree::centre_kept holds that level).
std::vector<HullCell> HullCells(const Octree& octree, int level);
// The same cells less those whose six neighbours across their faces all belong to the hull, each
// with its open faces: what a view sees of the hull, since a line of sight from outside reaches an
// inner cell only through a surface one, entering by an open face that faces the camera
// (ProjectHullSurface draws the same silhouette from these, several times faster). At levels above
// 8 (a dense grid of more than 16 M cells) every cell is returned, all faces open.
std::vector<HullCell> SurfaceHullCells(const Octree& octree, int level);

struct LevelStats {
  int level = 0;
  size_t nodes = 0, empty = 0, full = 0, partial = 0, unseen = 0;
  // Finest level with LeafTest::kCentre: partial leaves decided by their centre (counted in
  // `full` / `empty` too; `partial` is then 0).
  size_t leaves_kept_by_centre = 0, leaves_dropped_by_centre = 0;
  double seconds = 0.0;
};

struct CarveResult {
  Octree octree;
  std::vector<LevelStats> stats;           // one per level
  std::vector<std::string> views_not_seeing_volume;  // views for which every root cell was unknown
  std::vector<bool> outside_empty;         // per view: out-of-image treated as empty
};

// Carves the root cube (min corner `origin`, side `size`) from the views' silhouettes. Throws
// std::invalid_argument naming the view when a mask does not match its camera's size.
CarveResult CarveOctree(const std::vector<CarveView>& views, const Eigen::Vector3d& origin, double size,
                        const CarveOptions& options, ProgressReporter* progress = nullptr);

// Brute force on the level-`level` grid of the same root cube: for every cell, the same per-view
// bounding-box test scanning every pixel. Returns a dense grid (x fastest), 1 = kept.
std::vector<uint8_t> CarveBruteForce(const std::vector<CarveView>& views, const std::vector<bool>& outside_empty,
                                     const Eigen::Vector3d& origin, double size, int level);

// Dense occupancy (x fastest, 2^level per side) of the hull at `level`.
std::vector<uint8_t> DenseHull(const Octree& octree, int level);

// The silhouette of the hull cells in a view: pixels whose centre lies in the projection of a cell
// (each cell drawn as the convex hull of its 8 projected corners). Cells none of whose open faces
// faces the camera are skipped: a line of sight meets them only after a cell that has one. CV_8UC1 0/255.
cv::Mat ProjectHull(const std::vector<HullCell>& cells, const Camera& camera, const Rigid3d& cam_from_world);
// The hull's silhouette at `level` from its surface cells (SurfaceHullCells(octree, level)): the
// same mask as ProjectHull of every cell when the whole root cube is in front of the camera and
// projects within reach (then no cell is left undrawn, and a line of sight meets an inner cell only
// after a surface one); otherwise, a camera near or inside the volume, drawn from every cell.
cv::Mat ProjectHullSurface(const Octree& octree, int level, const std::vector<HullCell>& surface, const Camera& camera,
                           const Rigid3d& cam_from_world);

// Intersection over union of two masks' nonzero pixels (1 when both are empty).
double MaskIou(const cv::Mat& a, const cv::Mat& b);

// Near and far z (along the optical axis) of the hull cells seen in a view; false when no cell
// projects into the image in front of the camera.
bool HullDepthBounds(const std::vector<HullCell>& cells, const Camera& camera, const Rigid3d& cam_from_world,
                     double* near_z, double* far_z);

struct HullMeshStats {
  size_t boundary_quads = 0;
  size_t duplicated_vertices = 0;  // vertices split where the voxel surface is not manifold
  double max_displacement = 0.0;   // world units, after clamping
};

// Watertight boundary (quads split into triangles, counter-clockwise outside) of the hull at
// `level` dilated by one cell, smoothed in OpenMesh (Taubin lambda|mu, displacement clamped).
// Header comment "ibmr conservative_hull 1".
TriangleMesh HullMesh(const Octree& octree, int level, const CarveOptions& options, HullMeshStats* stats = nullptr);

// hull/octree.bin, little-endian:
//   char[8]  magic "IBMROCT1"
//   uint32   version (1)
//   uint32   L, the finest level (levels 0..L follow)
//   float64  origin x, y, z (min corner of the root cube, world units), float64 size (cube side)
//   uint64   node count of each level 0..L (L + 1 values)
//   then for each level 0..L, its nodes in order: uint8 state (0 empty, 1 full, 2 partial).
// Level 0 is the root cube; the 8 children of the k-th partial node of level l are nodes
// 8k..8k+7 of level l + 1, child index i = dx + 2 dy + 4 dz (dx, dy, dz in {0, 1}): cell
// coordinates (2x + dx, 2y + dy, 2z + dz). Cell (x, y, z) of level l spans
// origin + size / 2^l * [x, x+1) x [y, y+1) x [z, z+1).
std::string SerializeOctree(const Octree& octree);
// Throws std::runtime_error saying what is wrong with the bytes.
Octree DeserializeOctree(const std::string& bytes);

}  // namespace ibmr
