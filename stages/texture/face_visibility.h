// Which faces a view sees, and how well (seed 003 §5 visibility preprocessing; seed 000 §6 lines
// 4587-4654: z-buffer visibility, cosine weighting).
//
// A view sees a face when the face is in front of the camera and seen at an angle whose cosine,
// on either side of the face, is at least min_cos_angle, its three vertices project inside the image, and its vertices and
// centroid, pulled 5% toward the centroid, pass the z-buffer of the whole mesh within
// visibility_epsilon of their depth: seed 003 samples points of each polygon against an item
// buffer. Faces partly or wholly hidden are not split as seed 003 splits them: they are marked
// `partial` (a sample hidden) and `hidden` (the centroid hidden), kept out of the atlas (which
// never maps an occluder's pixels onto a face), and kept in the view maps, where the renderer's
// per-pixel depth test against each source's view of the mesh takes the place of the split (on
// templeRing's surfel mesh, whose bumps hide parts of many faces from their best views, lists of
// wholly seen views cost vdtm 0.5 dB against ULR, which tests every source per pixel).
//
// Quality (the view selection's data term) follows Waechter et al.'s gradient magnitude integral:
// the sum over the face's pixels in the item buffer of (1 + gradient magnitude / 32), so larger,
// sharper, less oblique projections win (the projected area carries the cosine weighting of seed
// 000 §6). A face smaller than a pixel gets its projected area in pixels.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rigid3.h"
#include "stages/texture/texture_options.h"

namespace ibmr {

// One view's observation of one face.
struct FaceObservation {
  int view = 0;
  float quality = 0;
  Eigen::Vector3f mean_color = Eigen::Vector3f::Zero();  // BGR, over the face's pixels (or its centroid)
  bool back = false;  // the view sees the face's back (its winding is the wrong way round, or the view is wrong)
  bool partial = false;  // a corner is hidden: for the view maps only
  bool hidden = false;   // the centroid is hidden (the face is behind other parts of the mesh): view maps only

  // The view sees the whole face from its front: the atlas takes only these; the view maps prefer them.
  bool SeesWhole() const { return !partial && !hidden && !back; }
};

// Per face: the views that see it entirely, in view order.
using FaceObservations = std::vector<std::vector<FaceObservation>>;

// Face centroids and unit normals (zero for degenerate faces, which no view sees).
struct FaceGeometry {
  std::vector<Eigen::Vector3d> centroids;
  std::vector<Eigen::Vector3d> normals;
  static FaceGeometry Of(const TriangleMesh& mesh);
};

// The faces `image` (CV_8UC3, the camera's size) sees entirely or partly (see above), with their quality and mean colour,
// appended to `observations` (sized to the faces) under index `view`. Not thread-safe for the
// same `observations`; run views in parallel into separate lists and merge.
void ObserveView(const TriangleMesh& mesh, const FaceGeometry& geometry, const Camera& camera,
                 const Rigid3d& cam_from_world, const cv::Mat& image, int view, const TextureOptions& options,
                 std::vector<std::pair<int, FaceObservation>>* seen);

// Turns each face toward the views that see it (its unhidden observations): a face seen mostly
// from its back is flipped (the mesh's winding and the geometry's normal), and the observations'
// `back` flags follow; the atlas then leaves out the views still behind the face
// (meshes from real data, e.g. the surfel mesh, have some faces wound the wrong way; their
// normals would otherwise point away from every view that sees them). Returns the flipped faces.
size_t OrientFaces(FaceObservations* observations, TriangleMesh* mesh, FaceGeometry* geometry);

// Photo-consistency (Waechter et al. 2014 §4.1 remove views that disagree with the others): a face
// seen by three or more views drops those whose mean luminance differs from the median of its
// views by more than max(20 levels, tolerance * median), e.g. a view where the face's pixels are
// the background because the mesh is larger than the object, or where an occluder the mesh lacks
// is in front. Returns the observations removed.
size_t RemoveInconsistentViews(double tolerance, FaceObservations* observations);

}  // namespace ibmr
