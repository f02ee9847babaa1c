// The report viewer's data (see report_viewer.h): each model read, made small enough for the
// page and turned into typed arrays; the cameras as frustum directions; the volume's planes.
#include "pipeline/runner/report_viewer.h"

#include "pipeline/core/gaussian_splats.h"
#include "pipeline/core/plane_volume.h"

#include <tiny_gltf.h>

#include <opencv2/imgproc.hpp>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cstring>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>
#include <tuple>
#include <unordered_map>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/view_agreement.h"
#include "pipeline/core/workspace.h"
#include "pipeline/runner/report_encoding.h"
#include "pipeline/runner/viewer_geometry.h"

namespace fs = std::filesystem;

namespace ibmr {

bool ViewerOptions::Check(std::string* error) const {
  const auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (max_faces <= 0) return fail("report.max_faces = " + std::to_string(max_faces) + ": must be > 0");
  if (max_points <= 0) return fail("report.max_points = " + std::to_string(max_points) + ": must be > 0");
  if (max_texture_size < 16 || max_texture_size > 16384) {
    return fail("report.max_texture_size = " + std::to_string(max_texture_size) + ": must be in [16, 16384]");
  }
  if (max_plane_size < 16 || max_plane_size > 16384) {
    return fail("report.max_plane_size = " + std::to_string(max_plane_size) + ": must be in [16, 16384]");
  }
  return true;
}

namespace {

// Collects the arrays of the models as they are gathered, each under a fresh element id.
class ArraySink {
 public:
  explicit ArraySink(std::vector<std::pair<std::string, std::string>>* arrays) : arrays_(arrays) {}
  template <typename T>
  std::string Add(const std::vector<T>& values) {
    const std::string id = "viewer-array-" + std::to_string(arrays_->size());
    arrays_->emplace_back(id, Base64(values.data(), values.size() * sizeof(T)));
    return id;
  }

 private:
  std::vector<std::pair<std::string, std::string>>* arrays_;
};

// The robust extent of a set of points: per axis the 2nd and 98th percentiles (stray fused points
// far from the object do not set the view), as {"center": [x, y, z], "radius": r}.
nlohmann::json RobustBounds(std::vector<Eigen::Vector3f> points) {
  if (points.empty()) return nullptr;
  Eigen::Vector3f lo, hi;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<float> values(points.size());
    for (size_t i = 0; i < points.size(); ++i) values[i] = points[i][axis];
    const size_t a = values.size() * 2 / 100, b = std::max(a, (values.size() - 1) * 98 / 100);
    std::nth_element(values.begin(), values.begin() + a, values.end());
    lo[axis] = values[a];
    std::nth_element(values.begin(), values.begin() + b, values.end());
    hi[axis] = values[b];
  }
  const Eigen::Vector3f center = (lo + hi) / 2;
  return {{"center", {center.x(), center.y(), center.z()}}, {"radius", std::max((hi - lo).norm() / 2, 1e-6f)}};
}

// Flattens xyz / rgb / uv vectors into the typed arrays the page reads.
std::vector<float> Flat(const std::vector<Eigen::Vector3f>& v) {
  std::vector<float> out;
  out.reserve(3 * v.size());
  for (const auto& p : v) out.insert(out.end(), {p.x(), p.y(), p.z()});
  return out;
}
std::vector<float> Flat(const std::vector<Eigen::Vector2f>& v) {
  std::vector<float> out;
  out.reserve(2 * v.size());
  for (const auto& p : v) out.insert(out.end(), {p.x(), p.y()});
  return out;
}
std::vector<uint8_t> Flat(const std::vector<Color3u8>& v) {
  std::vector<uint8_t> out;
  out.reserve(3 * v.size());
  for (const auto& c : v) out.insert(out.end(), {c[0], c[1], c[2]});
  return out;
}
std::vector<uint32_t> Flat(const std::vector<Eigen::Vector3i>& faces) {
  std::vector<uint32_t> out;
  out.reserve(3 * faces.size());
  for (const auto& f : faces) out.insert(out.end(), {static_cast<uint32_t>(f[0]), static_cast<uint32_t>(f[1]), static_cast<uint32_t>(f[2])});
  return out;
}

// The faces of `mesh` on page `page` (all faces when page < 0) with only the vertices they use.
ViewerMesh PagePart(const ViewerMesh& mesh, int page) {
  ViewerMesh part;
  std::vector<int> renumbered(mesh.vertices.size(), -1);
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    if (page >= 0 && mesh.face_page[f] != page) continue;
    Eigen::Vector3i face;
    for (int corner = 0; corner < 3; ++corner) {
      int& index = renumbered[mesh.faces[f][corner]];
      if (index < 0) {
        index = static_cast<int>(part.vertices.size());
        part.vertices.push_back(mesh.vertices[mesh.faces[f][corner]]);
        if (!mesh.colors.empty()) part.colors.push_back(mesh.colors[mesh.faces[f][corner]]);
        if (!mesh.uvs.empty()) part.uvs.push_back(mesh.uvs[mesh.faces[f][corner]]);
      }
      face[corner] = index;
    }
    part.faces.push_back(face);
  }
  return part;
}

// The model entry of a mesh (decimated to the budget), its arrays added to `sink`: one part per
// texture page (`pages`, BGR) or a single part when there are none.
nlohmann::json MeshEntry(const ViewerMesh& mesh, const std::vector<cv::Mat>& pages, const ViewerOptions& options,
                         ArraySink* sink) {
  const ViewerMesh shown = ClusterDecimate(mesh, static_cast<size_t>(options.max_faces));
  if (shown.faces.empty()) throw IoError("no face is left after decimating to report.max_faces = " + std::to_string(options.max_faces));
  nlohmann::json entry = {{"kind", "mesh"},
                          {"unit", "faces"},
                          {"elements", mesh.faces.size()},
                          {"shown", shown.faces.size()},
                          {"decimated", shown.faces.size() < mesh.faces.size()},
                          {"bounds", RobustBounds(shown.vertices)},
                          {"parts", nlohmann::json::array()}};
  const int page_count = pages.empty() ? 1 : static_cast<int>(pages.size());
  for (int page = 0; page < page_count; ++page) {
    const ViewerMesh part = pages.empty() ? shown : PagePart(shown, page);
    if (part.faces.empty()) continue;
    nlohmann::json p = {{"position", sink->Add(Flat(part.vertices))}, {"index", sink->Add(Flat(part.faces))}};
    if (!part.colors.empty()) p["color"] = sink->Add(Flat(part.colors));
    if (!pages.empty()) {
      p["uv"] = sink->Add(Flat(part.uvs));
      p["texture"] = JpegDataUri(ShrinkToFit(pages[page], options.max_texture_size, options.max_texture_size), 85);
    }
    entry["parts"].push_back(p);
  }
  return entry;
}

// A PLY triangle mesh (surfels/mesh.ply, hull/hull.ply) as the viewer draws it.
ViewerMesh ReadPlyForViewer(const std::string& path) {
  TriangleMesh mesh = ReadMeshPly(path);
  mesh.DropNonFiniteVertices();
  const std::string invalid = mesh.Validate();
  if (!invalid.empty()) throw IoError(path + ": " + invalid);
  if (mesh.faces.empty()) throw IoError(path + ": the mesh has no faces");
  ViewerMesh out;
  out.vertices = std::move(mesh.vertices);
  out.faces = std::move(mesh.faces);
  if (mesh.colors.size() == out.vertices.size()) out.colors = std::move(mesh.colors);
  return out;
}

// The `components` floats per element of accessor `index`, checked against its buffer.
std::vector<float> AccessorFloats(const tinygltf::Model& model, int index, int type, const std::string& path) {
  if (index < 0 || index >= static_cast<int>(model.accessors.size())) throw IoError(path + ": accessor " + std::to_string(index) + " missing");
  const tinygltf::Accessor& accessor = model.accessors[index];
  if (accessor.componentType != TINYGLTF_COMPONENT_TYPE_FLOAT || accessor.type != type || accessor.bufferView < 0 ||
      accessor.bufferView >= static_cast<int>(model.bufferViews.size())) {
    throw IoError(path + ": accessor " + std::to_string(index) + " is not float data of the expected type in a buffer");
  }
  const tinygltf::BufferView& view = model.bufferViews[accessor.bufferView];
  const size_t components = tinygltf::GetNumComponentsInType(type);
  const size_t stride = view.byteStride ? view.byteStride : components * sizeof(float);
  const size_t start = view.byteOffset + accessor.byteOffset;
  if (view.buffer < 0 || view.buffer >= static_cast<int>(model.buffers.size()) ||
      (accessor.count > 0 && start + stride * (accessor.count - 1) + components * sizeof(float) > model.buffers[view.buffer].data.size())) {
    throw IoError(path + ": accessor " + std::to_string(index) + " reaches past the end of its buffer");
  }
  std::vector<float> out(accessor.count * components);
  const unsigned char* data = model.buffers[view.buffer].data.data() + start;
  for (size_t i = 0; i < accessor.count; ++i) std::memcpy(&out[i * components], data + i * stride, components * sizeof(float));
  return out;
}

// The indices of a primitive (0, 1, 2, ... when it has none), each checked to be < vertex_count.
std::vector<uint32_t> PrimitiveIndices(const tinygltf::Model& model, const tinygltf::Primitive& primitive, size_t vertex_count,
                                       const std::string& path) {
  std::vector<uint32_t> out;
  if (primitive.indices < 0) {
    for (size_t i = 0; i < vertex_count; ++i) out.push_back(static_cast<uint32_t>(i));
    return out;
  }
  if (primitive.indices >= static_cast<int>(model.accessors.size())) throw IoError(path + ": index accessor missing");
  const tinygltf::Accessor& accessor = model.accessors[primitive.indices];
  const size_t size = tinygltf::GetComponentSizeInBytes(accessor.componentType);
  if (accessor.type != TINYGLTF_TYPE_SCALAR || (size != 1 && size != 2 && size != 4) || accessor.bufferView < 0 ||
      accessor.bufferView >= static_cast<int>(model.bufferViews.size())) {
    throw IoError(path + ": the indices are not unsigned integers in a buffer");
  }
  const tinygltf::BufferView& view = model.bufferViews[accessor.bufferView];
  const size_t start = view.byteOffset + accessor.byteOffset;
  if (view.buffer < 0 || view.buffer >= static_cast<int>(model.buffers.size()) ||
      start + size * accessor.count > model.buffers[view.buffer].data.size()) {
    throw IoError(path + ": the indices reach past the end of their buffer");
  }
  const unsigned char* data = model.buffers[view.buffer].data.data() + start;
  for (size_t i = 0; i < accessor.count; ++i) {
    uint32_t value = 0;
    if (size == 1) value = data[i];
    if (size == 2) {
      uint16_t v16 = 0;
      std::memcpy(&v16, data + 2 * i, 2);  // the buffer need not be aligned for uint16_t
      value = v16;
    }
    if (size == 4) std::memcpy(&value, data + 4 * i, 4);
    if (value >= vertex_count) throw IoError(path + ": index " + std::to_string(value) + " of " + std::to_string(vertex_count) + " vertices");
    out.push_back(value);
  }
  return out;
}

// The base colour image of a material as BGR; empty when it has none.
cv::Mat MaterialImage(const tinygltf::Model& model, int material) {
  if (material < 0 || material >= static_cast<int>(model.materials.size())) return {};
  const int texture = model.materials[material].pbrMetallicRoughness.baseColorTexture.index;
  if (texture < 0 || texture >= static_cast<int>(model.textures.size())) return {};
  const int source = model.textures[texture].source;
  if (source < 0 || source >= static_cast<int>(model.images.size())) return {};
  const tinygltf::Image& image = model.images[source];
  if (image.bits != 8 || (image.component != 3 && image.component != 4) ||
      image.image.size() != static_cast<size_t>(image.width) * image.height * image.component) {
    return {};
  }
  const cv::Mat pixels(image.height, image.width, image.component == 3 ? CV_8UC3 : CV_8UC4,
                       const_cast<unsigned char*>(image.image.data()));
  cv::Mat bgr;
  cv::cvtColor(pixels, bgr, image.component == 3 ? cv::COLOR_RGB2BGR : cv::COLOR_RGBA2BGR);
  return bgr;
}

// Merges the corners that share a position, a texture coordinate and a page (the texture stage's
// glTF gives every face three vertices of its own: inside a patch about six faces share each one,
// so the page's arrays shrink about fourfold).
class CornerWelder {
 public:
  int Index(const Eigen::Vector3f& position, const Eigen::Vector2f& uv, int page, ViewerMesh* mesh) {
    std::array<uint32_t, 6> key;
    std::memcpy(key.data(), position.data(), 12);
    std::memcpy(key.data() + 3, uv.data(), 8);
    key[5] = static_cast<uint32_t>(page);
    const auto [it, added] = index_.emplace(key, static_cast<int>(mesh->vertices.size()));
    if (added) {
      mesh->vertices.push_back(position);
      mesh->uvs.push_back(uv);
    }
    return it->second;
  }

 private:
  struct KeyHash {
    size_t operator()(const std::array<uint32_t, 6>& k) const {
      uint64_t h = 1469598103934665603ull;
      for (uint32_t v : k) h = (h ^ v) * 1099511628211ull;
      return static_cast<size_t>(h);
    }
  };
  std::unordered_map<std::array<uint32_t, 6>, int, KeyHash> index_;
};

// texture/mesh.glb: every primitive of every mesh, with the page (material image) each face
// samples, corners welded (CornerWelder); faces with a non-finite corner are left out.
ViewerMesh ReadGlbForViewer(const std::string& path, std::vector<cv::Mat>* pages) {
  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string error, warning;
  if (!loader.LoadBinaryFromFile(&model, &error, &warning, path)) {
    throw IoError(path + ": not a binary glTF file tinygltf reads (" + (error.empty() ? "no reason given" : error) + ")");
  }
  ViewerMesh out;
  CornerWelder welder;
  std::map<int, int> page_of_material;
  for (const tinygltf::Mesh& mesh : model.meshes) {
    for (const tinygltf::Primitive& primitive : mesh.primitives) {
      if (primitive.mode != TINYGLTF_MODE_TRIANGLES && primitive.mode != -1) continue;
      if (!primitive.attributes.count("POSITION")) throw IoError(path + ": a primitive without POSITION");
      const std::vector<float> xyz = AccessorFloats(model, primitive.attributes.at("POSITION"), TINYGLTF_TYPE_VEC3, path);
      const size_t count = xyz.size() / 3;
      std::vector<float> uv;
      if (primitive.attributes.count("TEXCOORD_0")) uv = AccessorFloats(model, primitive.attributes.at("TEXCOORD_0"), TINYGLTF_TYPE_VEC2, path);
      if (!uv.empty() && uv.size() != 2 * count) throw IoError(path + ": TEXCOORD_0 and POSITION differ in length");
      const std::vector<uint32_t> indices = PrimitiveIndices(model, primitive, count, path);
      int page = -1;
      if (!uv.empty()) {
        if (!page_of_material.count(primitive.material)) {
          cv::Mat image = MaterialImage(model, primitive.material);
          page_of_material[primitive.material] = image.empty() ? -1 : static_cast<int>(pages->size());
          if (!image.empty()) pages->push_back(image);
        }
        page = page_of_material[primitive.material];
      }
      for (size_t i = 0; i + 2 < indices.size(); i += 3) {
        bool finite = true;
        for (int c = 0; c < 3; ++c) finite = finite && Eigen::Map<const Eigen::Vector3f>(&xyz[3 * indices[i + c]]).allFinite();
        if (!finite) continue;
        Eigen::Vector3i face;
        for (int c = 0; c < 3; ++c) {
          const Eigen::Vector3f position = Eigen::Map<const Eigen::Vector3f>(&xyz[3 * indices[i + c]]);
          // glTF's v points down; the viewer's, as OBJ's, up.
          const Eigen::Vector2f texel = page >= 0 ? Eigen::Vector2f(uv[2 * indices[i + c]], 1.f - uv[2 * indices[i + c] + 1])
                                                  : Eigen::Vector2f(0.5f, 0.5f);
          face[c] = welder.Index(position, texel, page, &out);
        }
        out.faces.push_back(face);
        out.face_page.push_back(page);
      }
    }
  }
  if (out.faces.empty()) throw IoError(path + ": no triangles");
  // Faces without a page (a primitive with no texture) are drawn from a grey page of their own.
  if (std::count(out.face_page.begin(), out.face_page.end(), -1) > 0) {
    for (int& page : out.face_page) page = page < 0 ? static_cast<int>(pages->size()) : page;
    pages->push_back(cv::Mat(4, 4, CV_8UC3, cv::Scalar(160, 160, 160)));
  }
  return out;
}

// dense/fused.ply: an even subsample of at most max_points, non-finite points left out.
nlohmann::json PointsEntry(const std::string& path, const ViewerOptions& options, ArraySink* sink) {
  const PointCloud cloud = ReadPointCloudPly(path);
  if (cloud.size() == 0) throw IoError(path + ": no points");
  std::vector<Eigen::Vector3f> positions;
  std::vector<Color3u8> colors;
  for (size_t i : EvenSubsample(cloud.size(), static_cast<size_t>(options.max_points))) {
    if (!cloud.positions[i].allFinite()) continue;
    positions.push_back(cloud.positions[i]);
    colors.push_back(cloud.colors.size() == cloud.size() ? cloud.colors[i] : Color3u8(170, 170, 170));
  }
  if (positions.empty()) throw IoError(path + ": no point with finite coordinates");
  nlohmann::json entry = {{"kind", "points"},
                          {"unit", "points"},
                          {"elements", cloud.size()},
                          {"shown", positions.size()},
                          {"decimated", positions.size() < cloud.size()},
                          {"bounds", RobustBounds(positions)}};
  entry["parts"] = {{{"position", sink->Add(Flat(positions))}, {"color", sink->Add(Flat(colors))}}};
  return entry;
}

// splat_fit/splats.ply: each splat's centre as a point in its view-independent colour (0.5 + C0
// times the DC coefficients, clamped to [0, 1]); the splats nearly transparent (opacity < 0.1:
// their share of a pixel is small) left out, then an even subsample of at most max_points.
nlohmann::json SplatsEntry(const std::string& path, const ViewerOptions& options, ArraySink* sink) {
  const GaussianSplats splats = ReadGaussianSplatsPly(path);
  if (splats.size() == 0) throw IoError(path + ": no splats");
  std::vector<size_t> visible;
  for (size_t i = 0; i < splats.size(); ++i) {
    const float opacity = 1.f / (1.f + std::exp(-splats.opacity_logit[i]));
    if (opacity >= 0.1f && splats.position[i].allFinite()) visible.push_back(i);
  }
  if (visible.empty()) throw IoError(path + ": every splat is transparent (opacity below 0.1) or not finite");
  std::vector<Eigen::Vector3f> positions;
  std::vector<Color3u8> colors;
  for (size_t k : EvenSubsample(visible.size(), static_cast<size_t>(options.max_points))) {
    const size_t i = visible[k];
    positions.push_back(splats.position[i]);
    const float* sh = splats.Sh(i);  // [k][channel]: the DC terms first
    Color3u8 color;
    for (int c = 0; c < 3; ++c) color[c] = static_cast<uint8_t>(std::lround(255.f * std::clamp(0.5f + kShC0 * sh[c], 0.f, 1.f)));
    colors.push_back(color);
  }
  nlohmann::json entry = {{"kind", "points"},
                          {"unit", "splats of opacity 0.1 or more (of " + std::to_string(splats.size()) + ")"},
                          {"elements", visible.size()},
                          {"shown", positions.size()},
                          {"decimated", positions.size() < visible.size()},
                          {"bounds", RobustBounds(positions)}};
  entry["parts"] = {{{"position", sink->Add(Flat(positions))}, {"color", sink->Add(Flat(colors))}}};
  return entry;
}

// The direction the viewer orbits around: the cameras' mean image up (-y) where they agree (the
// mean at least 0.9 long: within about 25 degrees), else, when their centres lie near a plane (a
// ring whose cameras are rolled, as Middlebury's templeRing: its image ups turn with the ring), the plane's
// normal, turned so that the cameras look down along it or, when they look level, along their
// mean image right (a guess: nothing in the photos says which way is up then). Zero when neither.
Eigen::Vector3d OrbitUp(const std::vector<Rigid3d>& world_from_cams) {
  Eigen::Vector3d up = Eigen::Vector3d::Zero(), right = Eigen::Vector3d::Zero(), forward = Eigen::Vector3d::Zero();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  const double n = static_cast<double>(world_from_cams.size());
  for (const Rigid3d& pose : world_from_cams) {
    up -= pose.rotation * Eigen::Vector3d::UnitY();
    right += pose.rotation * Eigen::Vector3d::UnitX();
    forward += pose.rotation * Eigen::Vector3d::UnitZ();
    mean += pose.translation / n;
  }
  if (up.norm() >= 0.9 * n) return up.normalized();
  if (world_from_cams.size() < 3) return Eigen::Vector3d::Zero();
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const Rigid3d& pose : world_from_cams) scatter += (pose.translation - mean) * (pose.translation - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);  // eigenvalues in increasing order
  if (solver.eigenvalues()[0] > 0.1 * solver.eigenvalues()[1]) return Eigen::Vector3d::Zero();  // not a plane
  Eigen::Vector3d normal = solver.eigenvectors().col(0);
  const double down = -normal.dot(forward) / n;
  if (std::abs(down) > 0.05 ? down < 0 : normal.dot(right) < 0) normal = -normal;
  return normal;
}

// The cameras of the last sparse model a stage wrote, as frustum data; `up` (OrbitUp of the
// training cameras) when there is one.
nlohmann::json Cameras(const Workspace& workspace, const nlohmann::json& scores, const std::string& metric, nlohmann::json* viewer) {
  std::string folder;
  for (const char* candidate : {"dense/sparse", "sfm/sparse", "sparse"}) {
    if (fs::exists(workspace.Path(std::string(candidate) + "/images.txt"))) {
      folder = candidate;
      break;
    }
  }
  nlohmann::json cameras = nlohmann::json::array();
  if (folder.empty()) return cameras;
  (*viewer)["cameras_from"] = folder;
  std::set<std::string> heldout;
  if (scores.is_object() && scores.contains("heldout") && scores["heldout"].is_array()) {
    for (const auto& name : scores["heldout"]) {
      if (name.is_string()) heldout.insert(name.get<std::string>());
    }
  }
  const nlohmann::json proxies = scores.is_object() ? scores.value("proxies", nlohmann::json::object()) : nlohmann::json::object();
  // Views whose agreement with the others stands out on the bad side (issue 67; multi_depth).
  const std::vector<std::string> flagged_names = ReadFlaggedViews(workspace.ViewAgreementPath());
  const std::set<std::string> flagged(flagged_names.begin(), flagged_names.end());
  const SparseModel model = ReadSparseModelText(workspace.Path(folder));
  std::vector<Rigid3d> training_poses;
  for (int id : model.ImageIdsByName()) {
    const Image& image = model.images.at(id);
    const Camera& camera = model.CameraOf(image);
    const Rigid3d world_from_cam = image.cam_from_world.Inverse();
    const Eigen::Vector3d center = world_from_cam.translation;
    nlohmann::json corners = nlohmann::json::array();
    for (const Eigen::Vector2d& pixel : {Eigen::Vector2d(0, 0), Eigen::Vector2d(camera.width, 0),
                                         Eigen::Vector2d(camera.width, camera.height), Eigen::Vector2d(0, camera.height)}) {
      const Eigen::Vector3d direction = world_from_cam.rotation * camera.CamFromImg(pixel);
      corners.insert(corners.end(), {direction.x(), direction.y(), direction.z()});
    }
    nlohmann::json entry = {{"name", image.name}, {"heldout", heldout.count(image.name) > 0},
                            {"center", {center.x(), center.y(), center.z()}}, {"corners", corners}};
    if (!entry["heldout"]) training_poses.push_back(world_from_cam);
    if (flagged.count(image.name)) entry["flagged"] = true;
    // The best score any model reached on this held-out view.
    for (const auto& [name, proxy] : proxies.items()) {
      if (!proxy.is_object() || !proxy.contains("views") || !proxy["views"].is_object()) continue;
      const nlohmann::json& views = proxy["views"];
      if (!views.contains(image.name) || !views[image.name].is_object()) continue;
      const nlohmann::json& view = views[image.name];
      if (!view.contains(metric) || !view[metric].is_number()) continue;
      if (!entry.contains("score") || view[metric].get<double>() > entry["score"].get<double>()) {
        entry["score"] = view[metric];
        entry["model"] = name;
      }
    }
    cameras.push_back(entry);
  }
  const Eigen::Vector3d up = OrbitUp(training_poses);
  if (up.norm() > 0.5) {
    (*viewer)["up"] = {up.x(), up.y(), up.z()};
  }
  return cameras;
}

// One model entry: `read` fills it; what it throws becomes the entry's error, with `remedy`.
template <typename Read>
nlohmann::json ModelEntry(const std::string& name, const std::string& source, const std::string& remedy, Read read) {
  nlohmann::json entry;
  try {
    entry = read();
  } catch (const std::exception& e) {
    entry = {{"error", std::string(e.what()) + "; " + remedy}};
  }
  entry["name"] = name;
  entry["source"] = source;
  return entry;
}

}  // namespace

nlohmann::json ReadVolumeForViewer(const std::string& folder, const ViewerOptions& options) {
  // The volume stage's own reader and format (pipeline/core/plane_volume.h).
  const PlaneVolume volume = ReadPlaneVolume(folder);
  const std::vector<cv::Mat> images = PlaneImages(volume);
  const Rigid3d world_from_cam = volume.cam_from_world.Inverse();
  const double width = volume.Width(), height = volume.Height();
  nlohmann::json planes = nlohmann::json::array();
  std::vector<Eigen::Vector3f> all_corners;
  for (int k = 0; k < volume.Planes(); ++k) {
    nlohmann::json corners = nlohmann::json::array();
    for (const auto& [u, v] : {std::pair{0.0, 0.0}, {width, 0.0}, {width, height}, {0.0, height}}) {
      const Eigen::Vector3d in_world =
          world_from_cam * (volume.depths[k] * volume.camera.CamFromImg(Eigen::Vector2d(u, v)));
      corners.insert(corners.end(), {in_world.x(), in_world.y(), in_world.z()});
      all_corners.push_back(in_world.cast<float>());
    }
    planes.push_back({{"depth", volume.depths[k]},
                      {"corners", corners},
                      {"texture", PngDataUri(ShrinkToFit(images[k], options.max_plane_size, options.max_plane_size))}});
  }
  return {{"kind", "planes"}, {"unit", "planes"}, {"elements", planes.size()}, {"shown", planes.size()}, {"decimated", false},
          {"bounds", RobustBounds(all_corners)}, {"planes", planes}};
}

ViewerData GatherViewer(const std::string& root, const nlohmann::json& scores, const std::string& metric,
                        const ViewerOptions& options) {
  const Workspace workspace(root);
  ViewerData data;
  ArraySink sink(&data.arrays);
  data.viewer = {{"models", nlohmann::json::array()}, {"metric", metric}, {"max_faces", options.max_faces},
                 {"max_points", options.max_points}};
  nlohmann::json& models = data.viewer["models"];
  const auto rerun = [](const std::string& stage) { return "re-run the " + stage + " stage (ibmr run CONFIG --only " + stage + " --force)"; };
  if (fs::exists(workspace.Path("texture/mesh.glb"))) {
    models.push_back(ModelEntry("textured mesh", "texture/mesh.glb", rerun("texture"), [&] {
      std::vector<cv::Mat> pages;
      const ViewerMesh mesh = ReadGlbForViewer(workspace.Path("texture/mesh.glb"), &pages);
      return MeshEntry(mesh, pages, options, &sink);
    }));
  }
  for (const auto& [name, source, stage] : {std::tuple{"surfel mesh", "surfels/mesh.ply", "surfels"}, {"hull", "hull/hull.ply", "carve"}}) {
    if (!fs::exists(workspace.Path(source))) continue;
    const std::string path = workspace.Path(source);  // a structured binding cannot be captured in C++17
    models.push_back(ModelEntry(name, source, rerun(stage), [&] {
      return MeshEntry(ReadPlyForViewer(path), {}, options, &sink);
    }));
  }
  if (fs::exists(workspace.Path("dense/fused.ply"))) {
    nlohmann::json points = ModelEntry("fused points", "dense/fused.ply", rerun("fuse"),
                                       [&] { return PointsEntry(workspace.Path("dense/fused.ply"), options, &sink); });
    // The order of preference: textured mesh, surfel mesh, fused points, hull.
    const auto hull = std::find_if(models.begin(), models.end(), [](const nlohmann::json& m) { return m["name"] == "hull"; });
    models.insert(hull, points);
  }
  if (fs::exists(workspace.Path("splat_fit/splats.ply"))) {
    models.push_back(ModelEntry("fitted splats", "splat_fit/splats.ply", rerun("splat_fit"),
                                [&] { return SplatsEntry(workspace.Path("splat_fit/splats.ply"), options, &sink); }));
  }
  if (fs::is_directory(workspace.Path("volume"))) {
    std::vector<fs::path> folders;
    for (const auto& entry : fs::directory_iterator(workspace.Path("volume"))) {
      if (fs::exists(entry.path() / "volume.json")) folders.push_back(entry.path());
    }
    std::sort(folders.begin(), folders.end());
    for (const fs::path& folder : folders) {
      const std::string reference = folder.filename().string();
      models.push_back(ModelEntry("volume " + reference, "volume/" + reference, rerun("volume"),
                                  [&] { return ReadVolumeForViewer(folder.string(), options); }));
    }
  }
  try {
    data.viewer["cameras"] = Cameras(workspace, scores, metric, &data.viewer);
  } catch (const std::exception& e) {
    data.viewer["cameras"] = nlohmann::json::array();
    data.viewer["cameras_error"] = e.what();
  }
  return data;
}

std::string ViewerArraysHtml(const ViewerData& data) {
  std::string html;
  for (const auto& [id, base64] : data.arrays) {
    html += "<script type=\"application/octet-stream\" id=\"" + id + "\">" + base64 + "</script>\n";
  }
  return html;
}

}  // namespace ibmr
