// Polygon view maps for view-dependent texture mapping (Debevec, Yu & Borshukov, seed 003 §7):
// per face, the training views that see it entirely, each view's direction in the face's local
// frame, and a regular grid over viewing directions holding the nearest of those views. At
// rendering time a desired direction is located in the grid: the grid triangle containing it
// gives at most three views and their barycentric weights (seed 003 §8, Fig. 6).
//
// Local frame (seed 003 Eq. 1, 2): x = y_W x n (x_W when y_W and n are collinear), y = n x x.
// A direction v (unit, from the face centroid toward a camera) maps to
// p = acos(n.v) * (x.v_r, y.v_r) / |v_r| with v_r = (n x v) x n: the arc length from the normal
// laid out in the face's plane. Directions up to the horizon fill the disc of radius pi/2; the
// grid spans [-pi, pi]^2 in `grid` x `grid` samples (sample (i, j) at
// -pi + 2 pi * (i / (grid - 1), j / (grid - 1))), so that views behind the face's plane keep
// their place too: a mesh from real data has normals that are off, and a view on the wrong side
// of a face's normal may see the face well (seed 003 assumes accurate polygons). Views that see
// a face only partly may carry a penalty in the grid's nearest-view choice (BuildGrid): on the
// synthetic ring's true mesh, partly seen views chosen as freely as whole ones cost vdtm 2.4 dB
// held out (34.7 against 37.1 dB without them), on templeRing's surfel mesh leaving them out
// costs 0.8 dB (24.07 against 24.83); a penalty of 0.3 rad gives 36.5 and 24.8.
//
// File texture/view_maps.bin, little-endian:
//   char[8] "IBMRVM02"; uint32 faces; uint32 views; uint32 grid;
//   views x { uint32 name_length; name bytes }            the training view names, in index order
//   faces x { uint16 count; count x { uint16 view; float32 px; float32 py };
//             if count >= 2: grid*grid x uint8 k (index into this face's list, row-major in j) }
// A face seen by no view has count 0 and no grid; by one view, no grid (that view, weight 1).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "pipeline/core/mesh.h"

namespace ibmr {

struct FaceViewMap {
  std::vector<uint16_t> views;                // training views that see the face entirely
  std::vector<Eigen::Vector2f> directions;    // each view's mapped direction p_i
  std::vector<uint8_t> nearest;               // grid*grid, index into views; empty when views.size() < 2
};

struct ViewMaps {
  int grid = 16;
  std::vector<std::string> view_names;
  std::vector<FaceViewMap> faces;
};

// Up to three views and weights summing to 1 (a view may appear once only); count 0 when the
// face is seen by no view.
struct ViewBlend {
  int count = 0;
  std::array<int, 3> views{};        // indices into ViewMaps::view_names
  std::array<float, 3> weights{};
};

// The face's local frame (seed 003 Eq. 1): columns x, y, n.
Eigen::Matrix3d FaceFrame(const Eigen::Vector3d& normal);
// A unit direction mapped into the face's view map plane (seed 003 Eq. 2 and the arc length).
Eigen::Vector2d MapDirection(const Eigen::Matrix3d& frame, const Eigen::Vector3d& direction);
// Fills `nearest` of a face from its views' directions (seed 003 §7, Fig. 6). `penalty` (empty,
// or one per view, in radians of the map plane) counts a view as that much farther from every
// sample than it is: views that see the face only partly are chosen where no whole view is near.
void BuildGrid(int grid, FaceViewMap* face, const std::vector<float>& penalty = {});
// The blend for a desired direction (unit, from the face toward the desired camera).
ViewBlend BlendFor(const ViewMaps& maps, int face, const Eigen::Matrix3d& frame, const Eigen::Vector3d& direction);
// The same blend for the direction already mapped into the plane (MapDirection), for a caller that
// needs the mapped point too.
ViewBlend BlendAt(const ViewMaps& maps, int face, const Eigen::Vector2d& mapped);
// Asks the processor to start fetching what BlendAt(maps, face, mapped) reads (the face's views
// and the two grid rows of its cell), for a caller that walks many faces: the maps of a large
// mesh are hundreds of megabytes, each face's grid cell a miss to memory otherwise.
void PrefetchBlendAt(const ViewMaps& maps, int face, const Eigen::Vector2d& mapped);

void WriteViewMaps(const ViewMaps& maps, const std::string& path);  // atomically; throws IoError
ViewMaps ReadViewMaps(const std::string& path);                     // throws InputError naming the file

}  // namespace ibmr
