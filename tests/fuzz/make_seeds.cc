// Writes the seed corpus of every fuzz harness: small valid files of each format, made for the
// purpose (a few hundred bytes to a few KB each, so that a harness runs thousands of inputs a
// second), mostly through the project's own writers and by hand where a reader accepts more than
// the writers produce (ascii PLY, lists of other types, PNG bit depths and channel counts).
// Each seed is read back with its harness's reader before the program reports success.
// Usage: fuzz_seeds OUT_DIR   (writes OUT_DIR/<harness>/<seed>; scripts/fuzz.sh runs it)
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/imgcodecs.hpp>  // the IMWRITE_ flags; encoding through image_codecs.h
#include <string>
#include <vector>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/image_codecs.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/nerf_formats.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/runner/record.h"
#include "stages/carve/carve.h"
#include "stages/import/import.h"

namespace fs = std::filesystem;

namespace {

fs::path out_dir;
int written = 0;

void Put(const std::string& harness, const std::string& name, const std::string& bytes) {
  fs::create_directories(out_dir / harness);
  std::ofstream(out_dir / harness / name, std::ios::binary) << bytes;
  ++written;
}

// --- PNG by hand (stored deflate blocks): every bit depth and colour type of the PNG spec, which
// OpenCV's writer does not all produce (1/2/4-bit grey, palette, grey + alpha, 16-bit grey + alpha).
uint32_t Crc32(const std::string& data) {
  uint32_t crc = 0xffffffffu;
  for (const unsigned char c : data) {
    crc ^= c;
    for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
  }
  return crc ^ 0xffffffffu;
}

std::string BigEndian32(uint32_t v) {
  return std::string{static_cast<char>(v >> 24), static_cast<char>(v >> 16), static_cast<char>(v >> 8), static_cast<char>(v)};
}

std::string Chunk(const std::string& type, const std::string& data) {
  return BigEndian32(static_cast<uint32_t>(data.size())) + type + data + BigEndian32(Crc32(type + data));
}

std::string Png(int width, int height, int bit_depth, int color_type, const std::string& palette = "") {
  const int samples = color_type == 0 ? 1 : color_type == 2 ? 3 : color_type == 3 ? 1 : color_type == 4 ? 2 : 4;
  const size_t row_bytes = (static_cast<size_t>(width) * samples * bit_depth + 7) / 8;
  std::string raw;
  for (int y = 0; y < height; ++y) {
    raw.push_back(static_cast<char>(y % 5));  // each of the five row filters once
    for (size_t i = 0; i < row_bytes; ++i) raw.push_back(static_cast<char>((i * 37 + y * 11) & 0xff));
  }
  std::string zlib = "\x78\x01";
  zlib.push_back(1);  // one final stored block
  const uint16_t len = static_cast<uint16_t>(raw.size());
  zlib += std::string{static_cast<char>(len & 0xff), static_cast<char>(len >> 8), static_cast<char>(~len & 0xff),
                      static_cast<char>((~len >> 8) & 0xff)};
  zlib += raw;
  uint32_t a = 1, b = 0;
  for (const unsigned char c : raw) {
    a = (a + c) % 65521;
    b = (b + a) % 65521;
  }
  zlib += BigEndian32((b << 16) | a);
  std::string ihdr = BigEndian32(width) + BigEndian32(height);
  ihdr += std::string{static_cast<char>(bit_depth), static_cast<char>(color_type), 0, 0, 0};
  std::string png = "\x89PNG\r\n\x1a\n";
  png += Chunk("IHDR", ihdr);
  if (!palette.empty()) png += Chunk("PLTE", palette);
  png += Chunk("IDAT", zlib);
  return png + Chunk("IEND", "");
}

std::string Encode(const std::string& ext, const cv::Mat& image, const std::vector<int>& params = {}) {
  std::vector<uchar> bytes;
  if (!ibmr::EncodeImage(ext, image, &bytes, params)) throw std::runtime_error("cannot encode " + ext);
  return std::string(bytes.begin(), bytes.end());
}

cv::Mat Pattern(int width, int height, int type) {
  cv::Mat image(height, width, type);
  const double top = CV_MAT_DEPTH(type) == CV_16U ? 65535.0 : 255.0;
  std::vector<cv::Mat> planes;
  for (int c = 0; c < CV_MAT_CN(type); ++c) {
    cv::Mat plane(height, width, CV_MAKETYPE(CV_MAT_DEPTH(type), 1));
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        const double v = top * (((x * 7 + y * 13 + c * 5) % 16) / 15.0);
        if (CV_MAT_DEPTH(type) == CV_16U) plane.at<uint16_t>(y, x) = static_cast<uint16_t>(v);
        else plane.at<uint8_t>(y, x) = static_cast<uint8_t>(v);
      }
    planes.push_back(plane);
  }
  cv::merge(planes, image);
  return image;
}

void Images() {
  // PNG: grey 1, 2, 4, 8, 16 bit; RGB 8, 16; palette 4, 8; grey + alpha 8, 16; RGBA 8, 16.
  const std::string palette = std::string("\x00\x00\x00\xff\x00\x00\x00\xff\x00\x00\x00\xff", 12) + "\xff\xff\xff";
  const struct { int depth, type; const char* name; } kPngs[] = {
      {1, 0, "grey1"}, {2, 0, "grey2"}, {4, 0, "grey4"}, {8, 0, "grey8"}, {16, 0, "grey16"},
      {8, 2, "rgb8"},  {16, 2, "rgb16"}, {4, 3, "palette4"}, {8, 3, "palette8"}, {8, 4, "grey_alpha8"},
      {16, 4, "grey_alpha16"}, {8, 6, "rgba8"}, {16, 6, "rgba16"}};
  for (const auto& png : kPngs) {
    Put("image", std::string(png.name) + ".png", Png(7, 5, png.depth, png.type, png.type == 3 ? palette : ""));
  }
  // OpenCV's own encoders: JPEG grey and colour (baseline, progressive, optimised, restart markers), PGM/PPM 8 and
  // 16 bit (binary and ascii), PNG with real compression, BMP.
  Put("image", "grey.jpg", Encode(".jpg", Pattern(16, 8, CV_8UC1)));
  Put("image", "colour.jpg", Encode(".jpg", Pattern(16, 8, CV_8UC3)));
  Put("image", "progressive.jpg", Encode(".jpg", Pattern(16, 16, CV_8UC3), {cv::IMWRITE_JPEG_PROGRESSIVE, 1}));
  Put("image", "optimized_q100.jpg",
      Encode(".jpg", Pattern(9, 7, CV_8UC3), {cv::IMWRITE_JPEG_QUALITY, 100, cv::IMWRITE_JPEG_OPTIMIZE, 1}));
  Put("image", "restarts.jpg", Encode(".jpg", Pattern(24, 16, CV_8UC1), {cv::IMWRITE_JPEG_RST_INTERVAL, 1}));
  Put("image", "grey8.pgm", Encode(".pgm", Pattern(6, 4, CV_8UC1)));
  Put("image", "grey16.pgm", Encode(".pgm", Pattern(6, 4, CV_16UC1)));
  Put("image", "grey8_ascii.pgm", Encode(".pgm", Pattern(5, 3, CV_8UC1), {cv::IMWRITE_PXM_BINARY, 0}));
  Put("image", "colour8.ppm", Encode(".ppm", Pattern(6, 4, CV_8UC3)));
  Put("image", "colour16.ppm", Encode(".ppm", Pattern(6, 4, CV_16UC3)));
  Put("image", "rgba_deflate.png", Encode(".png", Pattern(8, 8, CV_8UC4)));
  Put("image", "colour.bmp", Encode(".bmp", Pattern(5, 3, CV_8UC3)));
}

// --- PLY: meshes and clouds, ascii (by hand) and binary little endian (the writers and by hand).
void Plys(const fs::path& scratch) {
  ibmr::TriangleMesh mesh;
  mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  mesh.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  ibmr::WriteMeshPly((scratch / "m.ply").string(), mesh);
  Put("ply", "tetrahedron_binary.ply", ibmr::ReadFile((scratch / "m.ply").string()));
  mesh.ComputeVertexNormals();
  mesh.colors = {{255, 0, 0}, {0, 255, 0}, {0, 0, 255}, {9, 9, 9}};
  mesh.comments = {"ibmr conservative_hull 1"};
  ibmr::WriteMeshPly((scratch / "m.ply").string(), mesh);
  Put("ply", "tetrahedron_normals_colours_binary.ply", ibmr::ReadFile((scratch / "m.ply").string()));

  ibmr::PointCloud cloud;
  cloud.positions = {{0, 0, 0}, {1, 2, 3}, {-1, 0.5f, 2}};
  ibmr::WritePointCloudPly((scratch / "c.ply").string(), cloud);
  Put("ply", "cloud_binary.ply", ibmr::ReadFile((scratch / "c.ply").string()));
  cloud.normals = {{0, 0, 1}, {0, 1, 0}, {1, 0, 0}};
  cloud.colors = {{1, 2, 3}, {4, 5, 6}, {7, 8, 9}};
  cloud.radius = {0.1f, 0.2f, 0.3f};
  cloud.confidence = {1, 0.5f, 0.25f};
  ibmr::WritePointCloudPly((scratch / "c.ply").string(), cloud);
  Put("ply", "surfels_binary.ply", ibmr::ReadFile((scratch / "c.ply").string()));

  Put("ply", "triangle_ascii.ply",
      "ply\nformat ascii 1.0\ncomment a triangle\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  Put("ply", "quad_colours_ascii.ply",
      "ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\n"
      "property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\n"
      "property uchar blue\nelement face 1\nproperty list uint8 uint32 vertex_index\nend_header\n"
      "0 0 0 0 0 1 255 0 0\n1 0 0 0 0 1 0 255 0\n1 1 0 0 0 1 0 0 255\n0 1 0 0 0 1 9 9 9\n4 0 1 2 3\n");
  Put("ply", "cloud_ascii.ply",
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
      "property float confidence\nproperty float radius\nproperty float diffuse_red\nproperty float "
      "diffuse_green\nproperty float diffuse_blue\nend_header\n1 2 3 0.5 0.1 1 0 0.5\n-1e3 2.5e-3 7 1 1 0 1 0\n");
  Put("ply", "extra_element_ascii.ply",
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "property int16 quality\nelement face 1\nproperty list uchar int vertex_indices\nproperty uchar flags\n"
      "element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0 7\n1 0 0 8\n0 1 0 9\n"
      "3 0 1 2 1\n0 1\n");
  // Binary by hand: int16/uint16/int32 properties and a uint16 list count.
  std::string binary = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                       "property float z\nproperty ushort quality\nproperty short id\nelement face 1\n"
                       "property list ushort int vertex_indices\nend_header\n";
  auto append = [&binary](const auto value) { binary.append(reinterpret_cast<const char*>(&value), sizeof(value)); };
  const float xyz[3][3] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  for (int v = 0; v < 3; ++v) {
    for (const float c : xyz[v]) append(c);
    append(static_cast<uint16_t>(v * 100));
    append(static_cast<int16_t>(-v));
  }
  append(static_cast<uint16_t>(3));
  for (int32_t i = 0; i < 3; ++i) append(i);
  Put("ply", "triangle_types_binary.ply", binary);
}

// --- COLMAP text model (cameras, images, points as the harness splits them) and arrays.
ibmr::SparseModel Model(ibmr::CameraModelId model, int images, int points) {
  ibmr::SparseModel sparse;
  ibmr::Camera camera;
  camera.model = model;
  camera.width = 64;
  camera.height = 48;
  const std::vector<double> params = {50, 52, 32, 24, 0.01, -0.002, 0.001, 0.0005, 0.0001, 0, 0, 0};
  camera.params.assign(params.begin(), params.begin() + ibmr::CameraModelNumParams(model));
  sparse.cameras[1] = camera;
  for (int i = 1; i <= images; ++i) {
    ibmr::Image image;
    image.image_id = i;
    image.camera_id = 1;
    image.name = "view_" + std::to_string(i) + ".png";
    image.cam_from_world.translation = Eigen::Vector3d(0.1 * i, -0.2, 3);
    image.cam_from_world.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.2 * i, Eigen::Vector3d::UnitY()));
    sparse.images[i] = image;
  }
  for (int p = 1; p <= points; ++p) {
    ibmr::Point3D point;
    point.xyz = Eigen::Vector3d(0.1 * p, 0.2, -0.3 * p);
    point.color = {static_cast<uint8_t>(10 * p), 20, 30};
    point.error = 0.5;
    for (int i = 1; i <= images; ++i) {
      sparse.images[i].points2D.push_back({Eigen::Vector2d(10.0 + p, 20.0 + i), static_cast<int64_t>(p)});
      point.track.push_back({i, static_cast<int>(sparse.images[i].points2D.size()) - 1});
    }
    sparse.points[p] = point;
  }
  return sparse;
}

void ColmapAndNerf(const fs::path& scratch) {
  using ibmr::CameraModelId;
  const struct { CameraModelId model; int images, points; const char* name; } kModels[] = {
      {CameraModelId::kSimplePinhole, 1, 0, "simple_pinhole"}, {CameraModelId::kPinhole, 2, 2, "pinhole_points"},
      {CameraModelId::kSimpleRadial, 3, 1, "simple_radial"},   {CameraModelId::kRadial, 2, 0, "radial"},
      {CameraModelId::kOpenCV, 2, 3, "opencv"},                {CameraModelId::kFullOpenCV, 1, 1, "full_opencv"}};
  for (const auto& m : kModels) {
    const ibmr::SparseModel model = Model(m.model, m.images, m.points);
    const fs::path folder = scratch / m.name;
    ibmr::WriteSparseModelText(folder.string(), model);
    Put("colmap_text", m.name,
        ibmr::ReadFile((folder / "cameras.txt").string()) + "\n%%\n" + ibmr::ReadFile((folder / "images.txt").string()) +
            "\n%%\n" + ibmr::ReadFile((folder / "points3D.txt").string()));
    if (m.model == CameraModelId::kPinhole || m.model == CameraModelId::kSimplePinhole || m.model == CameraModelId::kOpenCV) {
      Put("transforms", std::string(m.name) + ".json", ibmr::WriteTransformsJson(model, "images/"));
    }
  }
  // transforms.json as other tools write it: Blender (camera_angle_x, 4x4 lists), per-frame intrinsics.
  Put("transforms", "blender.json",
      R"({"camera_angle_x": 0.69, "frames": [{"file_path": "./train/r_0", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]},)"
      R"( {"file_path": "./train/r_1.png", "transform_matrix": [[0,0,1,4],[0,1,0,0],[-1,0,0,0],[0,0,0,1]]}]})");
  Put("transforms", "per_frame.json",
      R"({"frames": [{"file_path": "images/a.png", "fl_x": 50, "fl_y": 51, "cx": 32, "cy": 24, "w": 64, "h": 48,)"
      R"( "k1": 0.01, "k2": 0.001, "p1": 0, "p2": 0, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,2],[0,0,0,1]]}]})");

  // poses_bounds.npy: the harness asks for three images at downscale 2.
  for (const auto& [name, focal] : {std::pair<const char*, double>{"square", 40}, {"wide", 25}, {"long", 120},
                                    {"near", 60}, {"far", 33}}) {
    ibmr::SparseModel model = Model(CameraModelId::kSimplePinhole, 3, 0);
    model.cameras[1].params = {focal, 32, 24};
    std::vector<std::string> names;
    for (const auto& [id, image] : model.images) names.push_back(image.name);
    Put("poses_bounds", std::string(name) + ".npy",
        ibmr::WritePosesBounds(model, names, {{0.5, 10}, {focal / 100, focal}, {1, 2}}));
  }

  // COLMAP arrays: depth (1 channel), normals (3), odd sizes.
  const struct { int w, h, c; const char* name; } kArrays[] = {
      {4, 3, 1, "depth_4x3"}, {1, 1, 1, "depth_1x1"}, {3, 2, 3, "normal_3x2"}, {7, 1, 1, "row_7x1"}, {2, 5, 3, "normal_2x5"}};
  for (const auto& a : kArrays) {
    ibmr::FloatMap map(a.w, a.h, a.c);
    for (size_t i = 0; i < map.data.size(); ++i) map.data[i] = 0.5f + 0.25f * static_cast<float>(i % 7);
    ibmr::WriteColmapArray((scratch / "a.bin").string(), map);
    Put("colmap_array", std::string(a.name) + ".bin", ibmr::ReadFile((scratch / "a.bin").string()));
  }
  // PFM: little and big endian (negative and positive scale), NaN and infinity included.
  for (const auto& [w, h, name] : {std::tuple<int, int, const char*>{4, 3, "4x3"}, {1, 1, "1x1"}, {5, 2, "5x2"}}) {
    cv::Mat image(h, w, CV_32FC1);
    for (int i = 0; i < w * h; ++i) image.at<float>(i) = 1.5f * static_cast<float>(i) - 2.0f;
    if (w * h > 2) image.at<float>(1) = std::numeric_limits<float>::infinity();
    ibmr::WritePfm((scratch / "p.pfm").string(), image);
    Put("pfm", std::string(name) + ".pfm", ibmr::ReadFile((scratch / "p.pfm").string()));
  }
  std::string big = "Pf\n2 2\n1.0\n";
  for (const uint32_t bits : {0x3f800000u, 0x40000000u, 0x7fc00000u, 0xbf800000u}) big += BigEndian32(bits);
  Put("pfm", "big_endian_2x2.pfm", big);
  std::string little = "Pf\n3 1\n-2.5\n";
  for (const float v : {0.f, 1.f, -3.f}) little.append(reinterpret_cast<const char*>(&v), 4);
  Put("pfm", "scaled_3x1.pfm", little);
}

// --- Import's text formats: Middlebury _par.txt and Strecha .camera.
void ImportTexts() {
  const std::string k = "1520.4 0 302.32 0 1525.9 246.87 0 0 1";
  const std::string r[] = {"1 0 0 0 1 0 0 0 1", "0 0 1 0 1 0 -1 0 0", "0.5 -0.866025 0 0.866025 0.5 0 0 0 1"};
  for (int n = 1; n <= 3; ++n) {
    std::string par = std::to_string(n) + "\n";
    for (int i = 0; i < n; ++i) par += "view" + std::to_string(i) + ".png " + k + " " + r[i] + " 0.01 -0.02 " + std::to_string(0.5 + i) + "\n";
    Put("middlebury_par", "par_" + std::to_string(n) + ".txt", par);
  }
  Put("middlebury_par", "crlf_par.txt", "1\r\ntempleR0001.png " + k + " " + r[0] + " 0 0 0.6\r\n");
  Put("middlebury_par", "exponent_par.txt", "2\na.png 1.5e3 0 3.2e2 0 1.5e3 2.4e2 0 0 1 " + r[1] +
                                                 " 1e-2 0 6e-1\nb.png " + k + " " + r[2] + " 0 0 1\n");
  for (int i = 0; i < 3; ++i) {
    Put("strecha_camera", "view" + std::to_string(i) + ".camera",
        "2759.48 0 1520.69\n0 2764.16 1006.81\n0 0 1\n0 0 0\n" + r[i] + "\n" +
            std::to_string(-7.0 + i) + " 3.5 0.9\n3072 2048\n");
  }
  Put("strecha_camera", "small.camera", "50 0 31.5\n0 50 23.5\n0 0 1\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n0 0 -3\n64 48\n");
  Put("strecha_camera", "exponents.camera", "5e1 0 3.15e1 0 5e1 2.35e1 0 0 1 0 0 0 1 0 0 0 1 0 0 0 1 1e-1 2e-1 -3 64 48");
}

// --- The carve stage's octree.bin: a root only, and trees with full, empty and partial nodes.
void Octrees() {
  for (int depth = 0; depth <= 4; ++depth) {
    ibmr::Octree octree;
    octree.origin = Eigen::Vector3d(-1, -0.5, 0.25 * depth);
    octree.size = 2.0 + depth;
    octree.levels.push_back({ibmr::OctreeNode{0, 0, 0, depth == 0 ? ibmr::NodeState::kFull : ibmr::NodeState::kPartial}});
    for (int level = 1; level <= depth; ++level) {
      std::vector<ibmr::OctreeNode> nodes;
      int partials = 0;
      for (const ibmr::OctreeNode& parent : octree.levels.back()) {
        if (parent.state != ibmr::NodeState::kPartial) continue;
        for (int child = 0; child < 8; ++child) {
          ibmr::OctreeNode node;
          node.x = static_cast<uint16_t>(2 * parent.x + (child & 1));
          node.y = static_cast<uint16_t>(2 * parent.y + ((child >> 1) & 1));
          node.z = static_cast<uint16_t>(2 * parent.z + ((child >> 2) & 1));
          // One partial child per level (none at the last), the rest full or empty.
          const bool partial = level < depth && child == (level % 8) && partials++ == 0;
          node.state = partial ? ibmr::NodeState::kPartial : (child % 3 == 0 ? ibmr::NodeState::kFull : ibmr::NodeState::kEmpty);
          nodes.push_back(node);
        }
      }
      octree.levels.push_back(nodes);
    }
    Put("octree", "depth" + std::to_string(depth) + ".bin", ibmr::SerializeOctree(octree));
  }
}

// --- Stage records as the runner writes them.
void Records() {
  const char* const kStatus[] = {"ok", "failed", "running", "ok", "ok"};
  for (int i = 0; i < 5; ++i) {
    ibmr::StageRecord record;
    record.stage = i == 4 ? "plane_sweep" : "carve";
    record.version = std::to_string(i + 1);
    record.status = kStatus[i];
    record.key = "0123456789abcdef" + std::to_string(i);
    record.params = {{"max_level", 6 + i}, {"method", "box"}, {"scale", 0.5 * i}};
    record.inputs = {{"masks/view_000.png", "9f86d081884c7d65"}, {"sparse/cameras.txt", "2c26b46b68ffc68f"}};
    record.outputs = {"hull/octree.bin", "hull/mesh.ply"};
    if (i == 3) record.heldout = {"view_002.png", "view_009.png"};
    record.metrics = {{"cells", 512 * i}, {"iou", 0.93}, {"levels", {{"4", 0.8}, {"5", 0.9}}}};
    if (i == 1) record.error = "carve: masks/view_003.png is missing";
    record.started = "2026-12-06T02:3" + std::to_string(i) + ":00";
    record.wall_seconds = 1.25 * i;
    record.cpu_seconds = 2.5 * i;
    record.peak_memory_mb = 120.5;
    record.memory_budget_mb = i == 4 ? 3000 : 0;
    record.view_memory_mb = i == 4 ? 80 : 0;
    record.views_in_flight = i == 4 ? 2 : 0;
    record.views_resumed = i == 4 ? 3 : 0;
    if (i == 2) record.reused_from = "../v00";
    Put("record", record.stage + "_" + std::to_string(i) + ".json", ibmr::DumpJson(record.ToJson(), i % 2 ? 2 : -1));
  }
}

// Every seed must be valid: read back with the reader its harness fuzzes (throws otherwise).
void CheckSeeds(const fs::path& scratch) {
  const auto size_of = [](const std::string&) { return std::pair<int, int>(64, 48); };
  for (const auto& folder : fs::directory_iterator(out_dir)) {
    const std::string harness = folder.path().filename().string();
    if (folder.path() == scratch) continue;
    for (const auto& entry : fs::directory_iterator(folder.path())) {
      const std::string path = entry.path().string(), name = entry.path().filename().string();
      const std::string bytes = ibmr::ReadFile(path);
      try {
        if (harness == "image") {
          if (ibmr::ReadImageUnchanged(path).empty() || ibmr::ReadImageColor(path).empty()) throw std::runtime_error("empty");
        } else if (harness == "ply") {
          if (ibmr::ReadPointCloudPly(path).size() == 0) throw std::runtime_error("no points");
          if (name.find("cloud") == std::string::npos && name.find("surfels") == std::string::npos &&
              !ibmr::ReadMeshPly(path).Validate().empty()) throw std::runtime_error("invalid mesh");
        } else if (harness == "colmap_text") {
          const fs::path model = scratch / "model";
          fs::create_directories(model);
          const char* const files[] = {"cameras.txt", "images.txt", "points3D.txt"};
          size_t start = 0;
          for (const char* file : files) {
            const size_t end = std::min(bytes.find("\n%%\n", start), bytes.size());
            std::ofstream(model / file, std::ios::binary) << bytes.substr(start, end - start);
            start = end + 4;
          }
          if (!ibmr::ReadSparseModelText(model.string()).Validate().empty()) throw std::runtime_error("invalid model");
        } else if (harness == "colmap_array") {
          (void)ibmr::ReadColmapArray(path);
        } else if (harness == "pfm") {
          (void)ibmr::ReadPfm(path);
        } else if (harness == "middlebury_par") {
          (void)ibmr::ParseMiddleburyPar(bytes, path, [](const std::string&) { return std::pair<int, int>(640, 480); });
        } else if (harness == "strecha_camera") {
          ibmr::Camera camera;
          ibmr::Rigid3d pose;
          ibmr::ParseStrechaCamera(bytes, path, &camera, &pose);
        } else if (harness == "octree") {
          (void)ibmr::DeserializeOctree(bytes);
        } else if (harness == "record") {
          if (!ibmr::ReadRecord(path)) throw std::runtime_error("not a record");
        } else if (harness == "transforms") {
          std::vector<std::string> names;
          (void)ibmr::ParseTransformsJson(bytes, path, size_of, &names);
        } else if (harness == "poses_bounds") {
          (void)ibmr::ParsePosesBounds(bytes, path, {"a.png", "b.png", "c.png"}, 2, nullptr);
        }
      } catch (const std::exception& e) {
        throw std::runtime_error("seed " + path + " is not valid: " + e.what());
      }
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: fuzz_seeds OUT_DIR\n";
    return 2;
  }
  out_dir = argv[1];
  const fs::path scratch = out_dir / ".scratch";
  fs::create_directories(scratch);
  try {
    Images();
    Plys(scratch);
    ColmapAndNerf(scratch);
    ImportTexts();
    Octrees();
    Records();
    CheckSeeds(scratch);
  } catch (const std::exception& e) {
    std::cerr << "fuzz_seeds: " << e.what() << "\n";
    return 1;
  }
  fs::remove_all(scratch);
  std::cout << "fuzz_seeds: " << written << " seeds in " << out_dir.string() << "\n";
  return 0;
}
