// PLY reading and writing for point clouds and triangle meshes. Writing always produces the
// binary little-endian layout documented in ply_io.h. Reading parses the header into elements
// and typed properties, then walks the records of every element in order (ascii tokens or
// packed binary), keeping vertex positions, normals, colours, confidence and face indices and
// skipping everything else. Polygons with more than three corners are split into a fan.
#include "pipeline/core/ply_io.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <sstream>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "binary PLY I/O assumes a little-endian host");

// ---------------------------------------------------------------------------------------------
// Writing

// Appends raw little-endian bytes of `value`.
template <typename T>
void Append(std::string* out, T value) {
  out->append(reinterpret_cast<const char*>(&value), sizeof(T));
}

std::string HeaderStart(const std::vector<std::string>& comments) {
  std::string header = "ply\nformat binary_little_endian 1.0\n";
  for (std::string comment : comments) {
    // A newline inside a comment would end the header line early and corrupt the file.
    std::replace(comment.begin(), comment.end(), '\n', ' ');
    std::replace(comment.begin(), comment.end(), '\r', ' ');
    header += "comment " + comment + "\n";
  }
  return header;
}

std::string VertexHeader(size_t count, bool normals, bool colors, bool confidence, bool radius = false) {
  std::string h = "element vertex " + std::to_string(count) + "\n";
  h += "property float x\nproperty float y\nproperty float z\n";
  if (normals) h += "property float nx\nproperty float ny\nproperty float nz\n";
  if (radius) h += "property float radius\n";
  if (colors) h += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  if (confidence) h += "property float confidence\n";
  return h;
}

// Appends the packed vertex records; optional arrays are empty or one entry per vertex.
void AppendVertices(const std::vector<Eigen::Vector3f>& positions, const std::vector<Eigen::Vector3f>& normals,
                    const std::vector<Color3u8>& colors, const std::vector<float>& confidence, std::string* out,
                    const std::vector<float>& radius = {}) {
  const size_t record = 12 + (normals.empty() ? 0 : 12) + (radius.empty() ? 0 : 4) + (colors.empty() ? 0 : 3) +
                        (confidence.empty() ? 0 : 4);
  out->reserve(out->size() + record * positions.size());
  for (size_t i = 0; i < positions.size(); ++i) {
    for (int k = 0; k < 3; ++k) Append<float>(out, positions[i][k]);
    if (!normals.empty()) {
      for (int k = 0; k < 3; ++k) Append<float>(out, normals[i][k]);
    }
    if (!radius.empty()) Append<float>(out, radius[i]);
    if (!colors.empty()) {
      for (int k = 0; k < 3; ++k) Append<uint8_t>(out, colors[i][k]);
    }
    if (!confidence.empty()) Append<float>(out, confidence[i]);
  }
}

void CheckAttributeSize(const std::string& path, const char* what, size_t size, size_t expected) {
  if (size != 0 && size != expected) {
    throw IoError("cannot write " + path + ": " + std::to_string(size) + " " + what + " for " +
                  std::to_string(expected) + " vertices (need none or one per vertex)");
  }
}

// ---------------------------------------------------------------------------------------------
// Reading: header

enum class PlyType { kInt8, kUInt8, kInt16, kUInt16, kInt32, kUInt32, kFloat32, kFloat64 };

bool TypeFromName(const std::string& name, PlyType* type) {
  static const std::pair<const char*, PlyType> kNames[] = {
      {"char", PlyType::kInt8},     {"int8", PlyType::kInt8},       {"uchar", PlyType::kUInt8},
      {"uint8", PlyType::kUInt8},   {"short", PlyType::kInt16},     {"int16", PlyType::kInt16},
      {"ushort", PlyType::kUInt16}, {"uint16", PlyType::kUInt16},   {"int", PlyType::kInt32},
      {"int32", PlyType::kInt32},   {"uint", PlyType::kUInt32},     {"uint32", PlyType::kUInt32},
      {"float", PlyType::kFloat32}, {"float32", PlyType::kFloat32}, {"double", PlyType::kFloat64},
      {"float64", PlyType::kFloat64}};
  for (const auto& entry : kNames) {
    if (name == entry.first) {
      *type = entry.second;
      return true;
    }
  }
  return false;
}

bool IsFloatType(PlyType type) { return type == PlyType::kFloat32 || type == PlyType::kFloat64; }

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;  // the item type for lists
  bool is_list = false;
  PlyType count_type = PlyType::kUInt8;
};

struct PlyElement {
  std::string name;
  size_t count = 0;
  std::vector<PlyProperty> properties;
};

struct PlyHeader {
  bool ascii = false;
  std::vector<PlyElement> elements;
  std::vector<std::string> comments;
  size_t data_offset = 0;  // first byte after "end_header\n"
};

class HeaderParser {
 public:
  HeaderParser(const std::string& path, const std::string& bytes) : path_(path), bytes_(bytes) {}

  PlyHeader Parse() {
    std::string line;
    if (!NextLine(&line) || line != "ply") Fail("the file does not start with \"ply\" (not a PLY file)");
    bool have_format = false;
    while (NextLine(&line)) {
      std::istringstream tokens(line);
      std::string keyword;
      tokens >> keyword;
      if (keyword == "end_header") {
        if (!have_format) Fail("no \"format\" line before end_header");
        header_.data_offset = pos_;
        return header_;
      }
      if (keyword == "format") {
        ParseFormat(&tokens);
        have_format = true;
      } else if (keyword == "comment") {
        header_.comments.push_back(line.size() > 8 ? line.substr(8) : "");
      } else if (keyword == "obj_info" || keyword.empty()) {
        continue;
      } else if (keyword == "element") {
        ParseElement(&tokens);
      } else if (keyword == "property") {
        ParseProperty(&tokens);
      } else {
        Fail("unknown header keyword \"" + keyword + "\"");
      }
    }
    Fail("the header has no end_header line (truncated or not a PLY file)");
    return header_;
  }

 private:
  // Reads the next header line without its "\n" or "\r\n"; false at the end of the file.
  bool NextLine(std::string* line) {
    if (pos_ >= bytes_.size()) return false;
    const size_t end = bytes_.find('\n', pos_);
    if (end == std::string::npos) return false;
    *line = bytes_.substr(pos_, end - pos_);
    if (!line->empty() && line->back() == '\r') line->pop_back();
    pos_ = end + 1;
    ++line_number_;
    return true;
  }

  [[noreturn]] void Fail(const std::string& what) const {
    throw IoError(path_ + ": PLY header line " + std::to_string(line_number_) + ": " + what);
  }

  void ParseFormat(std::istringstream* tokens) {
    std::string format, version;
    *tokens >> format >> version;
    if (format == "ascii") {
      header_.ascii = true;
    } else if (format == "binary_little_endian") {
      header_.ascii = false;
    } else {
      Fail("unsupported format \"" + format + "\" (ascii and binary_little_endian are supported)");
    }
  }

  void ParseElement(std::istringstream* tokens) {
    PlyElement element;
    long long count = -1;
    *tokens >> element.name >> count;
    if (element.name.empty() || tokens->fail() || count < 0) Fail("expected \"element NAME COUNT\"");
    element.count = static_cast<size_t>(count);
    header_.elements.push_back(element);
  }

  void ParseProperty(std::istringstream* tokens) {
    if (header_.elements.empty()) Fail("a property before any element");
    PlyProperty property;
    std::string type_name;
    *tokens >> type_name;
    if (type_name == "list") {
      std::string count_name, item_name;
      *tokens >> count_name >> item_name >> property.name;
      property.is_list = true;
      if (!TypeFromName(count_name, &property.count_type) || IsFloatType(property.count_type)) {
        Fail("unsupported list count type \"" + count_name + "\"");
      }
      if (!TypeFromName(item_name, &property.type)) Fail("unsupported list item type \"" + item_name + "\"");
    } else {
      *tokens >> property.name;
      if (!TypeFromName(type_name, &property.type)) Fail("unsupported property type \"" + type_name + "\"");
    }
    if (property.name.empty()) Fail("a property without a name");
    header_.elements.back().properties.push_back(property);
  }

  const std::string& path_;
  const std::string& bytes_;
  size_t pos_ = 0;
  int line_number_ = 0;
  PlyHeader header_;
};

// ---------------------------------------------------------------------------------------------
// Reading: data

// Reads successive values from the body, as ascii tokens or packed little-endian binary.
class ValueReader {
 public:
  ValueReader(const std::string& path, const std::string& bytes, size_t offset, bool ascii)
      : path_(path), bytes_(bytes), pos_(offset), ascii_(ascii) {}

  // Where the reader is, for error messages.
  void SetContext(const std::string& element, size_t record) {
    element_ = &element;
    record_ = record;
  }

  double Next(PlyType type) { return ascii_ ? NextAscii() : NextBinary(type); }

  // A list length: a whole number in [0, 2^24]; anything else means a corrupt file (and
  // checking here keeps the conversion to an integer well defined).
  size_t NextCount(PlyType type) {
    const double n = Next(type);
    if (!(n >= 0.0 && n <= static_cast<double>(1 << 24)) || n != std::floor(n)) {
      throw IoError(path_ + ": element \"" + *element_ + "\" record " + std::to_string(record_) +
                    ": bad list length " + std::to_string(n));
    }
    return static_cast<size_t>(n);
  }

 private:
  template <typename T>
  double Load() {
    if (bytes_.size() - pos_ < sizeof(T)) Truncated();
    T value;
    std::memcpy(&value, bytes_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return static_cast<double>(value);
  }

  double NextBinary(PlyType type) {
    switch (type) {
      case PlyType::kInt8: return Load<int8_t>();
      case PlyType::kUInt8: return Load<uint8_t>();
      case PlyType::kInt16: return Load<int16_t>();
      case PlyType::kUInt16: return Load<uint16_t>();
      case PlyType::kInt32: return Load<int32_t>();
      case PlyType::kUInt32: return Load<uint32_t>();
      case PlyType::kFloat32: return Load<float>();
      case PlyType::kFloat64: return Load<double>();
    }
    return 0.0;
  }

  double NextAscii() {
    // std::string's buffer is NUL-terminated, so strtod stops at the end of the file.
    const char* begin = bytes_.c_str() + pos_;
    char* end = nullptr;
    const double value = std::strtod(begin, &end);
    if (end == begin) {
      const char* p = begin;
      while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n') ++p;
      if (*p == '\0') Truncated();
      throw IoError(path_ + ": element \"" + *element_ + "\" record " + std::to_string(record_) +
                    ": expected a number, found \"" + std::string(p, std::min<size_t>(std::strlen(p), 16)) + "\"");
    }
    pos_ += static_cast<size_t>(end - begin);
    return value;
  }

  [[noreturn]] void Truncated() const {
    throw IoError(path_ + ": the file ends inside element \"" + *element_ + "\" record " + std::to_string(record_) +
                  " (truncated?)");
  }

  const std::string& path_;
  const std::string& bytes_;
  size_t pos_;
  bool ascii_;
  const std::string* element_ = nullptr;
  size_t record_ = 0;
};

// What the reader keeps from a file.
struct PlyContents {
  std::vector<Eigen::Vector3f> positions;
  std::vector<Eigen::Vector3f> normals;
  std::vector<Color3u8> colors;
  std::vector<float> confidence;
  std::vector<float> radius;
  std::vector<Eigen::Vector3i> faces;
  std::vector<std::string> comments;
};

// Vertex attributes we keep, by the index of their slot in a record.
enum VertexSlot { kX, kY, kZ, kNx, kNy, kNz, kRed, kGreen, kBlue, kConfidence, kRadius, kNumSlots };

int SlotOf(const std::string& name) {
  static const std::pair<const char*, int> kSlots[] = {
      {"x", kX},           {"y", kY},          {"z", kZ},        {"nx", kNx},         {"ny", kNy},
      {"nz", kNz},         {"red", kRed},      {"green", kGreen}, {"blue", kBlue},    {"r", kRed},
      {"g", kGreen},       {"b", kBlue},       {"diffuse_red", kRed}, {"diffuse_green", kGreen},
      {"diffuse_blue", kBlue}, {"confidence", kConfidence}, {"radius", kRadius}};
  for (const auto& entry : kSlots) {
    if (name == entry.first) return entry.second;
  }
  return -1;
}

uint8_t ToColorByte(double value, PlyType type) {
  // Colours stored as floats are in [0, 1] by convention; integer colours are 0..255.
  const double scaled = IsFloatType(type) ? value * 255.0 : value;
  return static_cast<uint8_t>(std::clamp(std::lround(scaled), 0L, 255L));
}

// Skips the remaining values of one property (scalar or list).
void SkipProperty(const PlyProperty& property, ValueReader* reader) {
  if (!property.is_list) {
    reader->Next(property.type);
    return;
  }
  const size_t n = reader->NextCount(property.count_type);
  for (size_t i = 0; i < n; ++i) reader->Next(property.type);
}

void ReadVertices(const std::string& path, const PlyElement& element, ValueReader* reader, PlyContents* out) {
  std::vector<int> slot(element.properties.size());
  bool present[kNumSlots] = {};
  for (size_t p = 0; p < element.properties.size(); ++p) {
    slot[p] = element.properties[p].is_list ? -1 : SlotOf(element.properties[p].name);
    if (slot[p] >= 0) present[slot[p]] = true;
  }
  if (!present[kX] || !present[kY] || !present[kZ]) {
    throw IoError(path + ": element \"vertex\" lacks one of the properties x, y, z");
  }
  const bool has_normals = present[kNx] && present[kNy] && present[kNz];
  const bool has_colors = present[kRed] && present[kGreen] && present[kBlue];
  out->positions.resize(element.count);
  if (has_normals) out->normals.resize(element.count);
  if (has_colors) out->colors.resize(element.count);
  if (present[kConfidence]) out->confidence.resize(element.count);
  if (present[kRadius]) out->radius.resize(element.count);
  for (size_t i = 0; i < element.count; ++i) {
    reader->SetContext(element.name, i);
    double values[kNumSlots] = {};
    uint8_t color[3] = {};
    for (size_t p = 0; p < element.properties.size(); ++p) {
      const PlyProperty& property = element.properties[p];
      if (slot[p] < 0) {
        SkipProperty(property, reader);
        continue;
      }
      values[slot[p]] = reader->Next(property.type);
      if (slot[p] >= kRed && slot[p] <= kBlue) color[slot[p] - kRed] = ToColorByte(values[slot[p]], property.type);
    }
    out->positions[i] = Eigen::Vector3d(values[kX], values[kY], values[kZ]).cast<float>();
    if (has_normals) out->normals[i] = Eigen::Vector3d(values[kNx], values[kNy], values[kNz]).cast<float>();
    if (has_colors) out->colors[i] = Color3u8(color[0], color[1], color[2]);
    if (present[kConfidence]) out->confidence[i] = static_cast<float>(values[kConfidence]);
    if (present[kRadius]) out->radius[i] = static_cast<float>(values[kRadius]);
  }
}

// Indices beyond int become -1, which TriangleMesh::Validate then reports.
int ToIndex(double value) {
  return value >= 0 && value <= static_cast<double>(std::numeric_limits<int>::max()) ? static_cast<int>(value) : -1;
}

void ReadFaces(const std::string& path, const PlyElement& element, ValueReader* reader, PlyContents* out) {
  int list = -1;
  for (size_t p = 0; p < element.properties.size(); ++p) {
    const PlyProperty& property = element.properties[p];
    if (property.is_list && (property.name == "vertex_indices" || property.name == "vertex_index")) {
      list = static_cast<int>(p);
    }
  }
  if (list < 0) throw IoError(path + ": element \"face\" has no list property vertex_indices");
  out->faces.reserve(element.count);
  std::vector<int> polygon;
  for (size_t i = 0; i < element.count; ++i) {
    reader->SetContext(element.name, i);
    for (size_t p = 0; p < element.properties.size(); ++p) {
      const PlyProperty& property = element.properties[p];
      if (static_cast<int>(p) != list) {
        SkipProperty(property, reader);
        continue;
      }
      const size_t n = reader->NextCount(property.count_type);
      if (n < 3) throw IoError(path + ": face " + std::to_string(i) + " has " + std::to_string(n) + " corners");
      polygon.resize(n);
      for (size_t k = 0; k < n; ++k) polygon[k] = ToIndex(reader->Next(property.type));
      // Fan triangulation keeps the winding of convex polygons.
      for (size_t k = 1; k + 1 < n; ++k) out->faces.emplace_back(polygon[0], polygon[k], polygon[k + 1]);
    }
  }
}

PlyContents ReadPly(const std::string& path) {
  const std::string bytes = ReadFile(path);
  const PlyHeader header = HeaderParser(path, bytes).Parse();
  PlyContents contents;
  contents.comments = header.comments;
  ValueReader reader(path, bytes, header.data_offset, header.ascii);
  bool have_vertices = false;
  for (const PlyElement& element : header.elements) {
    // Every record takes at least one byte, so a larger count is a corrupt header; checking
    // here avoids allocating for it. An element without properties has empty records, but a
    // count beyond the data is no more plausible, and looping over 10^14 of them never ends.
    if (element.count > bytes.size() - header.data_offset) {
      throw IoError(path + ": element \"" + element.name + "\" claims " + std::to_string(element.count) +
                    " records but the file has only " + std::to_string(bytes.size() - header.data_offset) +
                    " bytes of data (truncated, or a corrupt header: rewrite the file)");
    }
    if (element.properties.empty() && element.name != "vertex" && element.name != "face") continue;  // no data
    if (element.name == "vertex") {
      ReadVertices(path, element, &reader, &contents);
      have_vertices = true;
    } else if (element.name == "face") {
      ReadFaces(path, element, &reader, &contents);
    } else {
      for (size_t i = 0; i < element.count; ++i) {
        reader.SetContext(element.name, i);
        for (const PlyProperty& property : element.properties) SkipProperty(property, &reader);
      }
    }
  }
  if (!have_vertices) throw IoError(path + ": the PLY file has no \"vertex\" element");
  return contents;
}

}  // namespace

void WritePointCloudPly(const std::string& path, const PointCloud& cloud) {
  const size_t n = cloud.positions.size();
  CheckAttributeSize(path, "normals", cloud.normals.size(), n);
  CheckAttributeSize(path, "colours", cloud.colors.size(), n);
  CheckAttributeSize(path, "confidence values", cloud.confidence.size(), n);
  CheckAttributeSize(path, "radii", cloud.radius.size(), n);
  std::string bytes = HeaderStart(cloud.comments) +
                      VertexHeader(n, !cloud.normals.empty(), !cloud.colors.empty(), !cloud.confidence.empty(),
                                   !cloud.radius.empty()) +
                      "end_header\n";
  AppendVertices(cloud.positions, cloud.normals, cloud.colors, cloud.confidence, &bytes, cloud.radius);
  WriteFileAtomic(path, bytes);
}

PointCloud ReadPointCloudPly(const std::string& path) {
  PlyContents contents = ReadPly(path);
  PointCloud cloud;
  cloud.positions = std::move(contents.positions);
  cloud.normals = std::move(contents.normals);
  cloud.colors = std::move(contents.colors);
  cloud.confidence = std::move(contents.confidence);
  cloud.radius = std::move(contents.radius);
  cloud.comments = std::move(contents.comments);
  return cloud;
}

void WriteMeshPly(const std::string& path, const TriangleMesh& mesh) {
  const std::string problem = mesh.Validate();
  if (!problem.empty()) throw IoError("cannot write " + path + ": " + problem);
  std::string bytes = HeaderStart(mesh.comments) +
                      VertexHeader(mesh.vertices.size(), !mesh.normals.empty(), !mesh.colors.empty(), false) +
                      "element face " + std::to_string(mesh.faces.size()) +
                      "\nproperty list uchar int vertex_indices\nend_header\n";
  AppendVertices(mesh.vertices, mesh.normals, mesh.colors, {}, &bytes);
  bytes.reserve(bytes.size() + 13 * mesh.faces.size());
  for (const Eigen::Vector3i& face : mesh.faces) {
    Append<uint8_t>(&bytes, 3);
    for (int k = 0; k < 3; ++k) Append<int32_t>(&bytes, face[k]);
  }
  WriteFileAtomic(path, bytes);
}

TriangleMesh ReadMeshPly(const std::string& path) {
  PlyContents contents = ReadPly(path);
  TriangleMesh mesh;
  mesh.vertices = std::move(contents.positions);
  mesh.normals = std::move(contents.normals);
  mesh.colors = std::move(contents.colors);
  mesh.faces = std::move(contents.faces);
  mesh.comments = std::move(contents.comments);
  const size_t faces = mesh.faces.size();
  if (const size_t dropped = mesh.DropNonFiniteVertices()) {
    spdlog::warn("{}: {} vertices with a NaN or infinite coordinate and the {} faces using them are left out", path,
                 dropped, faces - mesh.faces.size());
  }
  const std::string problem = mesh.Validate();
  if (!problem.empty()) throw IoError(path + ": " + problem);
  return mesh;
}

}  // namespace ibmr
