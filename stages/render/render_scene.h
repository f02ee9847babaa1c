// What every render model of a run shares (render_model.h): the training views' photos, the
// sparse points and ULR's options (RenderScene), and the desired views to draw, read once by the
// render stage (render_stage.cc) from the workspace.
#pragma once

#include <Eigen/Core>
#include <set>
#include <string>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/params.h"
#include "pipeline/core/rigid3.h"
#include "pipeline/core/sparse_model.h"
#include "pipeline/core/stage_api.h"
#include "stages/render/render.h"

namespace ibmr {

// What every model of a run shares, built once by the stage before the first model.
struct RenderScene {
  const StageContext* context = nullptr;     // workspace, params
  const SparseModel* model = nullptr;
  std::vector<std::string> training;         // source views (held-out ones never are), model order
  std::vector<SourceView> sources;           // their photos, without a proxy depth
  RenderOptions options;                     // ULR's, and the visibility tolerance and hole extension
  std::vector<Eigen::Vector3d> sparse_points;  // finite sparse points seen by a training view
  Eigen::Vector3d axes_point = Eigen::Vector3d::Zero();  // nearest to the training optical axes
  bool have_axes_point = false;
  bool exclude_self = true;                  // leave-one-out for training views among the desired ones
  int factor = 1;                            // supersampling: sub-samples per pixel side

  // True when a plane proxy can be placed (sparse points, or optical axes that meet).
  bool PlanePossible() const { return !sparse_points.empty() || have_axes_point; }
  // Index of the training view named `name` among the sources, -1 when it is none or exclude_self
  // is off: the source a leave-one-out render never uses.
  int SelfSource(const std::string& name) const;
  // `all` without the view `name`'s own photo when exclude_self applies to it (into `own`), else
  // `all` itself (no copy of its pixels or depth maps).
  const std::vector<SourceView>* SourcesWithout(const std::vector<SourceView>& all, const std::string& name,
                                                std::vector<SourceView>* own) const;
};

// A desired view: a photographed view (held out, or listed in `views`) or the novel camera.
struct DesiredView {
  std::string name, stem;
  Camera camera;           // at the output size
  Rigid3d cam_from_world;
};

// ULR's options from the stage's keys (k, alpha, ..., visibility_epsilon, proxy_extend_px).
RenderOptions ToRenderOptions(const Params& params);

// The scene of `model`: the training views (those not held out) with their photos, which must be
// undistorted and of their cameras' size (InputError otherwise), the finite sparse points a
// training view sees and the point nearest to their optical axes; the options from the params.
void LoadRenderScene(const StageContext& context, const SparseModel& model, RenderScene* scene);

// The views to draw: `photo_views` (images of `model`) and the novel camera of `novel_look_at`,
// less those outside `shard` when it is not empty. Throws InputError for an unknown image, two
// views with one file stem (their files would collide) or a shard view that is none of them.
std::vector<DesiredView> DesiredViews(const StageContext& context, const SparseModel& model, const RenderScene& scene,
                                      const std::vector<std::string>& photo_views, const std::set<std::string>& shard);

}  // namespace ibmr
