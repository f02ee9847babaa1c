// A triangle mesh with a texture atlas: per-corner texture coordinates (a vertex on a patch
// border has one per patch), the atlas page each face samples, and the pages as images. What the
// texture stage writes and the textured / vdtm renderers read.
//
// Files (texture/): mesh.obj + mesh.mtl + atlas_<page>.png, as Wavefront OBJ/MTL (one material
// per page, `usemtl atlas_<page>`, `map_Kd atlas_<page>.png`), and mesh.glb (binary glTF 2.0, one
// primitive per page, the page embedded as PNG). UV convention in memory and in OBJ: u to the
// right and v up, both in [0, 1] over the page, texel (c, r) of a page H rows high centred at
// ((c + 0.5) / W, 1 - (r + 0.5) / H). glTF's v points down: the writer stores 1 - v.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/mesh.h"

namespace ibmr {

struct TexturedMesh {
  TriangleMesh mesh;                               // vertices, faces, optional normals
  std::vector<Eigen::Matrix<float, 3, 2>> face_uv;  // one per face: row k = (u, v) of corner k
  std::vector<int> face_page;                       // one per face: index into pages
  std::vector<cv::Mat> pages;                       // CV_8UC3 (BGR), the atlas pages

  // Empty when consistent; otherwise what is wrong (sizes, a page index out of range, a UV
  // outside [0, 1], an empty page).
  std::string Validate() const;
};

// Texel position (x right, y down, in pixels, continuous: texel centres at +0.5) of a UV on a
// page of the given size, and back.
inline Eigen::Vector2f TexelFromUv(const Eigen::Vector2f& uv, int width, int height) {
  return {uv.x() * width, (1.f - uv.y()) * height};
}
inline Eigen::Vector2f UvFromTexel(const Eigen::Vector2f& texel, int width, int height) {
  return {texel.x() / width, 1.f - texel.y() / height};
}

// Writes FOLDER/STEM.obj, FOLDER/STEM.mtl and FOLDER/atlas_<page>.png (each atomically).
// Throws IoError.
void WriteTexturedObj(const TexturedMesh& mesh, const std::string& folder, const std::string& stem);
// Reads what WriteTexturedObj wrote (triangles, `vt` per corner, materials with map_Kd). Throws
// InputError naming the file and line for anything it cannot read.
TexturedMesh ReadTexturedObj(const std::string& obj_path);
// Writes a binary glTF 2.0 file (tinygltf) with positions, normals when present, TEXCOORD_0 and
// the pages embedded as PNG images. Throws IoError.
void WriteTexturedGlb(const TexturedMesh& mesh, const std::string& path);

}  // namespace ibmr
