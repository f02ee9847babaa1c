// WriteTexturedGlb: a TexturedMesh as binary glTF 2.0 through tinygltf (Debian's libtinygltf,
// a shared library, so this is the one file that includes the large tiny_gltf.h). Layout: one
// buffer (the GLB BIN chunk) holding, 4-byte aligned, per page with faces the POSITION (with
// min/max), NORMAL (when the mesh has normals), TEXCOORD_0 (v stored as 1 - v, glTF's v points
// down) and uint32 index data, then each page encoded as PNG. glTF attributes are per vertex,
// so every face gets three vertices of its own in its page's primitive. One material per page
// (base colour texture, metallic 0, roughness 1, clamped linear sampling), one mesh with one
// TRIANGLES primitive per page that has faces, one node, one scene. Coordinates are written as
// they are, in the mesh's own frame and units.
#include <tiny_gltf.h>

#include <Eigen/Geometry>
#include <cstring>
#include <limits>
#include <sstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/textured_mesh.h"

namespace ibmr {
namespace {

constexpr int kArrayBuffer = 34962;         // bufferView target of vertex attributes
constexpr int kElementArrayBuffer = 34963;  // bufferView target of indices

// Appends `size` bytes as a new buffer view (4-byte aligned); returns its index.
int AddBufferView(tinygltf::Model* model, const void* data, size_t size, int target) {
  std::vector<unsigned char>& buffer = model->buffers[0].data;
  buffer.resize((buffer.size() + 3) / 4 * 4, 0);
  tinygltf::BufferView view;
  view.buffer = 0;
  view.byteOffset = buffer.size();
  view.byteLength = size;
  view.target = target;
  const auto* bytes = static_cast<const unsigned char*>(data);
  buffer.insert(buffer.end(), bytes, bytes + size);
  model->bufferViews.push_back(view);
  return static_cast<int>(model->bufferViews.size()) - 1;
}

// Adds a float accessor over `values` (`components` floats per element) with its own view.
int AddFloatAccessor(tinygltf::Model* model, const std::vector<float>& values, int components, int type,
                     bool with_bounds) {
  tinygltf::Accessor accessor;
  accessor.bufferView = AddBufferView(model, values.data(), values.size() * sizeof(float), kArrayBuffer);
  accessor.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
  accessor.type = type;
  accessor.count = values.size() / components;
  if (with_bounds) {
    accessor.minValues.assign(components, std::numeric_limits<double>::max());
    accessor.maxValues.assign(components, std::numeric_limits<double>::lowest());
    for (size_t i = 0; i < values.size(); ++i) {
      const size_t c = i % components;
      accessor.minValues[c] = std::min<double>(accessor.minValues[c], values[i]);
      accessor.maxValues[c] = std::max<double>(accessor.maxValues[c], values[i]);
    }
  }
  model->accessors.push_back(accessor);
  return static_cast<int>(model->accessors.size()) - 1;
}

// glTF requires unit normals: a zero normal (a vertex on degenerate faces only) is replaced by
// the face's own normal, or +z when the face is degenerate too.
Eigen::Vector3f UnitNormal(const Eigen::Vector3f& normal, const Eigen::Vector3f& face_normal) {
  if (normal.norm() > 0.f) return normal.normalized();
  if (face_normal.norm() > 0.f) return face_normal.normalized();
  return Eigen::Vector3f::UnitZ();
}

// The TRIANGLES primitive of the faces that sample `page` (three vertices per face).
tinygltf::Primitive PagePrimitive(const TexturedMesh& textured, int page, tinygltf::Model* model) {
  const TriangleMesh& mesh = textured.mesh;
  const bool has_normals = !mesh.normals.empty();
  std::vector<float> positions, normals, texcoords;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    if (textured.face_page[f] != page) continue;
    const Eigen::Vector3i& face = mesh.faces[f];
    const Eigen::Vector3f face_normal =
        (mesh.vertices[face[1]] - mesh.vertices[face[0]]).cross(mesh.vertices[face[2]] - mesh.vertices[face[0]]);
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3f& p = mesh.vertices[face[k]];
      positions.insert(positions.end(), {p.x(), p.y(), p.z()});
      if (has_normals) {
        const Eigen::Vector3f n = UnitNormal(mesh.normals[face[k]], face_normal);
        normals.insert(normals.end(), {n.x(), n.y(), n.z()});
      }
      texcoords.insert(texcoords.end(), {textured.face_uv[f](k, 0), 1.f - textured.face_uv[f](k, 1)});
    }
  }
  std::vector<uint32_t> indices(positions.size() / 3);
  for (size_t i = 0; i < indices.size(); ++i) indices[i] = static_cast<uint32_t>(i);

  tinygltf::Primitive primitive;
  primitive.mode = TINYGLTF_MODE_TRIANGLES;
  primitive.material = page;
  primitive.attributes["POSITION"] = AddFloatAccessor(model, positions, 3, TINYGLTF_TYPE_VEC3, true);
  if (has_normals) primitive.attributes["NORMAL"] = AddFloatAccessor(model, normals, 3, TINYGLTF_TYPE_VEC3, false);
  primitive.attributes["TEXCOORD_0"] = AddFloatAccessor(model, texcoords, 2, TINYGLTF_TYPE_VEC2, false);
  tinygltf::Accessor index_accessor;
  index_accessor.bufferView =
      AddBufferView(model, indices.data(), indices.size() * sizeof(uint32_t), kElementArrayBuffer);
  index_accessor.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;
  index_accessor.type = TINYGLTF_TYPE_SCALAR;
  index_accessor.count = indices.size();
  model->accessors.push_back(index_accessor);
  primitive.indices = static_cast<int>(model->accessors.size()) - 1;
  return primitive;
}

// Image, texture and material of `page` (all with index `page`), the PNG in the buffer.
void AddPageMaterial(const cv::Mat& image, int page, const std::string& path, tinygltf::Model* model) {
  // The pages (8-bit BGR) are encoded as WriteImage writes their files (RGB colours in the file).
  std::string png;
  try {
    png = EncodePngBytes(image);
  } catch (const IoError& e) {
    throw IoError("cannot write " + path + ": encoding atlas page " + std::to_string(page) + " as PNG failed: " + e.what());
  }

  const std::string name = "atlas_" + std::to_string(page);
  tinygltf::Image gltf_image;
  gltf_image.name = name;
  gltf_image.mimeType = "image/png";
  gltf_image.bufferView = AddBufferView(model, png.data(), png.size(), 0);
  model->images.push_back(gltf_image);

  tinygltf::Texture texture;
  texture.name = name;
  texture.sampler = 0;
  texture.source = page;
  model->textures.push_back(texture);

  tinygltf::Material material;
  material.name = name;
  material.pbrMetallicRoughness.baseColorTexture.index = page;
  material.pbrMetallicRoughness.metallicFactor = 0.0;
  material.pbrMetallicRoughness.roughnessFactor = 1.0;
  model->materials.push_back(material);
}

}  // namespace

void WriteTexturedGlb(const TexturedMesh& mesh, const std::string& path) {
  const std::string problem = mesh.Validate();
  if (!problem.empty()) throw IoError("cannot write " + path + ": the textured mesh is inconsistent: " + problem);

  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "ibmr";
  model.buffers.emplace_back();

  // Atlas texels are not meant to repeat: clamp at the page border.
  tinygltf::Sampler sampler;
  sampler.magFilter = TINYGLTF_TEXTURE_FILTER_LINEAR;
  sampler.minFilter = TINYGLTF_TEXTURE_FILTER_LINEAR_MIPMAP_LINEAR;
  sampler.wrapS = TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
  sampler.wrapT = TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE;
  model.samplers.push_back(sampler);

  // Geometry first, then the images, so that the vertex data sits at the start of the buffer.
  std::vector<bool> page_used(mesh.pages.size(), false);
  for (int page : mesh.face_page) page_used[page] = true;
  tinygltf::Mesh gltf_mesh;
  gltf_mesh.name = "textured_mesh";
  for (size_t page = 0; page < mesh.pages.size(); ++page) {
    if (page_used[page]) gltf_mesh.primitives.push_back(PagePrimitive(mesh, static_cast<int>(page), &model));
  }
  for (size_t page = 0; page < mesh.pages.size(); ++page) {
    AddPageMaterial(mesh.pages[page], static_cast<int>(page), path, &model);
  }

  tinygltf::Scene scene;
  if (!gltf_mesh.primitives.empty()) {  // glTF forbids a mesh without primitives
    model.meshes.push_back(gltf_mesh);
    tinygltf::Node node;
    node.mesh = 0;
    model.nodes.push_back(node);
    scene.nodes.push_back(0);
  }
  model.scenes.push_back(scene);
  model.defaultScene = 0;

  std::ostringstream stream;
  tinygltf::TinyGLTF writer;
  if (!writer.WriteGltfSceneToStream(&model, stream, /*prettyPrint=*/false, /*writeBinary=*/true) || !stream) {
    throw IoError("cannot write " + path + ": tinygltf failed to serialise the model");
  }
  WriteFileAtomic(path, stream.str());
}

}  // namespace ibmr
