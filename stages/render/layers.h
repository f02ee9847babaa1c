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
  // `sets` in memory, sprites included.
  LayersRenderer(std::vector<LayerSet> sets, int references, const Eigen::Vector3d& scene_centre);
  // `headers`: each set as ReadLayerSet gives it, without its sprites and residual depth (the
  // planes, camera and pose choose the references); a set's files are read again from
  // `folders[i]` each time a desired view is drawn from it. The full-size Sceaux castle's nine
  // sets hold 1.7 GB of sprites, of which a view uses two.
  LayersRenderer(std::vector<LayerSet> headers, std::vector<std::string> folders, int references,
                 const Eigen::Vector3d& scene_centre);
  // At the camera's size: colour (not premultiplied) and coverage 255 where alpha >= 0.5.
  // `exclude_image` non-empty: the reference set of that image is never used (leave-one-out: a
  // training view rendered without its own layers, which reproduce its photo at angle 0).
  // Throws InputError or IoError (naming the file) when a set read from its folder is unreadable.
  RenderResult Render(const Camera& camera, const Rigid3d& cam_from_world, const std::string& exclude_image = {}) const;
  size_t Sets() const { return sets_.size(); }
  bool HasSet(const std::string& image) const;
  size_t Layers() const;

 private:
  std::vector<LayerSet> sets_;       // whole, or headers when folders_ is not empty
  std::vector<std::string> folders_;
  int references_;
  Eigen::Vector3d centre_;
};

}  // namespace ibmr
