// Tests for the rasterizer against analytic answers: exact depth of a fronto-parallel plane,
// ray-plane depth at pixel centres for a tilted plane (catches half-pixel slips), z-test order,
// watertight shared edges (including pixel centres exactly on edges and vertices), near-plane
// clipping, backface culling, and barycentrics that reproduce the 3D surface point.
#include "pipeline/core/rasterizer.h"

#include <chrono>

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

// A rectangle given by its corners as the camera sees them (top-left, top-right, bottom-right,
// bottom-left); its two faces are counter-clockwise seen from the camera's side.
TriangleMesh Quad(const Eigen::Vector3f& top_left, const Eigen::Vector3f& top_right,
                  const Eigen::Vector3f& bottom_right, const Eigen::Vector3f& bottom_left) {
  TriangleMesh mesh;
  mesh.vertices = {top_left, top_right, bottom_right, bottom_left};
  // With y pointing down, image order runs clockwise as displayed; reverse it.
  mesh.faces = {{0, 3, 2}, {0, 2, 1}};
  return mesh;
}

// An axis-aligned cube [-1, 1]^3 with each side split into n x n cells, outward faces CCW.
TriangleMesh SubdividedCube(int n) {
  TriangleMesh mesh;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = -1; side <= 1; side += 2) {
      const int u_axis = (axis + 1) % 3, v_axis = (axis + 2) % 3;
      const int base = static_cast<int>(mesh.vertices.size());
      for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i) {
          Eigen::Vector3f p;
          p[axis] = side;
          p[u_axis] = -1.f + 2.f * i / n;
          p[v_axis] = -1.f + 2.f * j / n;
          mesh.vertices.push_back(p);
        }
      }
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const int a = base + j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
          // (u, v, axis) is right-handed, so a-b-d is CCW seen from +axis.
          if (side > 0) {
            mesh.faces.emplace_back(a, b, d);
            mesh.faces.emplace_back(a, d, c);
          } else {
            mesh.faces.emplace_back(a, d, b);
            mesh.faces.emplace_back(a, c, d);
          }
        }
      }
    }
  }
  return mesh;
}

// The ray through the centre of pixel (c, r), with z = 1.
Eigen::Vector3d PixelRay(const Camera& camera, int c, int r) {
  return {(c + 0.5 - camera.PrincipalX()) / camera.FocalX(), (r + 0.5 - camera.PrincipalY()) / camera.FocalY(), 1.0};
}

int CountCovered(const RasterResult& result) {
  return static_cast<int>(std::count_if(result.face_id.begin(), result.face_id.end(), [](int f) { return f >= 0; }));
}

TEST(Rasterizer, FrontoParallelQuadHasExactDepth) {
  const Camera camera = Camera::Pinhole(64, 48, 50, 55, 31.3, 24.9);
  const TriangleMesh quad = Quad({-100, -100, 5}, {100, -100, 5}, {100, 100, 5}, {-100, 100, 5});
  for (bool cull : {false, true}) {
    RasterizeOptions options;
    options.cull_backfaces = cull;
    const RasterResult result = Rasterize(quad, camera, Rigid3d(), options);
    ASSERT_EQ(result.depth.width, 64);
    ASSERT_EQ(result.depth.height, 48);
    for (int r = 0; r < 48; ++r) {
      for (int c = 0; c < 64; ++c) {
        ASSERT_EQ(result.depth.At(c, r), 5.f) << "pixel " << c << "," << r << " cull " << cull;
        ASSERT_GE(result.face_id[r * 64 + c], 0);
      }
    }
  }
}

// A result reused for another mesh, at the same image size or another, holds that raster alone, as
// a fresh one.
TEST(Rasterizer, AReusedResultEqualsAFreshOne) {
  RasterResult reused;
  const TriangleMesh cube = SubdividedCube(3);
  const Rigid3d pose(Eigen::Quaterniond(Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 1, 0).normalized())), Eigen::Vector3d(0, 0, 6));
  const TriangleMesh quad = Quad({-1, -1, 4}, {1, -1, 4}, {1, 1, 4}, {-1, 1, 4});
  for (const auto& [mesh, camera] : std::vector<std::pair<TriangleMesh, Camera>>{
           {cube, Camera::Pinhole(80, 60, 70, 70, 40, 30)}, {quad, Camera::Pinhole(80, 60, 70, 70, 40, 30)},  // same size
           {quad, Camera::Pinhole(50, 70, 60, 60, 25, 35)}, {cube, Camera::Pinhole(30, 20, 25, 25, 15, 10)}}) {
    Rasterize(mesh, camera, pose, RasterizeOptions(), &reused);
    const RasterResult fresh = Rasterize(mesh, camera, pose);
    EXPECT_GT(CountCovered(fresh), 0);
    EXPECT_EQ(reused.depth.width, fresh.depth.width);
    EXPECT_EQ(reused.depth.height, fresh.depth.height);
    EXPECT_EQ(reused.depth.data, fresh.depth.data);
    EXPECT_EQ(reused.face_id, fresh.face_id);
    EXPECT_EQ(reused.barycentric.channels, 3);
    EXPECT_EQ(reused.barycentric.data, fresh.barycentric.data);
  }
}

TEST(Rasterizer, TiltedPlaneDepthAtPixelCentres) {
  // Plane z = 4 + x in the camera frame; the ray (dx, dy, 1) meets it at z = 4 / (1 - dx).
  const Camera camera = Camera::Pinhole(160, 120, 100, 100, 80, 60);
  const TriangleMesh plane = Quad({-3, -30, 1}, {30, -30, 34}, {30, 30, 34}, {-3, 30, 1});
  const RasterResult result = Rasterize(plane, camera, Rigid3d());
  for (int r = 0; r < 120; ++r) {
    for (int c = 0; c < 160; ++c) {
      const double expected = 4.0 / (1.0 - PixelRay(camera, c, r).x());
      ASSERT_NEAR(result.depth.At(c, r), expected, 1e-4 * expected) << "pixel " << c << "," << r;
    }
  }
}

TEST(Rasterizer, NearerTriangleWinsInEitherOrder) {
  const Camera camera = Camera::Pinhole(40, 40, 40, 40, 20, 20);
  TriangleMesh mesh;
  mesh.vertices = {{-10, -10, 6}, {10, -10, 6}, {0, 10, 6}, {-1, -1, 3}, {1, -1, 3}, {0, 1, 3}};
  mesh.faces = {{0, 1, 2}, {3, 4, 5}};
  for (int order = 0; order < 2; ++order) {
    const RasterResult result = Rasterize(mesh, camera, Rigid3d());
    const int near_face = order == 0 ? 1 : 0;
    EXPECT_EQ(result.face_id[20 * 40 + 20], near_face);
    EXPECT_FLOAT_EQ(result.depth.At(20, 20), 3.f);
    EXPECT_FLOAT_EQ(result.depth.At(20, 2), 6.f) << "outside the near triangle the far one shows";
    std::swap(mesh.faces[0], mesh.faces[1]);
  }
}

// A fronto-parallel grid at z = 1 whose vertices project exactly onto pixel centres
// (u = 64 x + 32.5 with x = k / 64), so many centres lie exactly on edges and vertices.
TriangleMesh PixelAlignedGrid() {
  TriangleMesh mesh;
  const int n = 8;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) mesh.vertices.emplace_back((-16 + 4 * i) / 64.f, (-16 + 4 * j) / 64.f, 1.f);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      if ((i + j) % 2 == 0) {  // alternate diagonals, both windings
        mesh.faces.emplace_back(a, d, b);
        mesh.faces.emplace_back(a, c, d);
      } else {
        mesh.faces.emplace_back(a, b, c);
        mesh.faces.emplace_back(b, d, c);
      }
    }
  }
  return mesh;
}

Camera PixelAlignedCamera() { return Camera::Pinhole(64, 64, 64, 64, 32.5, 32.5); }

TEST(Rasterizer, SharedEdgesThroughPixelCentresLeaveNoCracks) {
  const RasterResult result = Rasterize(PixelAlignedGrid(), PixelAlignedCamera(), Rigid3d());
  // Columns/rows whose centres are strictly inside the grid: u in (16.5, 48.5).
  for (int r = 17; r <= 47; ++r)
    for (int c = 17; c <= 47; ++c) EXPECT_GE(result.face_id[r * 64 + c], 0) << "crack at " << c << "," << r;
  for (int r = 0; r < 64; ++r) {
    EXPECT_EQ(result.face_id[r * 64 + 10], -1);
    EXPECT_EQ(result.face_id[r * 64 + 55], -1);
  }
}

TEST(Rasterizer, CentresOnSharedEdgesGoToOneFaceWhateverTheOrder) {
  // Both faces have the same depth on a shared edge, so with a rule that gave a centre on the
  // edge to both, the first face drawn would keep it and reversing the faces would change the
  // answer. A fill rule decides by geometry alone.
  TriangleMesh mesh = PixelAlignedGrid();
  const RasterResult forward = Rasterize(mesh, PixelAlignedCamera(), Rigid3d());
  const int num_faces = static_cast<int>(mesh.faces.size());
  std::reverse(mesh.faces.begin(), mesh.faces.end());
  const RasterResult backward = Rasterize(mesh, PixelAlignedCamera(), Rigid3d());
  for (size_t i = 0; i < forward.face_id.size(); ++i) {
    const int expected = forward.face_id[i] < 0 ? -1 : num_faces - 1 - forward.face_id[i];
    ASSERT_EQ(backward.face_id[i], expected) << "pixel " << i % 64 << "," << i / 64;
  }
}

TEST(Rasterizer, CubeSilhouetteIsFullyCovered) {
  const Camera camera = Camera::Pinhole(200, 150, 180, 180, 100, 75);
  const Rigid3d cam_from_world = LookAt({2.5, -1.8, -3.1}, {0.1, 0.05, 0}, {0, -1, 0});
  const TriangleMesh cube = SubdividedCube(5);
  std::vector<cv::Point2f> corners;
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d p = cam_from_world * Eigen::Vector3d(i & 1 ? 1 : -1, i & 2 ? 1 : -1, i & 4 ? 1 : -1);
    corners.emplace_back(camera.FocalX() * p.x() / p.z() + camera.PrincipalX(),
                         camera.FocalY() * p.y() / p.z() + camera.PrincipalY());
  }
  std::vector<cv::Point2f> hull;
  cv::convexHull(corners, hull);
  for (bool cull : {false, true}) {
    RasterizeOptions options;
    options.cull_backfaces = cull;
    const RasterResult result = Rasterize(cube, camera, cam_from_world, options);
    int inside = 0;
    for (int r = 0; r < 150; ++r) {
      for (int c = 0; c < 200; ++c) {
        const double distance = cv::pointPolygonTest(hull, cv::Point2f(c + 0.5f, r + 0.5f), true);
        const bool covered = result.face_id[r * 200 + c] >= 0;
        if (distance > 0.01) {
          ++inside;
          ASSERT_TRUE(covered) << "hole at " << c << "," << r << " cull " << cull;
        } else if (distance < -0.01) {
          ASSERT_FALSE(covered) << "spill at " << c << "," << r;
        }
      }
    }
    EXPECT_GT(inside, 2000);
  }
}

TEST(Rasterizer, BackfacesAreCulledOnlyWhenAsked) {
  const Camera camera = Camera::Pinhole(40, 40, 40, 40, 20, 20);
  TriangleMesh mesh = Quad({-1, -1, 3}, {1, -1, 3}, {1, 1, 3}, {-1, 1, 3});
  for (Eigen::Vector3i& f : mesh.faces) std::swap(f[1], f[2]);  // now facing away
  RasterizeOptions options;
  EXPECT_GT(CountCovered(Rasterize(mesh, camera, Rigid3d(), options)), 100);
  options.cull_backfaces = true;
  EXPECT_EQ(CountCovered(Rasterize(mesh, camera, Rigid3d(), options)), 0);
}

TEST(Rasterizer, ClipsTrianglesCrossingTheNearPlane) {
  // One vertex behind the camera: without clipping it would project to the wrong side.
  const Camera camera = Camera::Pinhole(200, 200, 100, 100, 100, 100);
  TriangleMesh mesh;
  mesh.vertices = {{-1, -1, 2}, {1, -1, 2}, {0, 1, -1}};
  mesh.faces = {{0, 1, 2}};
  RasterizeOptions options;
  options.near_z = 0.5;
  const RasterResult result = Rasterize(mesh, camera, Rigid3d(), options);
  const Eigen::Vector3d a = mesh.vertices[0].cast<double>(), b = mesh.vertices[1].cast<double>(),
                        c = mesh.vertices[2].cast<double>();
  const Eigen::Vector3d normal = (b - a).cross(c - a);
  int checked_in = 0, checked_out = 0;
  for (int r = 0; r < 200; ++r) {
    for (int col = 0; col < 200; ++col) {
      const Eigen::Vector3d ray = PixelRay(camera, col, r);
      const double t = normal.dot(a) / normal.dot(ray);  // ray-plane hit, z = t
      const Eigen::Vector3d p = t * ray;
      // Barycentrics of p by sub-triangle areas.
      const double total = normal.norm();
      const Eigen::Vector3d w((b - p).cross(c - p).dot(normal) / (total * total),
                              (c - p).cross(a - p).dot(normal) / (total * total),
                              (a - p).cross(b - p).dot(normal) / (total * total));
      const bool hit = t > 0 && w.minCoeff() > 0;
      const bool clearly_in = hit && w.minCoeff() > 1e-3 && t > options.near_z + 1e-3;
      const bool clearly_out = !hit ? (t <= 0 || w.minCoeff() < -1e-3) : t < options.near_z - 1e-3;
      const int id = result.face_id[r * 200 + col];
      if (clearly_in) {
        ++checked_in;
        ASSERT_EQ(id, 0) << col << "," << r;
        ASSERT_NEAR(result.depth.At(col, r), t, 1e-5 * t);
        for (int k = 0; k < 3; ++k) ASSERT_NEAR(result.barycentric.At(col, r, k), w[k], 1e-4) << "original weights";
      } else if (clearly_out) {
        ++checked_out;
        ASSERT_EQ(id, -1) << col << "," << r;
      }
      if (id >= 0) {
        ASSERT_GE(result.depth.At(col, r), options.near_z * (1 - 1e-6));
      }
    }
  }
  EXPECT_GT(checked_in, 1000);
  EXPECT_GT(checked_out, 1000);
}

// A subdivided cube seen from outside (6144 faces, so the automatic choice uses bands), plus a
// duplicate of each face at the same depth (ties go to the first face), a large triangle across
// every row and one crossing the near plane (near_z 0.2); the last two faces are those two.
struct TiesScene {
  Camera camera = Camera::Pinhole(173, 131, 120, 118, 85.3, 66.1);
  Rigid3d cam_from_world = LookAt({2.6, -1.9, 3.1}, {0.1, 0.2, -0.1}, {0, -1, 0});
  TriangleMesh mesh;
  RasterizeOptions one_pass;

  TiesScene() {
    mesh = SubdividedCube(32);
    const size_t cube_faces = mesh.faces.size();
    for (size_t f = 0; f < cube_faces; f += 3) mesh.faces.push_back(mesh.faces[f]);
    const Eigen::Vector3d centre = cam_from_world.Inverse().translation;
    const Eigen::Matrix3d world_from_cam = cam_from_world.R().transpose();
    auto world = [&](double x, double y, double z) -> Eigen::Vector3f {
      return (centre + world_from_cam * Eigen::Vector3d(x, y, z)).cast<float>();
    };
    const int base = static_cast<int>(mesh.vertices.size());
    mesh.vertices.push_back(world(-9, -7, 8.3));  // behind the cube, over every row
    mesh.vertices.push_back(world(9, -6.5, 8.6));
    mesh.vertices.push_back(world(0.2, 8, 8.4));
    mesh.vertices.push_back(world(-1.4, -0.9, 1.5));  // at the left, in front of the cube
    mesh.vertices.push_back(world(-0.9, -0.8, 1.5));
    mesh.vertices.push_back(world(-1.2, 0.9, -1.0));  // behind the camera
    mesh.faces.emplace_back(base, base + 1, base + 2);
    mesh.faces.emplace_back(base + 3, base + 4, base + 5);
    one_pass.near_z = 0.2;
    one_pass.row_bands = 1;
  }
};

TEST(Rasterizer, BandsOfRowsDrawAsOnePass) {
  const TiesScene scene;
  ASSERT_GE(scene.mesh.faces.size(), 4096u);
  const RasterResult reference = Rasterize(scene.mesh, scene.camera, scene.cam_from_world, scene.one_pass);
  ASSERT_GT(CountCovered(reference), 3000);
  const int faces = static_cast<int>(scene.mesh.faces.size());
  for (const int face : {faces - 2, faces - 1}) {
    EXPECT_GT(std::count(reference.face_id.begin(), reference.face_id.end(), face), 20) << "face " << face << " is drawn";
  }
  for (const int bands : {0, 2, 7, 131, 500}) {
    RasterizeOptions options = scene.one_pass;
    options.row_bands = bands;
    const RasterResult banded = Rasterize(scene.mesh, scene.camera, scene.cam_from_world, options);
    EXPECT_EQ(banded.face_id, reference.face_id) << bands << " bands";
    EXPECT_EQ(banded.depth.data, reference.depth.data) << bands << " bands";
    EXPECT_EQ(banded.barycentric.data, reference.barycentric.data) << bands << " bands";
  }
}

TEST(Rasterizer, WindowsOfRowsDrawAsOnePass) {
  // Windows of any height, each drawn in automatic bands, put together give one pass's image; the
  // windows come in order, cover every row once, and hold only their own rows.
  const TiesScene scene;
  const int width = scene.camera.width, height = scene.camera.height;
  const RasterResult reference = Rasterize(scene.mesh, scene.camera, scene.cam_from_world, scene.one_pass);
  for (const int window_rows : {1, 5, 16, 64, 130, 131, 1000}) {
    RasterizeOptions options = scene.one_pass;
    options.row_bands = 0;
    std::vector<int> face_id;
    std::vector<float> depth, barycentric(3 * static_cast<size_t>(width) * height);
    int next_row = 0;
    RasterResult window;
    RasterizeWindows(scene.mesh, scene.camera, scene.cam_from_world, options, window_rows, &window,
                     [&](int first_row, const RasterResult& drawn) {
      ASSERT_EQ(first_row, next_row);
      ASSERT_EQ(drawn.depth.height, std::min(window_rows, height - first_row));
      ASSERT_EQ(drawn.face_id.size(), static_cast<size_t>(width) * drawn.depth.height);
      face_id.insert(face_id.end(), drawn.face_id.begin(), drawn.face_id.end());
      depth.insert(depth.end(), drawn.depth.data.begin(), drawn.depth.data.end());
      for (int y = 0; y < drawn.depth.height; ++y)
        for (int x = 0; x < width; ++x)
          for (int c = 0; c < 3; ++c) barycentric[c * static_cast<size_t>(width) * height + static_cast<size_t>(first_row + y) * width + x] = drawn.barycentric.At(x, y, c);
      next_row = first_row + drawn.depth.height;
    });
    EXPECT_EQ(next_row, height) << window_rows << " rows a window";
    EXPECT_EQ(face_id, reference.face_id) << window_rows << " rows a window";
    EXPECT_EQ(depth, reference.depth.data) << window_rows << " rows a window";
    EXPECT_EQ(barycentric, reference.barycentric.data) << window_rows << " rows a window";
  }
  RasterResult window;
  EXPECT_THROW(RasterizeWindows(scene.mesh, scene.camera, scene.cam_from_world, scene.one_pass, 0, &window,
                                [](int, const RasterResult&) {}),
               InputError);
}

TEST(Rasterizer, BarycentricsReproduceTheSurfacePoint) {
  const Camera camera = Camera::Pinhole(160, 120, 150, 140, 79.2, 61.7);
  const Rigid3d cam_from_world = LookAt({-2.2, 1.5, -2.9}, {0.2, -0.1, 0.3}, {0, -1, 0});
  const TriangleMesh cube = SubdividedCube(3);
  const RasterResult result = Rasterize(cube, camera, cam_from_world);
  int covered = 0;
  for (int r = 0; r < 120; ++r) {
    for (int c = 0; c < 160; ++c) {
      if (result.face_id[r * 160 + c] < 0) continue;
      ++covered;
      float sum = 0;
      for (int k = 0; k < 3; ++k) {
        ASSERT_GE(result.barycentric.At(c, r, k), -1e-6f);
        sum += result.barycentric.At(c, r, k);
      }
      ASSERT_NEAR(sum, 1.f, 1e-5f);
      const Eigen::Vector3f world = InterpolateAttribute(result, cube, cube.vertices, c, r);
      const Eigen::Vector3d p = cam_from_world * world.cast<double>();
      const double depth = result.depth.At(c, r);
      ASSERT_NEAR(p.z(), depth, 1e-4 * depth) << c << "," << r;
      // And the point lies on the ray through the pixel centre.
      ASSERT_NEAR(camera.FocalX() * p.x() / p.z() + camera.PrincipalX(), c + 0.5, 1e-3);
      ASSERT_NEAR(camera.FocalY() * p.y() / p.z() + camera.PrincipalY(), r + 0.5, 1e-3);
    }
  }
  EXPECT_GT(covered, 2000);
}

TEST(Rasterizer, TrianglesProjectingBeyondIntRangeFinishAndDrawNothingOffScreen) {
  // Crosses the near plane far off to the side: the clipped vertices project to x ~ 2.5e9 and
  // 5e9 pixels, beyond int range. Casting those bounds to int used to give INT_MIN and a loop of
  // ~2^31 columns per row (a hang); the triangle is wholly right of the image, so nothing is drawn.
  const Camera camera = Camera::Pinhole(64, 48, 1000, 1000, 32, 24);
  TriangleMesh mesh;
  mesh.vertices = {{5000, 0, -1}, {5000, 1, -1}, {5001, 0, 0.002f}};
  mesh.faces = {{0, 1, 2}, {0, 2, 1}};  // both windings
  // The mirrored triangle lies far off to the left, and a huge one spans the image side to side.
  mesh.vertices.push_back({-5000, 0, -1});
  mesh.vertices.push_back({-5000, 1, -1});
  mesh.vertices.push_back({-5001, 0, 0.002f});
  mesh.faces.push_back({3, 4, 5});
  mesh.faces.push_back({3, 5, 4});
  const auto start = std::chrono::steady_clock::now();
  const RasterResult result = Rasterize(mesh, camera, Rigid3d());
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_LT(seconds, 1.0);
  EXPECT_EQ(CountCovered(result), 0);

  // A triangle spanning the whole image from beyond int range on both sides still covers it all.
  TriangleMesh wide;
  wide.vertices = {{-3e6f, -3e6f, 1e-3f}, {3e6f, -3e6f, 1e-3f}, {0, 3e6f, 1e-3f}};
  wide.faces = {{0, 2, 1}};
  RasterizeOptions options;
  options.near_z = 1e-4;
  EXPECT_EQ(CountCovered(Rasterize(wide, camera, Rigid3d(), options)), 64 * 48);
}

TEST(Rasterizer, RejectsBadInputs) {
  const TriangleMesh mesh = Quad({-1, -1, 3}, {1, -1, 3}, {1, 1, 3}, {-1, 1, 3});
  RasterizeOptions options;
  options.near_z = 0;
  EXPECT_THROW(Rasterize(mesh, Camera::Pinhole(10, 10, 10, 10, 5, 5), Rigid3d(), options), InputError);
  EXPECT_THROW(Rasterize(mesh, Camera::Pinhole(0, 10, 10, 10, 5, 5), Rigid3d()), InputError);
  RasterizeOptions bands;
  bands.row_bands = -1;
  EXPECT_THROW(Rasterize(mesh, Camera::Pinhole(10, 10, 10, 10, 5, 5), Rigid3d(), bands), InputError);
}

}  // namespace
}  // namespace ibmr
