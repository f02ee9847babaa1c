// The texture atlas: patches of faces that take their colour from the same view, cut out of that
// view's image with a margin, packed into pages, and the faces no view sees filled from their
// neighbours (seed 003 §6, object-space hole filling).
//
// A patch is a connected set of faces (sharing edges) with one label. Its rectangle is the
// bounding box of its faces' projections into the label's image plus `padding` pixels on every
// side; the rectangle is copied whole, so the texels around the faces are the image's own
// neighbouring pixels (edge bleeding that bilinear and mipmapped sampling cannot tell from the
// surface). A patch wider or higher than a page is scaled down to fit. Rectangles are packed in
// shelves, tallest first, into pages at most max_texture_size texels on a side.
//
// Faces no view sees (seed 003 §6): a colour per face, taken iteratively from the neighbours
// already coloured (first the seen faces' mean colours in their views), mid-grey where a
// connected part has no seen face at all; each such face gets a hole_cell x hole_cell cell of that
// colour (seed 003 interpolates vertex colours with Gouraud shading; a constant per face is the
// simplification here).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <opencv2/core.hpp>
#include <vector>

#include "pipeline/core/camera.h"
#include "pipeline/core/rigid3.h"
#include "pipeline/core/textured_mesh.h"
#include "stages/texture/color_leveling.h"
#include "stages/texture/face_visibility.h"
#include "stages/texture/texture_options.h"

namespace ibmr {

struct AtlasPatch {
  int label = -1;            // the view; -1: a block of hole cells
  std::vector<int> faces;
  Eigen::Vector2d image_min = Eigen::Vector2d::Zero();  // the rectangle's corner in the view's image, pixels
  double scale = 1;          // texels per image pixel
  int page = 0, x = 0, y = 0, width = 0, height = 0;   // where it lies in its page, texels
};

struct AtlasLayout {
  std::vector<AtlasPatch> patches;
  std::vector<cv::Size> page_sizes;
  size_t hole_faces = 0;
};

struct TextureView {
  Camera camera;  // pinhole, the image's size
  Rigid3d cam_from_world;
};

// Patches, their rectangles and pages; fills `out`'s UVs and face pages and allocates its pages
// (black). `labels` from SelectViews.
AtlasLayout LayoutAtlas(const TriangleMesh& mesh, const std::vector<int>& labels,
                        const std::vector<std::array<int, 3>>& adjacency, const std::vector<TextureView>& views,
                        const TextureOptions& options, TexturedMesh* out);

// Copies the patches of view `view` from its image (CV_8UC3), multiplied by `gain`. Patches of
// different views may be copied in parallel.
void CopyPatches(const AtlasLayout& layout, int view, const cv::Mat& image, double gain, TexturedMesh* out);

// Adds the solved offsets to the texels of every labelled face (and the padding around it).
void ApplyLeveling(const AtlasLayout& layout, const SeamLeveling& leveling, int padding, TexturedMesh* out);

// Paints the hole cells (seed 003 §6) from the seen faces' colours; returns the faces that had
// no coloured neighbour in their connected part (painted grey).
size_t FillHoles(const AtlasLayout& layout, const std::vector<int>& labels, const FaceObservations& observations,
                 const std::vector<double>& gains, const std::vector<std::array<int, 3>>& adjacency, TexturedMesh* out);

// The colour step across the seams as the atlas holds it: for each edge between faces of
// different labels, the atlas colours (bilinear) of the two faces at the same points of the
// shared edge (a quarter, half and three quarters along it), their absolute difference averaged
// over the channels; the mean over those points (0 without seams). What leveling is for,
// measured on its output.
double SeamStepInAtlas(const TexturedMesh& textured, const std::vector<int>& labels,
                       const std::vector<std::array<int, 3>>& adjacency);

}  // namespace ibmr
