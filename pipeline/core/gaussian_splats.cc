// Oriented elliptical splats and their PLY layout (see gaussian_splats.h).
#include "pipeline/core/gaussian_splats.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {

void GaussianSplats::Add(const Eigen::Vector3f& centre, const Eigen::Vector4f& rotation_wxyz,
                         const Eigen::Vector2f& log_radii, float opacity, const Eigen::Vector3f& rgb) {
  position.push_back(centre);
  rotation.push_back(rotation_wxyz);
  log_scale.push_back(log_radii);
  const float o = std::min(std::max(opacity, 1e-4f), 1.0f - 1e-4f);
  opacity_logit.push_back(std::log(o / (1 - o)));
  const size_t start = sh.size();
  sh.resize(start + ShCount() * 3, 0.0f);
  for (int c = 0; c < 3; ++c) sh[start + c] = (rgb[c] - 0.5f) / kShC0;
}

std::string GaussianSplats::Validate() const {
  const size_t n = position.size();
  if (sh_degree < 0 || sh_degree > 3) return "sh_degree " + std::to_string(sh_degree) + " is not in [0, 3]";
  if (rotation.size() != n || log_scale.size() != n || opacity_logit.size() != n || sh.size() != n * ShCount() * 3) {
    return "per-splat arrays of different sizes";
  }
  for (size_t i = 0; i < n; ++i) {
    if (!position[i].allFinite() || !rotation[i].allFinite() || !log_scale[i].allFinite() ||
        !std::isfinite(opacity_logit[i]) || !(rotation[i].norm() > 0)) {
      return "splat " + std::to_string(i) + " holds a non-finite value or a zero rotation";
    }
  }
  return "";
}

Eigen::Vector4f RotationWithNormal(const Eigen::Vector3f& normal) {
  const Eigen::Quaternionf q = Eigen::Quaternionf::FromTwoVectors(Eigen::Vector3f::UnitZ(), normal.normalized());
  return Eigen::Vector4f(q.w(), q.x(), q.y(), q.z());
}

Eigen::Matrix3f RotationMatrix(const Eigen::Vector4f& wxyz) {
  const Eigen::Vector4f q = wxyz.normalized();
  return Eigen::Quaternionf(q[0], q[1], q[2], q[3]).toRotationMatrix();
}

void ShBasis(int degree, const Eigen::Vector3f& d, float* out) {
  out[0] = kShC0;
  if (degree < 1) return;
  const float x = d.x(), y = d.y(), z = d.z();
  constexpr float kC1 = 0.4886025119029199f;
  out[1] = -kC1 * y;
  out[2] = kC1 * z;
  out[3] = -kC1 * x;
  if (degree < 2) return;
  const float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  out[4] = 1.0925484305920792f * xy;
  out[5] = -1.0925484305920792f * yz;
  out[6] = 0.31539156525252005f * (2 * zz - xx - yy);
  out[7] = -1.0925484305920792f * xz;
  out[8] = 0.5462742152960396f * (xx - yy);
  if (degree < 3) return;
  out[9] = -0.5900435899266435f * y * (3 * xx - yy);
  out[10] = 2.890611442640554f * xy * z;
  out[11] = -0.4570457994644658f * y * (4 * zz - xx - yy);
  out[12] = 0.3731763325901154f * z * (2 * zz - 3 * xx - 3 * yy);
  out[13] = -0.4570457994644658f * x * (4 * zz - xx - yy);
  out[14] = 1.445305721320277f * z * (xx - yy);
  out[15] = -0.5900435899266435f * x * (xx - 3 * yy);
}

namespace {

std::vector<std::string> PropertyNames(int sh_degree) {
  std::vector<std::string> names = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  const int rest = 3 * ((sh_degree + 1) * (sh_degree + 1) - 1);
  for (int i = 0; i < rest; ++i) names.push_back("f_rest_" + std::to_string(i));
  for (const char* name : {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"}) {
    names.push_back(name);
  }
  return names;
}

}  // namespace

void WriteGaussianSplatsPly(const std::string& path, const GaussianSplats& splats, const std::string& comment) {
  const std::vector<std::string> names = PropertyNames(splats.sh_degree);
  std::ostringstream header;
  header << "ply\nformat binary_little_endian 1.0\n";
  if (!comment.empty()) header << "comment " << comment << "\n";
  header << "element vertex " << splats.size() << "\n";
  for (const std::string& name : names) header << "property float " << name << "\n";
  header << "end_header\n";
  const int k = splats.ShCount();
  std::string body(splats.size() * names.size() * sizeof(float), '\0');
  float* out = reinterpret_cast<float*>(body.data());
  for (size_t i = 0; i < splats.size(); ++i) {
    const Eigen::Matrix3f r = RotationMatrix(splats.rotation[i]);
    const Eigen::Vector4f q = splats.rotation[i].normalized();
    for (int a = 0; a < 3; ++a) *out++ = splats.position[i][a];
    for (int a = 0; a < 3; ++a) *out++ = r(a, 2);
    const float* sh = splats.Sh(i);
    for (int c = 0; c < 3; ++c) *out++ = sh[c];
    for (int c = 0; c < 3; ++c) {
      for (int j = 1; j < k; ++j) *out++ = sh[j * 3 + c];
    }
    *out++ = splats.opacity_logit[i];
    *out++ = splats.log_scale[i][0];
    *out++ = splats.log_scale[i][1];
    *out++ = kLogThinScale;
    for (int a = 0; a < 4; ++a) *out++ = q[a];
  }
  WriteFileAtomic(path, {header.str(), body});
}

GaussianSplats ReadGaussianSplatsPly(const std::string& path) {
  const std::string bytes = ReadFile(path);
  const size_t end = bytes.find("end_header\n");
  if (bytes.compare(0, 4, "ply\n") != 0 || end == std::string::npos) {
    throw IoError(path + ": not a PLY file (no 'ply' ... 'end_header')");
  }
  std::istringstream header(bytes.substr(0, end));
  std::string line;
  size_t count = 0;
  bool in_vertex = false, binary = false;
  std::map<std::string, int> index;  // property -> position in the record
  int properties = 0;
  while (std::getline(header, line)) {
    std::istringstream words(line);
    std::string word;
    words >> word;
    if (word == "format") {
      std::string format;
      words >> format;
      binary = format == "binary_little_endian";
    } else if (word == "element") {
      std::string element;
      words >> element;
      in_vertex = element == "vertex";
      if (in_vertex) words >> count;
    } else if (word == "property" && in_vertex) {
      std::string type, name;
      words >> type >> name;
      if (type != "float" && type != "float32") {
        throw IoError(path + ": vertex property '" + name + "' is " + type + "; splat files hold floats only");
      }
      index[name] = properties++;
    }
  }
  if (!binary) throw IoError(path + ": only binary_little_endian splat files are read");
  const size_t record = static_cast<size_t>(properties) * sizeof(float);
  const size_t data = end + std::string("end_header\n").size();
  if (bytes.size() < data + count * record) {
    throw IoError(path + ": " + std::to_string(count) + " splats announced but the file holds fewer (truncated?)");
  }
  auto need = [&](const std::string& name) {
    const auto it = index.find(name);
    if (it == index.end()) throw IoError(path + ": no vertex property '" + name + "' (not a Gaussian-splat file?)");
    return it->second;
  };
  int rest = 0;
  while (index.count("f_rest_" + std::to_string(rest))) ++rest;
  GaussianSplats splats;
  splats.sh_degree = rest == 0 ? 0 : rest == 9 ? 1 : rest == 24 ? 2 : rest == 45 ? 3 : -1;
  if (splats.sh_degree < 0) {
    throw IoError(path + ": " + std::to_string(rest) + " f_rest properties: not a whole SH degree (0, 9, 24 or 45)");
  }
  const int k = splats.ShCount();
  const int x = need("x"), dc = need("f_dc_0"), opacity = need("opacity"), s0 = need("scale_0"), s1 = need("scale_1");
  const int r0 = need("rot_0");
  need("y"), need("z"), need("f_dc_1"), need("f_dc_2"), need("rot_1"), need("rot_2"), need("rot_3");
  std::vector<int> rest_index(rest);
  for (int j = 0; j < rest; ++j) rest_index[j] = need("f_rest_" + std::to_string(j));
  splats.position.resize(count);
  splats.rotation.resize(count);
  splats.log_scale.resize(count);
  splats.opacity_logit.resize(count);
  splats.sh.assign(count * k * 3, 0.0f);
  std::vector<float> values(properties);
  for (size_t i = 0; i < count; ++i) {
    std::memcpy(values.data(), bytes.data() + data + i * record, record);
    splats.position[i] = Eigen::Vector3f(values[x], values[index["y"]], values[index["z"]]);
    splats.rotation[i] = Eigen::Vector4f(values[r0], values[index["rot_1"]], values[index["rot_2"]], values[index["rot_3"]]);
    splats.log_scale[i] = Eigen::Vector2f(values[s0], values[s1]);
    splats.opacity_logit[i] = values[opacity];
    float* sh = splats.Sh(i);
    sh[0] = values[dc];
    sh[1] = values[index["f_dc_1"]];
    sh[2] = values[index["f_dc_2"]];
    for (int c = 0; c < 3; ++c) {
      for (int j = 1; j < k; ++j) sh[j * 3 + c] = values[rest_index[c * (k - 1) + (j - 1)]];
    }
  }
  if (const std::string problem = splats.Validate(); !problem.empty()) throw IoError(path + ": " + problem);
  return splats;
}

}  // namespace ibmr
