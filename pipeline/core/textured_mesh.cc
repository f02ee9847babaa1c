// TexturedMesh consistency check and its Wavefront OBJ/MTL form. The writer emits `v` (and
// `vn` when there are normals), `vt` deduplicated by exact value, and the faces in their order
// with a `usemtl atlas_<page>` line wherever the page changes, so a round trip keeps the face
// order; numbers are written in their shortest exact form (std::to_chars), so they read back
// bit for bit. The reader accepts what this writer and common tools write (polygons are split
// as fans, relative indices, `v//vn`, unknown statements skipped) and names file and line of
// anything it cannot use. The binary glTF writer is in gltf_writer.cc.
#include "pipeline/core/textured_mesh.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <string_view>
#include <unordered_map>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

std::string PageName(size_t page) { return "atlas_" + std::to_string(page); }

// ---------------------------------------------------------------------------------------------
// Writing.

void AppendFloat(std::string* out, float value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out->append(buffer, result.ptr);
}

void AppendLine(std::string* out, const char* keyword, std::initializer_list<float> values) {
  out->append(keyword);
  for (float value : values) {
    out->push_back(' ');
    AppendFloat(out, value);
  }
  out->push_back('\n');
}

std::string MtlText(size_t num_pages) {
  std::string text = "# ibmr textured mesh: one material per atlas page\n";
  for (size_t page = 0; page < num_pages; ++page) {
    text += "\nnewmtl " + PageName(page) + "\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd " +
            PageName(page) + ".png\n";
  }
  return text;
}

// Key of a UV for exact deduplication (the bit patterns of u and v).
uint64_t UvKey(float u, float v) {
  uint32_t bits_u, bits_v;
  std::memcpy(&bits_u, &u, sizeof(float));
  std::memcpy(&bits_v, &v, sizeof(float));
  return (static_cast<uint64_t>(bits_u) << 32) | bits_v;
}

std::string ObjText(const TexturedMesh& textured, const std::string& stem) {
  const TriangleMesh& mesh = textured.mesh;
  const bool has_normals = !mesh.normals.empty();
  std::string text = "# ibmr textured mesh: " + std::to_string(mesh.vertices.size()) + " vertices, " +
                     std::to_string(mesh.faces.size()) + " faces, " + std::to_string(textured.pages.size()) +
                     " atlas pages\nmtllib " + stem + ".mtl\n";
  text.reserve(text.size() + 40 * mesh.vertices.size() * (has_normals ? 2 : 1) + 80 * mesh.faces.size());
  for (const Eigen::Vector3f& v : mesh.vertices) AppendLine(&text, "v", {v.x(), v.y(), v.z()});
  for (const Eigen::Vector3f& n : mesh.normals) AppendLine(&text, "vn", {n.x(), n.y(), n.z()});

  // One `vt` per distinct (u, v); corner_vt holds the 1-based index of each face corner's.
  std::unordered_map<uint64_t, int> vt_index;
  std::vector<int> corner_vt(3 * mesh.faces.size());
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const float u = textured.face_uv[f](k, 0), v = textured.face_uv[f](k, 1);
      const auto [it, inserted] = vt_index.emplace(UvKey(u, v), static_cast<int>(vt_index.size()) + 1);
      if (inserted) AppendLine(&text, "vt", {u, v});
      corner_vt[3 * f + k] = it->second;
    }
  }

  int current_page = -1;
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    if (textured.face_page[f] != current_page) {
      current_page = textured.face_page[f];
      text += "usemtl " + PageName(current_page) + "\n";
    }
    text += 'f';
    for (int k = 0; k < 3; ++k) {
      const std::string v = std::to_string(mesh.faces[f][k] + 1);
      text += ' ' + v + '/' + std::to_string(corner_vt[3 * f + k]);
      if (has_normals) text += '/' + v;
    }
    text += '\n';
  }
  return text;
}

// ---------------------------------------------------------------------------------------------
// Reading.

// Where a parse error happened; Fail throws "<path>:<line>: <message>".
struct Location {
  std::string path;
  int line = 0;

  [[noreturn]] void Fail(const std::string& message) const {
    throw InputError(path + ":" + std::to_string(line) + ": " + message);
  }
};

bool IsSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v'; }

std::vector<std::string_view> Tokenize(std::string_view line) {
  std::vector<std::string_view> tokens;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && IsSpace(line[i])) ++i;
    const size_t start = i;
    while (i < line.size() && !IsSpace(line[i])) ++i;
    if (i > start) tokens.push_back(line.substr(start, i - start));
  }
  return tokens;
}

// The text after `keyword` (a token viewing into `line`), trimmed: file and material names may
// hold spaces.
std::string RestOfLine(std::string_view line, std::string_view keyword) {
  std::string_view rest = line.substr(static_cast<size_t>(keyword.data() - line.data()) + keyword.size());
  while (!rest.empty() && IsSpace(rest.front())) rest.remove_prefix(1);
  while (!rest.empty() && IsSpace(rest.back())) rest.remove_suffix(1);
  return std::string(rest);
}

// Calls `on_line(tokens, line)` for every non-empty, non-comment line, with `where->line` set.
template <typename OnLine>
void ForEachLine(const std::string& text, Location* where, const OnLine& on_line) {
  size_t pos = 0;
  where->line = 0;
  while (pos < text.size()) {
    size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    ++where->line;
    const std::string_view line(text.data() + pos, end - pos);
    pos = end + 1;
    const std::vector<std::string_view> tokens = Tokenize(line);
    if (tokens.empty() || tokens[0].front() == '#') continue;
    on_line(tokens, line);
  }
}

// from_chars is locale-independent and rejects trailing garbage below.
template <typename T>
T ParseNumber(std::string_view token, const char* what, const Location& where) {
  T value{};
  const char* begin = token.data();
  if (!token.empty() && token.front() == '+') ++begin;  // from_chars rejects a leading '+'
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(begin, end, value);
  if (ec != std::errc() || ptr != end) {
    where.Fail("cannot parse '" + std::string(token) + "' as " + (std::is_integral_v<T> ? "an integer" : "a number") +
               " (" + what + "); fix or remove the line");
  }
  if constexpr (std::is_floating_point_v<T>) {
    if (!std::isfinite(value)) where.Fail(std::string(what) + " is not finite ('" + std::string(token) + "')");
  }
  return value;
}

// Parses tokens[1..] as between min_count and max_count numbers.
std::vector<float> ParseFloats(const std::vector<std::string_view>& tokens, size_t min_count, size_t max_count,
                               const char* what, const Location& where) {
  const size_t count = tokens.size() - 1;
  if (count < min_count || count > max_count) {
    where.Fail("'" + std::string(tokens[0]) + "' needs " + std::to_string(min_count) +
               (min_count == max_count ? "" : " to " + std::to_string(max_count)) + " numbers (" + what + "), got " +
               std::to_string(count));
  }
  std::vector<float> values;
  for (size_t i = 1; i < tokens.size(); ++i) values.push_back(ParseNumber<float>(tokens[i], what, where));
  return values;
}

// The materials of the MTL files named by `mtllib`, material k sampling page k.
struct MaterialLibrary {
  std::vector<std::string> names;
  std::vector<cv::Mat> pages;

  int Find(const std::string& name) const {
    for (size_t i = 0; i < names.size(); ++i)
      if (names[i] == name) return static_cast<int>(i);
    return -1;
  }
};

// The image file of a `map_Kd` line: the last token when options (-s, -o, ...) precede it,
// otherwise the rest of the line.
std::string MapFileName(const std::vector<std::string_view>& tokens, std::string_view line) {
  if (tokens.size() > 2 && tokens[1].front() == '-') return std::string(tokens.back());
  return RestOfLine(line, tokens[0]);
}

// Reads one MTL file into `library`; `from` is the OBJ line that names it.
void ReadMtl(const std::string& mtl_path, const Location& from, MaterialLibrary* library) {
  std::string text;
  try {
    text = ReadFile(mtl_path);
  } catch (const IoError& e) {
    from.Fail(std::string("cannot read the material library (") + e.what() +
              "); restore it beside the OBJ or write the mesh again");
  }
  Location where{mtl_path, 0};
  const size_t first = library->names.size();
  std::vector<int> newmtl_line;  // per material of this file, for "has no map_Kd"
  ForEachLine(text, &where, [&](const std::vector<std::string_view>& tokens, std::string_view line) {
    if (tokens[0] == "newmtl") {
      const std::string name = RestOfLine(line, tokens[0]);
      if (name.empty()) where.Fail("'newmtl' without a material name");
      if (library->Find(name) >= 0) where.Fail("material '" + name + "' is defined twice; rename one");
      library->names.push_back(name);
      library->pages.emplace_back();
      newmtl_line.push_back(where.line);
    } else if (tokens[0] == "map_Kd") {
      if (library->names.size() == first) where.Fail("'map_Kd' before any 'newmtl'");
      if (tokens.size() < 2) where.Fail("'map_Kd' without a file name");
      const std::string image_path = (fs::path(mtl_path).parent_path() / MapFileName(tokens, line)).string();
      try {
        library->pages.back() = ReadImageColor(image_path);
      } catch (const IoError& e) {
        where.Fail(std::string("cannot read the texture of material '") + library->names.back() + "' (" + e.what() +
                   "); restore the image or write the mesh again");
      }
    }
  });
  for (size_t i = first; i < library->names.size(); ++i) {
    if (library->pages[i].empty()) {
      where.line = newmtl_line[i - first];
      where.Fail("material '" + library->names[i] + "' has no 'map_Kd' texture; every material of a textured "
                 "mesh needs one");
    }
  }
}

// One face corner: 0-based indices, -1 when absent.
struct Corner {
  int v = -1, vt = -1, vn = -1;
};

// Resolves a 1-based or negative (relative) OBJ index against `count` elements defined so far.
int ResolveIndex(std::string_view token, int count, const char* element, const Location& where) {
  const int index = ParseNumber<int>(token, element, where);
  const int resolved = index > 0 ? index - 1 : count + index;
  if (index == 0 || resolved < 0 || resolved >= count) {
    where.Fail("face refers to " + std::string(element) + " " + std::to_string(index) + " but only " +
               std::to_string(count) + " precede it; fix the index or the file");
  }
  return resolved;
}

// Parses "v", "v/vt", "v//vn" or "v/vt/vn".
Corner ParseCorner(std::string_view token, int num_v, int num_vt, int num_vn, const Location& where) {
  std::string_view parts[3];
  int num_parts = 0;
  size_t start = 0;
  while (true) {
    const size_t slash = token.find('/', start);
    if (num_parts == 3) where.Fail("face corner '" + std::string(token) + "' has more than three '/' parts");
    parts[num_parts++] = token.substr(start, slash == std::string_view::npos ? std::string_view::npos : slash - start);
    if (slash == std::string_view::npos) break;
    start = slash + 1;
  }
  Corner corner;
  corner.v = ResolveIndex(parts[0], num_v, "vertex", where);
  if (num_parts > 1 && !parts[1].empty()) corner.vt = ResolveIndex(parts[1], num_vt, "texture coordinate", where);
  if (num_parts > 2 && !parts[2].empty()) corner.vn = ResolveIndex(parts[2], num_vn, "normal", where);
  return corner;
}

// Every corner of a textured face needs a texture coordinate on its page.
void CheckCornerUv(const Corner& corner, std::string_view token, const std::vector<Eigen::Vector2f>& vt,
                   const Location& where) {
  if (corner.vt < 0) {
    where.Fail("face corner '" + std::string(token) + "' has no texture coordinate (expected v/vt or v/vt/vn); "
               "a textured mesh needs one per corner");
  }
  const Eigen::Vector2f& uv = vt[corner.vt];
  if ((uv.array() < 0.f).any() || (uv.array() > 1.f).any()) {
    where.Fail("texture coordinate " + std::to_string(corner.vt + 1) + " (" + std::to_string(uv.x()) + ", " +
               std::to_string(uv.y()) + ") is outside [0, 1]; tiling textures are not supported, every UV must "
               "lie on its atlas page");
  }
}

// Everything an OBJ file holds that a TexturedMesh needs, in file order.
struct ObjContents {
  std::vector<Eigen::Vector3f> v, vn;
  std::vector<Eigen::Vector2f> vt;
  std::vector<std::array<Corner, 3>> triangles;
  std::vector<int> triangle_page;
  MaterialLibrary materials;
};

void ParseObj(const std::string& obj_path, const std::string& text, ObjContents* obj) {
  Location where{obj_path, 0};
  int current_page = -1;
  ForEachLine(text, &where, [&](const std::vector<std::string_view>& tokens, std::string_view line) {
    const std::string_view keyword = tokens[0];
    if (keyword == "v") {
      const std::vector<float> xyz = ParseFloats(tokens, 3, 7, "vertex x y z [w | r g b]", where);
      obj->v.emplace_back(xyz[0], xyz[1], xyz[2]);
    } else if (keyword == "vt") {
      const std::vector<float> uv = ParseFloats(tokens, 1, 3, "texture coordinate u [v [w]]", where);
      obj->vt.emplace_back(uv[0], uv.size() > 1 ? uv[1] : 0.f);
    } else if (keyword == "vn") {
      const std::vector<float> n = ParseFloats(tokens, 3, 3, "normal x y z", where);
      obj->vn.emplace_back(n[0], n[1], n[2]);
    } else if (keyword == "mtllib") {
      const std::string name = RestOfLine(line, keyword);
      if (name.empty()) where.Fail("'mtllib' without a file name");
      ReadMtl((fs::path(obj_path).parent_path() / name).string(), where, &obj->materials);
    } else if (keyword == "usemtl") {
      const std::string name = RestOfLine(line, keyword);
      current_page = obj->materials.Find(name);
      if (current_page < 0) {
        where.Fail("'usemtl " + name + "': no such material in the files named by 'mtllib' lines above " +
                   (obj->materials.names.empty() ? "(there are none)" : "(e.g. '" + obj->materials.names[0] + "')"));
      }
    } else if (keyword == "f") {
      if (tokens.size() < 4) where.Fail("a face needs at least 3 corners, got " + std::to_string(tokens.size() - 1));
      if (current_page < 0) where.Fail("face before any 'usemtl'; every face needs a textured material");
      std::vector<Corner> corners;
      for (size_t i = 1; i < tokens.size(); ++i) {
        corners.push_back(ParseCorner(tokens[i], static_cast<int>(obj->v.size()), static_cast<int>(obj->vt.size()),
                                      static_cast<int>(obj->vn.size()), where));
      }
      for (size_t i = 0; i < corners.size(); ++i) CheckCornerUv(corners[i], tokens[i + 1], obj->vt, where);
      for (size_t i = 1; i + 1 < corners.size(); ++i) {  // a fan around the first corner
        obj->triangles.push_back({corners[0], corners[i], corners[i + 1]});
        obj->triangle_page.push_back(current_page);
      }
    }
    // Other statements (o, g, s, l, p, ...) carry nothing a TexturedMesh holds.
  });
}

// Per-vertex normals from the corners' `vn` when every corner has one, else none. A file whose
// corners use `v/vt/v` with one `vn` per `v` (as written above) keeps its normals exactly.
std::vector<Eigen::Vector3f> VertexNormals(const ObjContents& obj) {
  if (obj.vn.empty()) return {};
  bool same_indices = obj.vn.size() == obj.v.size();
  for (const auto& triangle : obj.triangles) {
    for (const Corner& corner : triangle) {
      if (corner.vn < 0) return {};
      same_indices = same_indices && corner.vn == corner.v;
    }
  }
  if (same_indices) return obj.vn;
  std::vector<Eigen::Vector3f> normals(obj.v.size(), Eigen::Vector3f::Zero());
  std::vector<bool> assigned(obj.v.size(), false);
  for (const auto& triangle : obj.triangles) {
    for (const Corner& corner : triangle) {
      if (assigned[corner.v]) continue;
      normals[corner.v] = obj.vn[corner.vn];
      assigned[corner.v] = true;
    }
  }
  return normals;
}

TexturedMesh ToTexturedMesh(ObjContents&& obj) {
  TexturedMesh textured;
  textured.mesh.normals = VertexNormals(obj);
  textured.mesh.vertices = std::move(obj.v);
  textured.pages = std::move(obj.materials.pages);
  textured.face_page = std::move(obj.triangle_page);
  textured.mesh.faces.reserve(obj.triangles.size());
  textured.face_uv.reserve(obj.triangles.size());
  for (const auto& triangle : obj.triangles) {
    Eigen::Matrix<float, 3, 2> uv;
    for (int k = 0; k < 3; ++k) uv.row(k) = obj.vt[triangle[k].vt].transpose();
    textured.mesh.faces.emplace_back(triangle[0].v, triangle[1].v, triangle[2].v);
    textured.face_uv.push_back(uv);
  }
  return textured;
}

}  // namespace

std::string TexturedMesh::Validate() const {
  const std::string mesh_problem = mesh.Validate();
  if (!mesh_problem.empty()) return mesh_problem;
  const size_t num_faces = mesh.faces.size();
  if (face_uv.size() != num_faces) {
    return "textured mesh has " + std::to_string(face_uv.size()) + " face UV triples for " +
           std::to_string(num_faces) + " faces";
  }
  if (face_page.size() != num_faces) {
    return "textured mesh has " + std::to_string(face_page.size()) + " face pages for " + std::to_string(num_faces) +
           " faces";
  }
  for (size_t page = 0; page < pages.size(); ++page) {
    if (pages[page].empty()) return "atlas page " + std::to_string(page) + " is empty";
    if (pages[page].type() != CV_8UC3) return "atlas page " + std::to_string(page) + " is not 8-bit, 3-channel (CV_8UC3)";
  }
  for (size_t f = 0; f < num_faces; ++f) {
    if (face_page[f] < 0 || static_cast<size_t>(face_page[f]) >= pages.size()) {
      return "face " + std::to_string(f) + " samples atlas page " + std::to_string(face_page[f]) + " but there are " +
             std::to_string(pages.size()) + " pages";
    }
    const Eigen::Matrix<float, 3, 2>& uv = face_uv[f];
    if (!uv.allFinite() || (uv.array() < 0.f).any() || (uv.array() > 1.f).any()) {
      return "face " + std::to_string(f) + " has a UV outside [0, 1]: (" + std::to_string(uv(0, 0)) + ", " +
             std::to_string(uv(0, 1)) + "), (" + std::to_string(uv(1, 0)) + ", " + std::to_string(uv(1, 1)) + "), (" +
             std::to_string(uv(2, 0)) + ", " + std::to_string(uv(2, 1)) + ")";
    }
  }
  return "";
}

void WriteTexturedObj(const TexturedMesh& mesh, const std::string& folder, const std::string& stem) {
  const std::string obj_path = (fs::path(folder) / (stem + ".obj")).string();
  const bool stem_ok = !stem.empty() && std::none_of(stem.begin(), stem.end(), [](char c) {
    return IsSpace(c) || c == '/';
  });
  if (!stem_ok) {
    throw IoError("cannot write " + obj_path + ": the file stem '" + stem +
                  "' must be a non-empty name without spaces or '/' (it is written on the 'mtllib' line)");
  }
  const std::string problem = mesh.Validate();
  if (!problem.empty()) throw IoError("cannot write " + obj_path + ": the textured mesh is inconsistent: " + problem);
  // Pages and materials first: once the OBJ exists, everything it names does too.
  for (size_t page = 0; page < mesh.pages.size(); ++page) {
    WriteImage((fs::path(folder) / (PageName(page) + ".png")).string(), mesh.pages[page]);
  }
  WriteFileAtomic((fs::path(folder) / (stem + ".mtl")).string(), MtlText(mesh.pages.size()));
  WriteFileAtomic(obj_path, ObjText(mesh, stem));
}

TexturedMesh ReadTexturedObj(const std::string& obj_path) {
  std::string text;
  try {
    text = ReadFile(obj_path);
  } catch (const IoError& e) {
    throw InputError(std::string(e.what()) + "; run the texture stage again to write it");
  }
  ObjContents obj;
  ParseObj(obj_path, text, &obj);
  TexturedMesh textured = ToTexturedMesh(std::move(obj));
  const std::string problem = textured.Validate();
  if (!problem.empty()) {
    throw InputError(obj_path + ": not a usable textured mesh: " + problem);
  }
  return textured;
}

}  // namespace ibmr
