// Renderer `layers`: the layered_stereo stage's sprites with depth (pipeline/core/layered_sprites.h;
// seed 000 lines 5625-5811 for the layers, 12080-12355 for drawing sprites with depth) seen from a
// desired view. The reference views nearest the desired one in viewing direction (the `references`
// smallest angles between the rays to the scene centre) each composite their layers back to front
// (CompositeLayers); where several cover a pixel their colours blend with weights 1 / angle^2 (the
// angle softened by 0.5 degrees), so that the nearest reference dominates as in ULR (seed 001), and
// the pixel's alpha is the largest of theirs. With exclude_self, a training view being rendered does
// not use its own reference set.
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

#include "pipeline/core/layered_sprites.h"
#include "stages/render/render.h"

namespace ibmr {

class LayersRenderer {
 public:
  // `scene_centre`: the point the desired views look at (angles between rays to it).
  LayersRenderer(std::vector<LayerSet> sets, int references, const Eigen::Vector3d& scene_centre);
  // At the camera's size: colour (not premultiplied) and coverage 255 where alpha >= 0.5.
  // `exclude_image` non-empty: the reference set of that image is never used (leave-one-out: a
  // training view rendered without its own layers, which reproduce its photo at angle 0).
  RenderResult Render(const Camera& camera, const Rigid3d& cam_from_world, const std::string& exclude_image = {}) const;
  size_t Sets() const { return sets_.size(); }
  bool HasSet(const std::string& image) const;
  size_t Layers() const;

 private:
  std::vector<LayerSet> sets_;
  int references_;
  Eigen::Vector3d centre_;
};

}  // namespace ibmr
