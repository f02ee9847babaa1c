// Tests of fuse (seed 000 lines 4352-4453): options, exact point-to-mesh distances, and fusion of
// noisy depth maps of an analytic unit sphere seen by 12 ring views at 160x120: merged points lie
// closer to the surface than single samples, cover the seen surface, face outwards, and
// low-confidence samples produce no points. One adapter run writes a readable dense/fused.ply.
#include "pipeline/runner/config.h"
#include "stages/fuse/fuse.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <random>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/rank_correlation.h"
#include "pipeline/core/stage_api.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_fuse(StageRegistry* registry);

namespace {

// Unit sphere as a UV mesh (the tessellation is within 0.002 of the sphere).
TriangleMesh SphereMesh(int segments = 96, int rings = 48) {
  TriangleMesh mesh;
  for (int r = 0; r <= rings; ++r) {
    const double theta = M_PI * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * M_PI * s / segments;
      mesh.vertices.emplace_back(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi), std::cos(theta));
    }
  }
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      const int a = r * segments + s, b = r * segments + (s + 1) % segments, c = a + segments, d = b + segments;
      mesh.faces.emplace_back(a, c, b);
      mesh.faces.emplace_back(b, c, d);
    }
  }
  return mesh;
}

// z depth of the unit sphere, relative noise sigma, confidence 1 (0 in the top `blank` rows).
FuseView SphereView(int index, int views, double sigma, int blank_rows = 0) {
  FuseView view;
  view.camera = Camera::Pinhole(160, 120, 150, 150, 80, 60);
  const double angle = 2 * M_PI * index / views;
  view.cam_from_world = LookAt(Eigen::Vector3d(4 * std::cos(angle), 4 * std::sin(angle), 1.2), Eigen::Vector3d::Zero(),
                               Eigen::Vector3d::UnitZ());
  view.depth = DepthMap(160, 120, 1, 0.f);
  view.confidence = FloatMap(160, 120, 1, 1.f);
  view.image = cv::Mat(120, 160, CV_8UC3, cv::Scalar(40, 120, 200));  // BGR
  std::mt19937 rng(1000 + index);
  std::normal_distribution<double> noise(0, sigma);
  const Rigid3d world_from_cam = view.cam_from_world.Inverse();
  for (int y = 0; y < 120; ++y) {
    for (int x = 0; x < 160; ++x) {
      const Eigen::Vector3d dir = world_from_cam.rotation * view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
      const Eigen::Vector3d o = world_from_cam.translation;
      const double b = 2 * o.dot(dir), a = dir.squaredNorm(), c = o.squaredNorm() - 1, disc = b * b - 4 * a * c;
      if (disc < 0) continue;
      view.depth.At(x, y) = static_cast<float>((-b - std::sqrt(disc)) / (2 * a) * (1 + noise(rng)));
      if (y < blank_rows) view.confidence.At(x, y) = 0.02f;
    }
  }
  return view;
}

TEST(FuseOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(FuseOptions().Check(&error)) << error;
}

TEST(FuseOptions, RejectsInvalidRanges) {
  auto expect = [](FuseOptions o, const std::string& key) {
    std::string error;
    EXPECT_FALSE(o.Check(&error));
    EXPECT_EQ(error.rfind(key + ":", 0), 0u) << error;
  };
  FuseOptions o;
  o.relative_depth_sigma = 0;
  expect(o, "relative_depth_sigma");
  o = FuseOptions(), o.lateral_sigma_pixels = -1;
  expect(o, "lateral_sigma_pixels");
  o = FuseOptions(), o.merge_sigmas = 0;
  expect(o, "merge_sigmas");
  o = FuseOptions(), o.merge_pixel_radius = 0.8;  // beyond any point of the pixel it falls in
  expect(o, "merge_pixel_radius");
  o = FuseOptions(), o.max_normal_angle_deg = 0;
  expect(o, "max_normal_angle_deg");
  o = FuseOptions(), o.min_confidence = 2;
  expect(o, "min_confidence");
  o = FuseOptions(), o.min_views = 0;
  expect(o, "min_views");
  o = FuseOptions(), o.surface_neighbours = 3;
  expect(o, "surface_neighbours");
  o = FuseOptions(), o.surface_residual_scale = 0;
  expect(o, "surface_residual_scale");
  o = FuseOptions(), o.surface_neighbours = 0;  // off
  std::string error;
  EXPECT_TRUE(o.Check(&error)) << error;
}

// The surface factor ranks a noisy plane's points by their true distance to it (rank correlation
// below -0.5, where the stereo confidence of such noise ranks nothing), puts points lifted off
// it far below the rest, and is 1 on an exact plane and when off or too few points.
TEST(SurfaceFactors, FallWithTheDistanceToTheLocalSurface) {
  std::mt19937 rng(5);
  std::normal_distribution<float> noise(0.f, 0.002f);
  std::vector<Eigen::Vector3f> points, exact;
  std::vector<float> distance;
  for (int y = 0; y < 60; ++y) {
    for (int x = 0; x < 60; ++x) {
      const float z = noise(rng);
      points.emplace_back(0.01f * x, 0.01f * y, z);
      exact.emplace_back(0.01f * x, 0.01f * y, 0.f);
      distance.push_back(std::abs(z));
    }
  }
  for (int i = 0; i < 20; ++i) {  // lifted 2 cm: clearly off the surface
    points[i * 97].z() = 0.02f;
    distance[i * 97] = 0.02f;
  }
  const std::vector<float> f = SurfaceFactors(points, 32, 2.0);
  ASSERT_EQ(f.size(), points.size());
  std::vector<double> fd(f.begin(), f.end()), dd(distance.begin(), distance.end());
  EXPECT_LT(SpearmanCorrelation(fd, dd), -0.5);
  std::vector<float> sorted = f;
  std::sort(sorted.begin(), sorted.end());
  for (int i = 0; i < 20; ++i) EXPECT_LT(f[i * 97], 0.01f) << i;
  EXPECT_GT(sorted[sorted.size() / 2], 0.8f);
  for (float v : SurfaceFactors(exact, 32, 2.0)) ASSERT_NEAR(v, 1.f, 1e-6);
  for (float v : SurfaceFactors(points, 0, 2.0)) ASSERT_EQ(v, 1.f);
  const std::vector<Eigen::Vector3f> few(points.begin(), points.begin() + 10);
  for (float v : SurfaceFactors(few, 32, 2.0)) ASSERT_EQ(v, 1.f);
}

TEST(MeshDistance, MatchesBruteForceOnASphere) {
  const TriangleMesh mesh = SphereMesh(24, 12);
  const MeshDistance distance(mesh);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.6, 1.6);
  for (int i = 0; i < 200; ++i) {
    const Eigen::Vector3d p(u(rng), u(rng), u(rng));
    double brute = 1e9;
    for (const auto& f : mesh.faces) {
      // Dense barycentric sampling as an independent upper bound, plus the vertices.
      for (int a = 0; a <= 20; ++a) {
        for (int b = 0; a + b <= 20; ++b) {
          const Eigen::Vector3d q = (mesh.vertices[f[0]].cast<double>() * (20 - a - b) + mesh.vertices[f[1]].cast<double>() * a +
                                     mesh.vertices[f[2]].cast<double>() * b) / 20;
          brute = std::min(brute, (q - p).norm());
        }
      }
    }
    const double d = distance.Distance(p, 10);
    EXPECT_LE(d, brute + 1e-9);
    EXPECT_GT(d, brute - 0.02);  // the sampling above is within ~0.02 of exact
  }
  EXPECT_NEAR(distance.Distance(Eigen::Vector3d(0, 0, 5), 10), 4.0, 1e-6);  // the pole is a vertex
  EXPECT_DOUBLE_EQ(distance.Distance(Eigen::Vector3d(0, 0, 50), 3), 3.0);    // capped
}

TEST(Fuse, NoisySphereMergesIntoAccurateCompletePoints) {
  const int views = 12;
  FuseOptions options;
  PointFuser fuser(options);
  double single_error = 0;
  size_t single = 0;
  std::vector<char> visible;
  const TriangleMesh mesh = SphereMesh();
  const std::vector<Eigen::Vector3f> samples = SampleSurface(mesh, 20000);
  for (int i = 0; i < views; ++i) {
    const FuseView view = SphereView(i, views, 0.002);
    const FuseView clean = SphereView(i, views, 0.0);
    MarkVisible(samples, view.camera, view.cam_from_world, clean.depth, 0.01, &visible);
    for (int y = 0; y < 120; y += 3) {
      for (int x = 0; x < 160; x += 3) {
        const float d = view.depth.At(x, y);
        if (d <= 0) continue;
        const Eigen::Vector3d p = view.cam_from_world.Inverse() * (view.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)) * d);
        single_error += std::abs(p.norm() - 1), ++single;
      }
    }
    fuser.AddView(view);
  }
  FuseStats stats;
  const PointCloud cloud = fuser.Finish(&stats);
  ASSERT_GT(cloud.size(), 5000u);
  EXPECT_LT(stats.points, stats.samples / 2) << "samples should merge across views";
  double fused_error = 0;
  size_t outward = 0;
  for (size_t i = 0; i < cloud.size(); ++i) {
    fused_error += std::abs(cloud.positions[i].norm() - 1);
    outward += cloud.normals[i].dot(cloud.positions[i].normalized()) > 0.9f;
    ASSERT_EQ(cloud.colors[i], Color3u8(200, 120, 40));  // RGB of the BGR photo
    ASSERT_GT(cloud.confidence[i], 0.f);
    ASSERT_LE(cloud.confidence[i], 1.f);
  }
  fused_error /= cloud.size();
  single_error /= single;
  EXPECT_LT(fused_error, 0.7 * single_error) << "merging should reduce the noise";
  EXPECT_GT(outward, cloud.size() * 95 / 100);
  const PointSetAccuracy accuracy = EvaluatePointSet(cloud, mesh, samples, 0.03, &visible);
  EXPECT_LT(accuracy.accuracy_90, 0.01);
  EXPECT_GT(accuracy.completeness_visible, 0.95);
  EXPECT_LT(accuracy.completeness, accuracy.completeness_visible + 1e-9);
}

// Median confidence of the points two noise-free neighbouring views fuse into, the second view's
// depths scaled by `scale` (a disagreement its confidence-1 uncertainty does not explain).
float MedianPointConfidence(double scale, bool agreement_weighting) {
  FuseOptions options;
  options.agreement_weighting = agreement_weighting;
  options.min_views = 2;  // merged points only
  PointFuser fuser(options);
  fuser.AddView(SphereView(0, 12, 0));
  FuseView second = SphereView(1, 12, 0);
  for (float& d : second.depth.data) d *= static_cast<float>(scale);
  fuser.AddView(second);
  PointCloud cloud = fuser.Finish(nullptr);
  if (cloud.confidence.empty()) return -1;
  std::nth_element(cloud.confidence.begin(), cloud.confidence.begin() + cloud.confidence.size() / 2, cloud.confidence.end());
  return cloud.confidence[cloud.confidence.size() / 2];
}

TEST(Fuse, PointConfidenceFallsWhenItsSamplesDisagree) {
  // Agreeing samples: chi-square ~ 0, factor 1.
  EXPECT_GT(MedianPointConfidence(1.0, true), 0.95f);
  // 0.9% apart with sigmas of 0.3% each: merged (2.1 combined sigmas < merge_sigmas 3), but
  // chi-square 0.009^2 / (2 * 0.003^2) = 4.5 for one degree of freedom: exp(-(4.5 - 1) / 2) ~ 0.17.
  const float disagreeing = MedianPointConfidence(1.009, true);
  EXPECT_GT(disagreeing, 0.05f);
  EXPECT_LT(disagreeing, 0.35f);
  // Off: the mean of the samples' confidences (1).
  EXPECT_GT(MedianPointConfidence(1.009, false), 0.95f);
}

TEST(Fuse, LowConfidenceSamplesMakeNoPoints) {
  FuseOptions options;
  PointFuser fuser(options);
  for (int i = 0; i < 6; ++i) fuser.AddView(SphereView(i, 6, 0.001, /*blank_rows=*/120));
  FuseStats stats;
  EXPECT_EQ(fuser.Finish(&stats).size(), 0u);
  EXPECT_EQ(stats.samples, 0u);
}

// A confidence that is not a number counts as 0: such samples are skipped like low ones (NaN used
// to pass every `< min_confidence` test and the clamp).
TEST(Fuse, NotANumberConfidenceCountsAsZero) {
  PointFuser fuser{FuseOptions()};
  for (int i = 0; i < 6; ++i) {
    FuseView view = SphereView(i, 6, 0.001);
    for (float& c : view.confidence.data) c = std::numeric_limits<float>::quiet_NaN();
    fuser.AddView(view);
  }
  FuseStats stats;
  EXPECT_EQ(fuser.Finish(&stats).size(), 0u);
  EXPECT_EQ(stats.samples, 0u);
}

// With min_confidence 0, samples of confidence 0 still give their colour and normal to the points
// they make (they were black, with zero normals).
TEST(Fuse, ZeroConfidenceSamplesKeepColourAndNormal) {
  FuseOptions options;
  options.min_confidence = 0;
  PointFuser fuser(options);
  for (int i = 0; i < 6; ++i) {
    FuseView view = SphereView(i, 6, 0.001);
    for (float& c : view.confidence.data) c = 0.f;
    fuser.AddView(view);
  }
  const PointCloud cloud = fuser.Finish(nullptr);
  ASSERT_GT(cloud.size(), 1000u);
  for (size_t i = 0; i < cloud.size(); ++i) {
    ASSERT_EQ(cloud.colors[i], Color3u8(200, 120, 40));
    ASSERT_NEAR(cloud.normals[i].norm(), 1.f, 1e-4f);
    ASSERT_EQ(cloud.confidence[i], 0.f);
  }
}

// Points on a fronto-parallel square at depth 2 seen by one camera; the mask covers the left half
// of the image: the points left of the optical axis are on the silhouette, those behind the
// camera or outside the image are not counted.
TEST(SilhouetteCheck, CountsPointsLandingOnTheMask) {
  const Camera camera = Camera::Pinhole(100, 80, 50, 50, 50, 40);
  const Rigid3d cam_from_world;  // identity
  cv::Mat mask = cv::Mat::zeros(80, 100, CV_8UC1);
  mask.colRange(0, 50).setTo(255);
  PointCloud cloud;
  for (int i = 0; i < 40; ++i) {
    const float x = -1.5f + 3.0f * (i + 0.5f) / 40;  // projects to 50 + 25 x: columns 13..87
    cloud.positions.emplace_back(x, 0.1f, 2.0f);
  }
  cloud.positions.emplace_back(0.f, 0.f, -2.f);  // behind the camera
  cloud.positions.emplace_back(10.f, 0.f, 2.f);  // out of the image
  const SilhouetteHits hits = ProjectOntoSilhouette(cloud, camera, cam_from_world, mask);
  EXPECT_EQ(hits.projected, 40u);
  EXPECT_EQ(hits.on_silhouette, 20u);
  EXPECT_DOUBLE_EQ(hits.Fraction(), 0.5);
  // A mask at half the camera's resolution samples the same places.
  cv::Mat half;
  cv::resize(mask, half, cv::Size(50, 40), 0, 0, cv::INTER_NEAREST);
  EXPECT_EQ(ProjectOntoSilhouette(cloud, camera, cam_from_world, half).on_silhouette, 20u);
}

TEST(FuseStage, WritesAReadablePlyAndRecordsAccuracy) {
  const fs::path root = fs::temp_directory_path() / ("ibmr_fuse_test_" + std::to_string(::getpid()));
  fs::remove_all(root);
  const Workspace workspace(root.string());
  SparseModel model;
  const int views = 8;
  for (int i = 0; i < views; ++i) {
    const FuseView view = SphereView(i, views, 0.001);
    model.cameras[1] = view.camera;
    Image image;
    image.image_id = i + 1;
    image.camera_id = 1;
    image.name = "s" + std::to_string(i) + ".png";
    image.cam_from_world = view.cam_from_world;
    model.images[image.image_id] = image;
    WriteColmapArray(workspace.DepthMapPath(image.name, "geometric"), view.depth);
    WriteColmapArray(workspace.Path("dense/stereo/confidence_maps/" + image.name + ".geometric.bin"), view.confidence);
    WriteColmapArray(workspace.GroundTruthDepthPath(image.name), SphereView(i, views, 0).depth);
    fs::create_directories(workspace.ImagesDir());
    WriteImage(workspace.ImagesDir() + "/" + image.name, view.image);
  }
  WriteSparseModelText(workspace.SparseDir(), model);
  WriteMeshPly(workspace.GroundTruthMeshPath(), SphereMesh());

  StageRegistry registry;
  RegisterStage_fuse(&registry);
  const Stage* stage = registry.Find("fuse");
  ASSERT_NE(stage, nullptr);
  StageContext context;
  context.workspace = workspace;
  context.role = stage->Role();
  context.heldout_images = {"s7.png"};
  NullProgress progress;
  context.progress = &progress;
  context.params = DefaultParams(*stage, ".");
  context.params.Set("eval_samples", int64_t{20000});
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);
  const PointCloud cloud = ReadPointCloudPly(workspace.Path("dense/fused.ply"));
  EXPECT_GT(cloud.size(), 3000u);
  EXPECT_EQ(cloud.normals.size(), cloud.size());
  EXPECT_EQ(cloud.colors.size(), cloud.size());
  EXPECT_EQ(cloud.confidence.size(), cloud.size());
  EXPECT_LT(context.metrics["accuracy_90"].get<double>(), 0.01) << context.metrics.dump();
  EXPECT_GT(context.metrics["completeness_visible"].get<double>(), 0.85) << context.metrics.dump();
  EXPECT_EQ(context.metrics["views"].get<int>(), 7);

  Params bad = context.params;
  bad.Set("min_views", int64_t{0});
  ASSERT_TRUE(stage->CheckParams(bad).has_value());
  EXPECT_EQ(stage->CheckParams(bad)->key, "min_views");
  fs::remove(workspace.DepthMapPath("s2.png", "geometric"));
  try {
    stage->Run(context);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("s2.png.geometric.bin"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("multi_depth"), std::string::npos) << e.what();
  }
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
