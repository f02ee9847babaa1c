// Quadric decimation with OpenMesh (see mesh_decimation.h). Kept apart: OpenMesh's templates are
// heavy and only this file needs them.
#include "stages/render/mesh_decimation.h"

#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>
#include <OpenMesh/Core/System/omstream.hh>
#include <OpenMesh/Tools/Decimater/DecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModNormalFlippingT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>

namespace ibmr {

namespace {

struct Traits : public OpenMesh::DefaultTraits {
  VertexAttributes(OpenMesh::Attributes::Status | OpenMesh::Attributes::Color);
  FaceAttributes(OpenMesh::Attributes::Status | OpenMesh::Attributes::Normal);
  EdgeAttributes(OpenMesh::Attributes::Status);
  HalfedgeAttributes(OpenMesh::Attributes::Status | OpenMesh::Attributes::PrevHalfedge);
  typedef OpenMesh::Vec3uc Color;
};
using OmMesh = OpenMesh::TriMesh_ArrayKernelT<Traits>;

}  // namespace

TriangleMesh DecimateMesh(const TriangleMesh& mesh, size_t max_faces, size_t* refused) {
  if (refused) *refused = 0;
  if (mesh.faces.size() <= max_faces) return mesh;
  omerr().disable();  // refused faces are counted, not printed
  OmMesh om;
  std::vector<OmMesh::VertexHandle> handles;
  handles.reserve(mesh.vertices.size());
  const bool colored = mesh.colors.size() == mesh.vertices.size();
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Eigen::Vector3f& v = mesh.vertices[i];
    handles.push_back(om.add_vertex(OmMesh::Point(v.x(), v.y(), v.z())));
    if (colored) om.set_color(handles.back(), OmMesh::Color(mesh.colors[i][0], mesh.colors[i][1], mesh.colors[i][2]));
  }
  for (const Eigen::Vector3i& f : mesh.faces) {
    if (!om.add_face(handles[f[0]], handles[f[1]], handles[f[2]]).is_valid() && refused) ++*refused;
  }
  om.update_face_normals();

  OpenMesh::Decimater::DecimaterT<OmMesh> decimater(om);
  OpenMesh::Decimater::ModQuadricT<OmMesh>::Handle quadric;
  OpenMesh::Decimater::ModNormalFlippingT<OmMesh>::Handle flipping;
  decimater.add(quadric);
  decimater.add(flipping);
  decimater.module(quadric).unset_max_err();  // the face budget alone stops it
  decimater.initialize();
  decimater.decimate_to_faces(0, max_faces);
  om.garbage_collection();

  TriangleMesh out;
  out.comments = mesh.comments;
  out.comments.push_back("decimated towards " + std::to_string(max_faces) + " faces (quadric, OpenMesh)");
  out.vertices.reserve(om.n_vertices());
  for (const auto v : om.vertices()) {
    const OmMesh::Point& p = om.point(v);
    out.vertices.emplace_back(p[0], p[1], p[2]);
    if (colored) {
      const OmMesh::Color& c = om.color(v);
      out.colors.push_back(Color3u8(c[0], c[1], c[2]));
    }
  }
  out.faces.reserve(om.n_faces());
  for (const auto f : om.faces()) {
    Eigen::Vector3i face;
    int k = 0;
    for (const auto v : om.fv_range(f)) face[k++] = v.idx();
    out.faces.push_back(face);
  }
  out.ComputeVertexNormals();
  return out;
}

}  // namespace ibmr
