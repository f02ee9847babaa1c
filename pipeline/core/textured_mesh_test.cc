// Tests for TexturedMesh: Validate, the OBJ/MTL/PNG round trip (geometry, UVs, pages, face
// order), what the OBJ and MTL files hold, hand-written OBJs in other tools' forms (polygons,
// relative indices, CRLF), errors naming file and line for bad input, the GLB read back with
// tinygltf, and both files read by assimp (Debian assimp-utils) when it is installed.
#include "pipeline/core/textured_mesh.h"

#include <gtest/gtest.h>
#include <tiny_gltf.h>

#include <cstring>
#include <filesystem>
#include <functional>
#include <sstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/child_process.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "tests/scratch_dir.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

fs::path MakeTestDir(const std::string& name) { return ibmr_testing::ScratchDir("ibmr_textured_mesh_" + name); }

// An 8x8 page: a gradient over `base` (BGR) so that every texel differs.
cv::Mat Page(const cv::Vec3b& base) {
  cv::Mat page(8, 8, CV_8UC3);
  for (int r = 0; r < 8; ++r)
    for (int c = 0; c < 8; ++c) page.at<cv::Vec3b>(r, c) = base + cv::Vec3b(4 * r, 4 * c, static_cast<uchar>(r + c));
  return page;
}

Eigen::Matrix<float, 3, 2> Uv(float u0, float v0, float u1, float v1, float u2, float v2) {
  Eigen::Matrix<float, 3, 2> uv;
  uv << u0, v0, u1, v1, u2, v2;
  return uv;
}

// Two unit quads (4 triangles): the first on page 0 in z = 0, the second on page 1 in x = 2.
// The faces alternate pages so that the face order matters.
TexturedMesh TwoQuads() {
  TexturedMesh textured;
  textured.mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                            {2, 0, 0}, {2, 0, 1}, {2, 1, 1}, {2, 1, 0}};
  textured.mesh.faces = {{0, 1, 2}, {4, 5, 6}, {0, 2, 3}, {4, 6, 7}};
  textured.mesh.ComputeVertexNormals();
  textured.face_uv = {Uv(0, 0, 1, 0, 1, 1), Uv(0.0625f, 0.0625f, 0.9375f, 0.0625f, 0.9375f, 0.9375f),
                      Uv(0, 0, 1, 1, 0, 1), Uv(0.0625f, 0.0625f, 0.9375f, 0.9375f, 1.f / 3.f, 0.9375f)};
  textured.face_page = {0, 1, 0, 1};
  textured.pages = {Page({200, 10, 10}), Page({10, 10, 200})};
  return textured;
}

// An n x n grid of quads (2 n^2 triangles) in z = 0, left half on page 0, right half on page 1.
TexturedMesh Grid(int n) {
  TexturedMesh textured;
  for (int y = 0; y <= n; ++y)
    for (int x = 0; x <= n; ++x) textured.mesh.vertices.emplace_back(x, y, 0.f);
  auto uv_of = [n](int x, int y) { return Eigen::Vector2f(float(x) / n, float(y) / n); };
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const int a = y * (n + 1) + x, b = a + 1, c = a + n + 2, d = a + n + 1;
      for (const Eigen::Vector3i& face : {Eigen::Vector3i(a, b, c), Eigen::Vector3i(a, c, d)}) {
        Eigen::Matrix<float, 3, 2> uv;
        for (int k = 0; k < 3; ++k) {
          const int v = face[k];
          uv.row(k) = uv_of(v % (n + 1), v / (n + 1)).transpose();
        }
        textured.mesh.faces.push_back(face);
        textured.face_uv.push_back(uv);
        textured.face_page.push_back(2 * x < n ? 0 : 1);
      }
    }
  }
  textured.mesh.ComputeVertexNormals();
  textured.pages = {Page({0, 128, 255}), Page({255, 128, 0})};
  return textured;
}

std::string InputErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected InputError, got: " << e.what();
    return "";
  }
  ADD_FAILURE() << "expected InputError";
  return "";
}

void ExpectPagesEqual(const cv::Mat& a, const cv::Mat& b) {
  ASSERT_EQ(a.size(), b.size());
  ASSERT_EQ(a.type(), b.type());
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0);
}

TEST(TexturedMesh, ValidAndInvalid) {
  EXPECT_EQ(TexturedMesh().Validate(), "");
  EXPECT_EQ(TwoQuads().Validate(), "");

  TexturedMesh mesh = TwoQuads();
  mesh.face_uv[2](1, 0) = 1.0001f;
  EXPECT_NE(mesh.Validate().find("outside [0, 1]"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.face_uv[0](2, 1) = -0.01f;
  EXPECT_NE(mesh.Validate().find("face 0 has a UV outside"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.face_page[3] = 2;
  EXPECT_NE(mesh.Validate().find("face 3 samples atlas page 2"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.face_page[1] = -1;
  EXPECT_NE(mesh.Validate().find("atlas page -1"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.face_uv.pop_back();
  EXPECT_NE(mesh.Validate().find("3 face UV triples for 4 faces"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.face_page.push_back(0);
  EXPECT_NE(mesh.Validate().find("5 face pages for 4 faces"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.pages[1] = cv::Mat();
  EXPECT_NE(mesh.Validate().find("atlas page 1 is empty"), std::string::npos) << mesh.Validate();
  mesh = TwoQuads();
  mesh.mesh.faces[0][1] = 8;
  EXPECT_NE(mesh.Validate().find("face 0 refers to vertex 8"), std::string::npos) << mesh.Validate();
}

TEST(TexturedMesh, UvTexelConversionsAreInverse) {
  const Eigen::Vector2f texel = TexelFromUv({0.5f / 8, 1.f - 0.5f / 4}, 8, 4);
  EXPECT_NEAR(texel.x(), 0.5f, 1e-6f);
  EXPECT_NEAR(texel.y(), 0.5f, 1e-6f);
  const Eigen::Vector2f uv = UvFromTexel(texel, 8, 4);
  EXPECT_NEAR(uv.x(), 0.5f / 8, 1e-6f);
  EXPECT_NEAR(uv.y(), 1.f - 0.5f / 4, 1e-6f);
}

TEST(TexturedMesh, ObjRoundTrip) {
  const fs::path dir = MakeTestDir("round_trip") / "texture";
  const TexturedMesh mesh = TwoQuads();
  WriteTexturedObj(mesh, dir.string(), "mesh");
  for (const char* name : {"mesh.obj", "mesh.mtl", "atlas_0.png", "atlas_1.png"}) EXPECT_TRUE(fs::exists(dir / name)) << name;

  const TexturedMesh back = ReadTexturedObj((dir / "mesh.obj").string());
  EXPECT_EQ(back.Validate(), "");
  EXPECT_EQ(back.mesh.vertices, mesh.mesh.vertices);
  EXPECT_EQ(back.mesh.normals, mesh.mesh.normals);
  EXPECT_EQ(back.mesh.faces, mesh.mesh.faces);
  EXPECT_EQ(back.face_page, mesh.face_page);
  ASSERT_EQ(back.face_uv.size(), mesh.face_uv.size());
  for (size_t f = 0; f < mesh.face_uv.size(); ++f) {
    EXPECT_LE((back.face_uv[f] - mesh.face_uv[f]).cwiseAbs().maxCoeff(), 1e-6f) << "face " << f;
  }
  ASSERT_EQ(back.pages.size(), 2u);
  ExpectPagesEqual(back.pages[0], mesh.pages[0]);
  ExpectPagesEqual(back.pages[1], mesh.pages[1]);
}

TEST(TexturedMesh, ObjRoundTripWithoutNormals) {
  const fs::path dir = MakeTestDir("no_normals");
  TexturedMesh mesh = Grid(4);
  mesh.mesh.normals.clear();
  WriteTexturedObj(mesh, dir.string(), "grid");
  const std::string text = ReadFile((dir / "grid.obj").string());
  EXPECT_EQ(text.find("\nvn "), std::string::npos);
  const TexturedMesh back = ReadTexturedObj((dir / "grid.obj").string());
  EXPECT_TRUE(back.mesh.normals.empty());
  EXPECT_EQ(back.mesh.faces, mesh.mesh.faces);
  EXPECT_EQ(back.face_page, mesh.face_page);
}

TEST(TexturedMesh, ObjAndMtlContents) {
  const fs::path dir = MakeTestDir("contents");
  WriteTexturedObj(TwoQuads(), dir.string(), "mesh");
  const std::string obj = ReadFile((dir / "mesh.obj").string());
  EXPECT_NE(obj.find("\nmtllib mesh.mtl\n"), std::string::npos) << obj;
  EXPECT_NE(obj.find("\nusemtl atlas_0\nf 1/"), std::string::npos) << obj;
  EXPECT_NE(obj.find("\nusemtl atlas_1\nf 5/"), std::string::npos) << obj;
  EXPECT_NE(obj.find("\nf 1/1/1 2/2/2 3/3/3\n"), std::string::npos) << obj;

  int num_v = 0, num_vn = 0, num_vt = 0, num_f = 0;
  std::istringstream lines(obj);
  std::string line;
  while (std::getline(lines, line)) {
    std::istringstream fields(line);
    std::string keyword;
    fields >> keyword;
    if (keyword == "v") ++num_v;
    if (keyword == "vn") ++num_vn;
    if (keyword == "f") ++num_f;
    if (keyword != "vt") continue;
    ++num_vt;
    float u = -1, v = -1;
    fields >> u >> v;
    EXPECT_TRUE(u >= 0 && u <= 1 && v >= 0 && v <= 1) << line;
  }
  EXPECT_EQ(num_v, 8);
  EXPECT_EQ(num_vn, 8);
  EXPECT_EQ(num_f, 4);
  EXPECT_EQ(num_vt, 8);  // 12 corners, 4 of which repeat an earlier corner's UV

  const std::string mtl = ReadFile((dir / "mesh.mtl").string());
  for (const char* expected : {"newmtl atlas_0\nKa 1 1 1\nKd 1 1 1\n", "map_Kd atlas_0.png\n", "newmtl atlas_1\n",
                               "map_Kd atlas_1.png\n"}) {
    EXPECT_NE(mtl.find(expected), std::string::npos) << expected << " in\n" << mtl;
  }
}

TEST(TexturedMesh, WriterRefusesInconsistentMeshes) {
  const fs::path dir = MakeTestDir("refuse");
  TexturedMesh mesh = TwoQuads();
  mesh.face_uv[1](0, 0) = 2.f;
  EXPECT_THROW(WriteTexturedObj(mesh, dir.string(), "mesh"), IoError);
  EXPECT_THROW(WriteTexturedGlb(mesh, (dir / "mesh.glb").string()), IoError);
  EXPECT_THROW(WriteTexturedObj(TwoQuads(), dir.string(), "my mesh"), IoError);
  EXPECT_FALSE(fs::exists(dir / "mesh.obj"));
}

// A hand-written OBJ as other tools write it: a quad, relative indices, groups, CRLF.
TEST(TexturedMesh, ReadsPolygonsAndOtherToolsForms) {
  const fs::path dir = MakeTestDir("other_tools");
  WriteImage((dir / "tex.png").string(), Page({50, 60, 70}));
  WriteFileAtomic((dir / "scan.mtl").string(), "newmtl skin\r\n\tmap_Kd -s 1 1 1 tex.png\r\n");
  WriteFileAtomic((dir / "scan.obj").string(),
                  "# exported\r\nmtllib scan.mtl\r\no scan\r\nv 0 0 0\r\nv 1 0 0\r\nv 1 1 0\r\nv 0 1 0 0.5 0.5 0.5\r\n"
                  "vt 0 0\r\nvt 1 0\r\nvt 1 1\r\nvt 0 1\r\ng part\r\ns off\r\nusemtl skin\r\n"
                  "f -4/-4 -3/-3 -2/-2 -1/-1\r\n");
  const TexturedMesh mesh = ReadTexturedObj((dir / "scan.obj").string());
  ASSERT_EQ(mesh.mesh.faces.size(), 2u);  // the quad as a fan
  EXPECT_EQ(mesh.mesh.faces[0], Eigen::Vector3i(0, 1, 2));
  EXPECT_EQ(mesh.mesh.faces[1], Eigen::Vector3i(0, 2, 3));
  EXPECT_EQ(mesh.face_uv[1], Uv(0, 0, 1, 1, 0, 1));
  EXPECT_EQ(mesh.face_page, std::vector<int>({0, 0}));
  EXPECT_TRUE(mesh.mesh.normals.empty());
  ASSERT_EQ(mesh.pages.size(), 1u);
  ExpectPagesEqual(mesh.pages[0], Page({50, 60, 70}));
}

// Writes a good mesh into `dir` and returns mesh.obj's text, to corrupt.
std::string WriteGoodMesh(const fs::path& dir) {
  WriteTexturedObj(TwoQuads(), dir.string(), "mesh");
  return ReadFile((dir / "mesh.obj").string());
}

// The 1-based line of mesh.obj that starts with `prefix`.
int LineOf(const std::string& text, const std::string& prefix) {
  std::istringstream lines(text);
  std::string line;
  for (int number = 1; std::getline(lines, line); ++number)
    if (line.rfind(prefix, 0) == 0) return number;
  ADD_FAILURE() << "no line starts with " << prefix;
  return -1;
}

TEST(TexturedMesh, BadObjLinesNameFileAndLine) {
  const fs::path dir = MakeTestDir("bad_lines");
  WriteGoodMesh(dir);
  const std::string bad = (dir / "bad.obj").string();
  const std::string header = "mtllib mesh.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nusemtl atlas_0\n";
  struct Case {
    std::string text, expected;
  };
  const std::vector<Case> cases = {
      {header + "f 1 2 99\n", bad + ":9: face refers to vertex 99 but only 3 precede it"},
      {header + "f 1/1 2/2 99/3\n", bad + ":9: face refers to vertex 99"},
      {header + "f 1/1 2/2 3/7\n", bad + ":9: face refers to texture coordinate 7 but only 3"},
      {header + "f 1/1 2/2 0/3\n", bad + ":9: face refers to vertex 0"},
      {header + "f 1 2 3\n", bad + ":9: face corner '1' has no texture coordinate"},
      {header + "f 1/1 2/2\n", bad + ":9: a face needs at least 3 corners"},
      {header + "f 1/1/1/1 2/2 3/3\n", bad + ":9: face corner '1/1/1/1' has more than three"},
      {header + "f 1/x 2/2 3/3\n", bad + ":9: cannot parse 'x' as an integer"},
      {"mtllib mesh.mtl\nv 0 0 0\nv 1 abc 0\n", bad + ":3: cannot parse 'abc' as a number"},
      {"v 0 0\n", bad + ":1: 'v' needs 3 to 7 numbers"},
      {"v 0 nan 0\n", bad + ":1: vertex x y z [w | r g b] is not finite"},
      {"vt 0.5 1.5\nv 0 0 0\nv 1 0 0\nv 1 1 0\nmtllib mesh.mtl\nusemtl atlas_1\nf 1/1 2/1 3/1\n",
       bad + ":7: texture coordinate 1 (0.500000, 1.500000) is outside [0, 1]"},
      {"mtllib mesh.mtl\nusemtl wood\n", bad + ":2: 'usemtl wood': no such material"},
      {"v 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nf 1/1 2/1 3/1\n", bad + ":5: face before any 'usemtl'"},
      {"mtllib nothing.mtl\n", bad + ":1: cannot read the material library (cannot read " + (dir / "nothing.mtl").string()},
  };
  for (const Case& c : cases) {
    WriteFileAtomic(bad, c.text);
    const std::string message = InputErrorOf([&] { ReadTexturedObj(bad); });
    EXPECT_EQ(message.rfind(c.expected, 0), 0u) << "got: " << message << "\nexpected a message starting: " << c.expected;
  }
  // The good file still reads; a missing OBJ is an InputError naming it.
  EXPECT_EQ(ReadTexturedObj((dir / "mesh.obj").string()).mesh.faces.size(), 4u);
  EXPECT_NE(InputErrorOf([&] { ReadTexturedObj((dir / "absent.obj").string()); }).find("absent.obj"), std::string::npos);
}

TEST(TexturedMesh, MissingMtlOrPngNamesFileAndLine) {
  const fs::path dir = MakeTestDir("missing");
  const std::string obj = WriteGoodMesh(dir);
  const std::string obj_path = (dir / "mesh.obj").string();
  const std::string mtl_path = (dir / "mesh.mtl").string();

  const std::string mtl = ReadFile(mtl_path);
  fs::remove(dir / "atlas_1.png");
  std::string message = InputErrorOf([&] { ReadTexturedObj(obj_path); });
  EXPECT_NE(message.find(mtl_path + ":" + std::to_string(LineOf(mtl, "map_Kd atlas_1.png")) + ":"), std::string::npos)
      << message;
  EXPECT_NE(message.find("atlas_1.png"), std::string::npos) << message;
  EXPECT_NE(message.find("write the mesh again"), std::string::npos) << message;

  fs::remove(dir / "mesh.mtl");
  message = InputErrorOf([&] { ReadTexturedObj(obj_path); });
  EXPECT_NE(message.find(obj_path + ":" + std::to_string(LineOf(obj, "mtllib")) + ":"), std::string::npos) << message;
  EXPECT_NE(message.find("mesh.mtl"), std::string::npos) << message;

  WriteFileAtomic(mtl_path, "newmtl atlas_0\nKd 1 1 1\n");
  message = InputErrorOf([&] { ReadTexturedObj(obj_path); });
  EXPECT_NE(message.find(mtl_path + ":1: material 'atlas_0' has no 'map_Kd'"), std::string::npos) << message;
}

TEST(TexturedMesh, GlbReadsBackWithTinyGltf) {
  const fs::path dir = MakeTestDir("glb");
  const std::string path = (dir / "mesh.glb").string();
  const TexturedMesh mesh = TwoQuads();
  WriteTexturedGlb(mesh, path);

  const std::string bytes = ReadFile(path);
  ASSERT_GE(bytes.size(), 12u);
  EXPECT_EQ(bytes.substr(0, 4), "glTF");
  uint32_t version = 0, length = 0;
  std::memcpy(&version, bytes.data() + 4, 4);
  std::memcpy(&length, bytes.data() + 8, 4);
  EXPECT_EQ(version, 2u);
  EXPECT_EQ(length, bytes.size());

  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string error, warning;
  ASSERT_TRUE(loader.LoadBinaryFromFile(&model, &error, &warning, path)) << error;
  EXPECT_EQ(error, "");
  ASSERT_EQ(model.meshes.size(), 1u);
  const std::vector<tinygltf::Primitive>& primitives = model.meshes[0].primitives;
  ASSERT_EQ(primitives.size(), mesh.pages.size());

  size_t total_indices = 0;
  for (size_t p = 0; p < primitives.size(); ++p) {
    const tinygltf::Primitive& primitive = primitives[p];
    EXPECT_EQ(primitive.mode, TINYGLTF_MODE_TRIANGLES);
    EXPECT_EQ(primitive.material, static_cast<int>(p));
    ASSERT_TRUE(primitive.attributes.count("POSITION") && primitive.attributes.count("NORMAL") &&
                primitive.attributes.count("TEXCOORD_0"));
    const tinygltf::Accessor& indices = model.accessors[primitive.indices];
    EXPECT_EQ(indices.componentType, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT);
    total_indices += indices.count;
    const tinygltf::Accessor& positions = model.accessors[primitive.attributes.at("POSITION")];
    EXPECT_EQ(positions.minValues.size(), 3u);
    EXPECT_EQ(positions.maxValues.size(), 3u);

    const tinygltf::Accessor& texcoords = model.accessors[primitive.attributes.at("TEXCOORD_0")];
    ASSERT_EQ(texcoords.componentType, TINYGLTF_COMPONENT_TYPE_FLOAT);
    const tinygltf::BufferView& view = model.bufferViews[texcoords.bufferView];
    const auto* uv = reinterpret_cast<const float*>(model.buffers[view.buffer].data.data() + view.byteOffset +
                                                    texcoords.byteOffset);
    for (size_t i = 0; i < 2 * texcoords.count; ++i) EXPECT_TRUE(uv[i] >= 0.f && uv[i] <= 1.f) << uv[i];
    // The first vertex of the page's first face, v flipped.
    const int first_face = p == 0 ? 0 : 1;
    EXPECT_FLOAT_EQ(uv[0], mesh.face_uv[first_face](0, 0));
    EXPECT_FLOAT_EQ(uv[1], 1.f - mesh.face_uv[first_face](0, 1));
  }
  EXPECT_EQ(total_indices, 3 * mesh.mesh.faces.size());

  ASSERT_EQ(model.images.size(), mesh.pages.size());
  for (size_t p = 0; p < model.images.size(); ++p) {
    const tinygltf::Image& image = model.images[p];
    EXPECT_EQ(image.mimeType, "image/png");
    EXPECT_GE(image.bufferView, 0);  // embedded, not a file
    EXPECT_TRUE(image.uri.empty());
    ASSERT_EQ(image.width, 8);
    ASSERT_EQ(image.height, 8);
    // tinygltf decodes to RGB(A): the page's BGR texel (2, 5) reversed.
    const cv::Vec3b bgr = mesh.pages[p].at<cv::Vec3b>(2, 5);
    const unsigned char* rgb = image.image.data() + (2 * 8 + 5) * image.component;
    EXPECT_EQ(rgb[0], bgr[2]);
    EXPECT_EQ(rgb[1], bgr[1]);
    EXPECT_EQ(rgb[2], bgr[0]);
  }
  ASSERT_EQ(model.materials.size(), mesh.pages.size());
  EXPECT_EQ(model.materials[1].pbrMetallicRoughness.baseColorTexture.index, 1);
  EXPECT_EQ(model.materials[1].pbrMetallicRoughness.metallicFactor, 0.0);
  EXPECT_EQ(model.materials[1].pbrMetallicRoughness.roughnessFactor, 1.0);
}

TEST(TexturedMesh, GlbSkipsPagesWithoutFaces) {
  const fs::path dir = MakeTestDir("glb_unused_page");
  TexturedMesh mesh = TwoQuads();
  mesh.face_page = {1, 1, 1, 1};
  WriteTexturedGlb(mesh, (dir / "mesh.glb").string());
  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string error, warning;
  ASSERT_TRUE(loader.LoadBinaryFromFile(&model, &error, &warning, (dir / "mesh.glb").string())) << error;
  ASSERT_EQ(model.meshes.size(), 1u);
  ASSERT_EQ(model.meshes[0].primitives.size(), 1u);
  EXPECT_EQ(model.meshes[0].primitives[0].material, 1);
  EXPECT_EQ(model.images.size(), 2u);
}

// The face count `assimp info` prints ("Faces:   N"); -1 when it fails or prints none.
int AssimpFaceCount(const std::string& assimp, const std::string& path, std::string* output) {
  int faces = -1;
  const ProcessResult result = RunProcess({assimp, "info", path}, "", [&](const std::string& line) {
    *output += line + "\n";
    const size_t pos = line.find("Faces:");
    if (pos != std::string::npos) faces = std::atoi(line.c_str() + pos + 6);
  });
  return result.exit_code == 0 ? faces : -1;
}

TEST(TexturedMesh, AssimpReadsObjAndGlb) {
  const std::string assimp = FindExecutable("assimp");
  if (assimp.empty()) {
    GTEST_SKIP() << "`assimp` not found on PATH; install Debian package assimp-utils (scripts/test.sh does)";
  }
  const fs::path dir = MakeTestDir("assimp");
  const TexturedMesh mesh = Grid(10);  // 200 faces on two pages
  ASSERT_EQ(mesh.mesh.faces.size(), 200u);
  WriteTexturedObj(mesh, dir.string(), "mesh");
  WriteTexturedGlb(mesh, (dir / "mesh.glb").string());
  for (const char* name : {"mesh.obj", "mesh.glb"}) {
    std::string output;
    EXPECT_EQ(AssimpFaceCount(assimp, (dir / name).string(), &output), 200) << name << ":\n" << output;
  }
}

}  // namespace
}  // namespace ibmr
