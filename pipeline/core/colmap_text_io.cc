// Reads and writes COLMAP's text model (cameras.txt, images.txt, points3D.txt) byte-compatible
// with COLMAP: same comment headers, one record per line, doubles at 17 significant digits so
// that a write/read round trip is exact. Every parse error names file, line number and field.
#include "pipeline/core/colmap_text_io.h"

#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <locale>
#include <sstream>
#include <string_view>
#include <type_traits>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

constexpr char kCamerasFields[] = "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]";
constexpr char kImageFields[] = "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME";
constexpr char kPointFields[] = "POINT3D_ID X Y Z R G B ERROR TRACK[]";

std::string JoinPath(const std::string& folder, const std::string& file) {
  return (fs::path(folder) / file).string();
}

// Where a parse error happened: "<path>:<line>: <message>".
struct Location {
  std::string path;
  int line = 0;

  [[noreturn]] void Fail(const std::string& message) const {
    throw IoError(path + ":" + std::to_string(line) + ": " + message);
  }
};

bool IsSpace(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n'; }

std::string_view Trim(std::string_view s) {
  while (!s.empty() && IsSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && IsSpace(s.back())) s.remove_suffix(1);
  return s;
}

// Whitespace-separated tokens as views into `line`.
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

// from_chars is locale-independent, unlike strtod, and rejects trailing garbage below.
template <typename T>
T ParseNumber(std::string_view token, const char* field, const Location& where) {
  T value{};
  const char* begin = token.data();
  if (!token.empty() && token.front() == '+') ++begin;  // from_chars rejects a leading '+'
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(begin, end, value);
  if (ec != std::errc() || ptr != end) {
    where.Fail(std::string("field ") + field + ": cannot parse '" + std::string(token) + "' as " +
               (std::is_integral_v<T> ? "an integer" : "a number"));
  }
  // from_chars reads "nan" and "inf", which no field of a model means: a NaN pose or point would
  // pass every range test downstream and blank the views or centres computed from it.
  if constexpr (std::is_floating_point_v<T>) {
    if (!std::isfinite(value)) where.Fail(std::string("field ") + field + ": '" + std::string(token) + "' is not a finite number");
  }
  return value;
}

std::string ValidModelNames() {
  std::string names;
  for (CameraModelId id : {CameraModelId::kSimplePinhole, CameraModelId::kPinhole,
                           CameraModelId::kSimpleRadial, CameraModelId::kRadial,
                           CameraModelId::kOpenCV, CameraModelId::kFullOpenCV}) {
    names += (names.empty() ? "" : ", ") + CameraModelName(id);
  }
  return names;
}

// A file read line by line, tracking the line number for error messages.
class LineReader {
 public:
  explicit LineReader(const std::string& path) : stream_(path) { where_.path = path; }
  bool is_open() const { return stream_.is_open(); }
  const Location& where() const { return where_; }

  // Next raw line (possibly empty); false at end of file.
  bool NextRaw(std::string* line) {
    if (!std::getline(stream_, *line)) return false;
    ++where_.line;
    return true;
  }
  // Next line that is neither empty nor a comment.
  bool NextData(std::string* line) {
    while (NextRaw(line)) {
      const std::string_view trimmed = Trim(*line);
      if (!trimmed.empty() && trimmed.front() != '#') return true;
    }
    return false;
  }

 private:
  std::ifstream stream_;
  Location where_;
};

[[noreturn]] void FailMissing(const std::string& folder, const std::string& file) {
  const std::string bin = fs::path(file).replace_extension(".bin").string();
  std::string message = JoinPath(folder, file) + ": file not found. A COLMAP text model needs " +
                        "cameras.txt and images.txt (points3D.txt is optional) in '" + folder + "'";
  if (fs::exists(JoinPath(folder, bin))) {
    message += "; only " + bin + " is there: convert it with 'colmap model_converter --input_path " +
               folder + " --output_path " + folder + " --output_type TXT'";
  } else {
    message += "; run import (or sfm) first, or point the input at a COLMAP sparse folder";
  }
  throw IoError(message);
}

LineReader OpenOrFail(const std::string& folder, const std::string& file) {
  LineReader reader(JoinPath(folder, file));
  if (!reader.is_open()) {
    if (!fs::exists(JoinPath(folder, file))) FailMissing(folder, file);
    throw IoError(JoinPath(folder, file) + ": cannot open for reading (permissions?)");
  }
  return reader;
}

Camera ParseCamera(const std::vector<std::string_view>& tokens, const Location& where) {
  if (tokens.size() < 4) {
    where.Fail("expected at least 4 fields '" + std::string(kCamerasFields) + "', got " +
               std::to_string(tokens.size()));
  }
  Camera camera;
  camera.camera_id = ParseNumber<int>(tokens[0], "CAMERA_ID", where);
  if (!CameraModelFromName(std::string(tokens[1]), &camera.model)) {
    where.Fail("field MODEL: unknown camera model '" + std::string(tokens[1]) +
               "'; valid models are " + ValidModelNames());
  }
  camera.width = ParseNumber<int>(tokens[2], "WIDTH", where);
  camera.height = ParseNumber<int>(tokens[3], "HEIGHT", where);
  for (size_t i = 4; i < tokens.size(); ++i) {
    camera.params.push_back(ParseNumber<double>(tokens[i], "PARAMS", where));
  }
  const std::string error = camera.Validate();
  if (!error.empty()) where.Fail(error);
  return camera;
}

std::map<int, Camera> ReadCameras(const std::string& folder) {
  LineReader reader = OpenOrFail(folder, "cameras.txt");
  std::map<int, Camera> cameras;
  std::string line;
  while (reader.NextData(&line)) {
    Camera camera = ParseCamera(Tokenize(line), reader.where());
    if (cameras.count(camera.camera_id)) {
      reader.where().Fail("field CAMERA_ID: duplicate camera id " +
                          std::to_string(camera.camera_id));
    }
    cameras.emplace(camera.camera_id, std::move(camera));
  }
  return cameras;
}

// "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"; the name is the rest of the line.
Image ParseImageHeader(const std::string& line, const Location& where) {
  const std::vector<std::string_view> tokens = Tokenize(line);
  if (tokens.size() < 10) {
    where.Fail("expected 10 fields '" + std::string(kImageFields) + "', got " +
               std::to_string(tokens.size()));
  }
  const char* kNames[] = {"QW", "QX", "QY", "QZ", "TX", "TY", "TZ"};
  double v[7];
  for (int i = 0; i < 7; ++i) v[i] = ParseNumber<double>(tokens[i + 1], kNames[i], where);
  const Eigen::Quaterniond q(v[0], v[1], v[2], v[3]);
  if (!(q.norm() > 1e-12 && std::isfinite(q.norm()))) {
    where.Fail("fields QW QX QY QZ: quaternion has zero or overflowing length");
  }
  Image image;
  image.image_id = ParseNumber<int>(tokens[0], "IMAGE_ID", where);
  // Keep a quaternion that is already unit bit-for-bit (Rigid3d's constructor would
  // re-normalise and change the last digit), so that read-write-read is exact.
  image.cam_from_world.rotation = std::abs(q.norm() - 1) <= 1e-14 ? q : q.normalized();
  image.cam_from_world.translation = Eigen::Vector3d(v[4], v[5], v[6]);
  image.camera_id = ParseNumber<int>(tokens[8], "CAMERA_ID", where);
  const size_t name_start = static_cast<size_t>(tokens[9].data() - line.data());
  image.name = std::string(Trim(std::string_view(line).substr(name_start)));
  return image;
}

// "X Y POINT3D_ID" triples; an empty line means no observations.
std::vector<Point2D> ParsePoints2D(const std::string& line, const Location& where) {
  const std::vector<std::string_view> tokens = Tokenize(line);
  if (tokens.size() % 3 != 0) {
    where.Fail("expected POINTS2D[] as (X Y POINT3D_ID) triples, got " +
               std::to_string(tokens.size()) + " values");
  }
  std::vector<Point2D> points(tokens.size() / 3);
  for (size_t i = 0; i < points.size(); ++i) {
    points[i].xy.x() = ParseNumber<double>(tokens[3 * i], "X", where);
    points[i].xy.y() = ParseNumber<double>(tokens[3 * i + 1], "Y", where);
    points[i].point3D_id = ParseNumber<int64_t>(tokens[3 * i + 2], "POINT3D_ID", where);
  }
  return points;
}

std::map<int, Image> ReadImages(const std::string& folder) {
  LineReader reader = OpenOrFail(folder, "images.txt");
  std::map<int, Image> images;
  std::string line;
  while (reader.NextData(&line)) {
    Image image = ParseImageHeader(line, reader.where());
    if (images.count(image.image_id)) {
      reader.where().Fail("field IMAGE_ID: duplicate image id " + std::to_string(image.image_id));
    }
    // As COLMAP: the line after the header always holds the observations, even when empty.
    if (reader.NextRaw(&line)) image.points2D = ParsePoints2D(line, reader.where());
    images.emplace(image.image_id, std::move(image));
  }
  return images;
}

std::pair<int64_t, Point3D> ParsePoint3D(const std::string& line, const Location& where) {
  const std::vector<std::string_view> tokens = Tokenize(line);
  if (tokens.size() < 8 || (tokens.size() - 8) % 2 != 0) {
    where.Fail("expected '" + std::string(kPointFields) +
               "' with TRACK[] as (IMAGE_ID POINT2D_IDX) pairs, got " +
               std::to_string(tokens.size()) + " fields");
  }
  Point3D point;
  const int64_t point_id = ParseNumber<int64_t>(tokens[0], "POINT3D_ID", where);
  const char* kXyz[] = {"X", "Y", "Z"};
  for (int i = 0; i < 3; ++i) point.xyz[i] = ParseNumber<double>(tokens[1 + i], kXyz[i], where);
  const char* kColor[] = {"R", "G", "B"};
  for (int i = 0; i < 3; ++i) {
    const int c = ParseNumber<int>(tokens[4 + i], kColor[i], where);
    if (c < 0 || c > 255) where.Fail(std::string("field ") + kColor[i] + ": " +
                                     std::to_string(c) + " is outside [0, 255]");
    point.color[i] = static_cast<uint8_t>(c);
  }
  point.error = ParseNumber<double>(tokens[7], "ERROR", where);
  for (size_t i = 8; i < tokens.size(); i += 2) {
    TrackElement element;
    element.image_id = ParseNumber<int>(tokens[i], "TRACK IMAGE_ID", where);
    element.point2D_idx = ParseNumber<int>(tokens[i + 1], "TRACK POINT2D_IDX", where);
    point.track.push_back(element);
  }
  return {point_id, std::move(point)};
}

// points3D.txt is optional: a model of cameras and poses only is valid input.
std::map<int64_t, Point3D> ReadPoints(const std::string& folder) {
  std::map<int64_t, Point3D> points;
  if (!fs::exists(JoinPath(folder, "points3D.txt"))) return points;
  LineReader reader = OpenOrFail(folder, "points3D.txt");
  std::string line;
  while (reader.NextData(&line)) {
    auto [point_id, point] = ParsePoint3D(line, reader.where());
    if (!points.emplace(point_id, std::move(point)).second) {
      reader.where().Fail("field POINT3D_ID: duplicate point id " + std::to_string(point_id));
    }
  }
  return points;
}

// Without points3D.txt the observations' 3D points are unknown: mark them untriangulated so
// that the model stays consistent (SparseModel::Validate) instead of pointing at nothing.
void ForgetTriangulations(std::map<int, Image>* images) {
  for (auto& [image_id, image] : *images) {
    for (Point2D& point : image.points2D) point.point3D_id = -1;
  }
}

// A stream that writes '.' decimals and 17 significant digits whatever the global locale.
std::ostringstream MakeStream() {
  std::ostringstream out;
  out.imbue(std::locale::classic());
  out.precision(17);
  return out;
}

std::string FormatCameras(const SparseModel& model) {
  std::ostringstream out = MakeStream();
  out << "# Camera list with one line of data per camera:\n"
      << "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
      << "# Number of cameras: " << model.cameras.size() << "\n";
  for (const auto& [camera_id, camera] : model.cameras) {
    out << camera_id << " " << CameraModelName(camera.model) << " " << camera.width << " "
        << camera.height;
    for (double p : camera.params) out << " " << p;
    out << "\n";
  }
  return out.str();
}

std::string FormatImages(const SparseModel& model) {
  size_t num_observations = 0;
  for (const auto& [image_id, image] : model.images) num_observations += image.points2D.size();
  std::ostringstream out = MakeStream();
  out << "# Image list with two lines of data per image:\n"
      << "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
      << "#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
      << "# Number of images: " << model.images.size() << ", mean observations per image: "
      << (model.images.empty() ? 0.0 : double(num_observations) / model.images.size()) << "\n";
  for (const auto& [image_id, image] : model.images) {
    const Eigen::Quaterniond& q = image.cam_from_world.rotation;
    const Eigen::Vector3d& t = image.cam_from_world.translation;
    out << image_id << " " << q.w() << " " << q.x() << " " << q.y() << " " << q.z() << " "
        << t.x() << " " << t.y() << " " << t.z() << " " << image.camera_id << " " << image.name
        << "\n";
    for (size_t i = 0; i < image.points2D.size(); ++i) {
      const Point2D& p = image.points2D[i];
      out << (i ? " " : "") << p.xy.x() << " " << p.xy.y() << " " << p.point3D_id;
    }
    out << "\n";
  }
  return out.str();
}

std::string FormatPoints(const SparseModel& model) {
  size_t track_sum = 0;
  for (const auto& [point_id, point] : model.points) track_sum += point.track.size();
  std::ostringstream out = MakeStream();
  out << "# 3D point list with one line of data per point:\n"
      << "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
      << "# Number of points: " << model.points.size() << ", mean track length: "
      << (model.points.empty() ? 0.0 : double(track_sum) / model.points.size()) << "\n";
  for (const auto& [point_id, point] : model.points) {
    out << point_id << " " << point.xyz.x() << " " << point.xyz.y() << " " << point.xyz.z();
    for (int i = 0; i < 3; ++i) out << " " << static_cast<int>(point.color[i]);
    out << " " << point.error;
    for (const TrackElement& e : point.track) out << " " << e.image_id << " " << e.point2D_idx;
    out << "\n";
  }
  return out.str();
}

}  // namespace

std::map<int, Camera> ReadCamerasText(const std::string& folder) { return ReadCameras(folder); }

SparseModel ReadSparseModelText(const std::string& folder) {
  SparseModel model;
  model.cameras = ReadCameras(folder);
  model.images = ReadImages(folder);
  model.points = ReadPoints(folder);
  if (!fs::exists(JoinPath(folder, "points3D.txt"))) ForgetTriangulations(&model.images);
  const std::string error = model.Validate();
  if (!error.empty()) throw IoError(folder + ": inconsistent COLMAP model: " + error);
  return model;
}

void WriteSparseModelText(const std::string& folder, const SparseModel& model) {
  WriteFileAtomic(JoinPath(folder, "cameras.txt"), FormatCameras(model));
  WriteFileAtomic(JoinPath(folder, "images.txt"), FormatImages(model));
  WriteFileAtomic(JoinPath(folder, "points3D.txt"), FormatPoints(model));
}

}  // namespace ibmr
