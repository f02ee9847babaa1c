// Accuracy and completeness of a point set against a true mesh (Middlebury style: Seitz et al.,
// CVPR 2006): accuracy is the distance from the points to the mesh (uniform grid over triangles,
// exact point-triangle distance) at the 90th percentile; completeness the fraction of points
// sampled uniformly on the true surface that have a point of the set within a threshold (voxel
// hash). A reconstructed mesh is measured through points sampled uniformly on it (SampleSurface).
// Used by fuse (fused points) and surfels (particles and their mesh), and by benchmarks.
#pragma once

#include <limits>

#include <Eigen/Core>
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/mesh.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

// Exact distances to a triangle mesh through a uniform grid of triangles.
class MeshDistance {
 public:
  explicit MeshDistance(const TriangleMesh& mesh);
  ~MeshDistance();
  // Distance from `point` to the mesh, or `max_distance` when it is farther than that.
  double Distance(const Eigen::Vector3d& point, double max_distance) const;

 private:
  struct Grid;
  std::unique_ptr<Grid> grid_;
};

// `count` points uniformly by area on the mesh (seeded, deterministic).
std::vector<Eigen::Vector3f> SampleSurface(const TriangleMesh& mesh, size_t count, uint32_t seed = 1);

// Marks the surface samples that a view sees: in the image, in front, and within
// `relative_tolerance` of its true depth map (nearest pixel).
void MarkVisible(const std::vector<Eigen::Vector3f>& samples, const Camera& camera, const Rigid3d& cam_from_world,
                 const DepthMap& true_depth, double relative_tolerance, std::vector<char>* visible);

struct PointSetAccuracy {
  double accuracy_90 = 0;        // distance to the mesh below which 90% of the points lie
  double accuracy_median = 0;
  double completeness = 0;       // fraction of surface samples with a point of the set within threshold
  double completeness_visible = -1;  // the same among samples some view sees (-1: not computed)
  double threshold = 0;
  size_t points = 0;
  // Spearman's rho between the points' confidence and their distance to the mesh (NaN without
  // confidences): a confidence that means something is negative.
  double confidence_error_spearman = std::numeric_limits<double>::quiet_NaN();
  // Area under the sparsification curve of that confidence (mean distance of the kept points as
  // the least confident are removed) over the optimal one's (pipeline/core/sparsification.h; NaN
  // without confidences): 1 is perfect, larger is worse.
  double sparsification_auc_ratio = std::numeric_limits<double>::quiet_NaN();
};

// `visible` (optional, one flag per sample) restricts completeness_visible to seen samples.
PointSetAccuracy EvaluatePointSet(const PointCloud& cloud, const TriangleMesh& mesh,
                                 const std::vector<Eigen::Vector3f>& surface_samples, double threshold,
                                 const std::vector<char>* visible = nullptr);

// A reconstructed mesh against the true one: `samples` points uniformly on each, accuracy of the
// mesh's samples, completeness of the truth's within 1% of the true mesh's bounding-box diagonal
// (points = 0 when either mesh has no area).
PointSetAccuracy EvaluateMesh(const TriangleMesh& mesh, const TriangleMesh& truth, size_t samples);

// How many of the cloud's points that project into a view (in front of it, inside the image) land
// on its silhouette (`mask` nonzero, nearest pixel): the check that fused points lie on the object
// where no true surface is known (real photographs with silhouettes from the `silhouettes` stage).
struct SilhouetteHits {
  size_t projected = 0;
  size_t on_silhouette = 0;
  double Fraction() const { return projected ? static_cast<double>(on_silhouette) / projected : 0.0; }
};
SilhouetteHits ProjectOntoSilhouette(const PointCloud& cloud, const Camera& camera, const Rigid3d& cam_from_world,
                                     const cv::Mat& mask);

}  // namespace ibmr
