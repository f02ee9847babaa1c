// Tests of point splatting from depth images and surfels (seed 004): no holes and bounded overlap on
// a fronto-parallel plane at the source resolution, epipole consistency, skins across a depth step
// (found where another view saw through them, never drawn), tile merging that culls redundancy but
// no surface, back-facing surfels, option checks.
#include "stages/render/splat.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <unistd.h>

#include <Eigen/Geometry>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/depth_normals.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/sparse_model.h"
#include "pipeline/core/workspace.h"
#include "stages/render/depth_image_io.h"
#include "stages/render/depth_images.h"

namespace ibmr {
namespace {

constexpr int kWidth = 80, kHeight = 60;
constexpr double kFocal = 70;

cv::Vec3b Texture(double x, double y) {
  const double r = 128 + 90 * std::sin(7.0 * x + 1.3 * std::cos(5.0 * y));
  const double g = 128 + 90 * std::sin(6.0 * y + 0.7) * std::cos(3.0 * x);
  const double b = 128 + 90 * std::cos(4.0 * (x + y));
  return cv::Vec3b(cv::saturate_cast<uint8_t>(b), cv::saturate_cast<uint8_t>(g), cv::saturate_cast<uint8_t>(r));
}

Camera TestCamera() { return Camera::Pinhole(kWidth, kHeight, kFocal, kFocal, kWidth / 2.0, kHeight / 2.0); }

// A camera at `center` looking along +z (identity rotation).
Rigid3d At(const Eigen::Vector3d& center) { return Rigid3d(Eigen::Matrix3d::Identity(), -center); }

// Scene: a background plane z = 4 and, when `step`, a foreground square |x|, |y| <= 0.4 at z = 2.
// Exact depth image (ray cast through pixel centres), colours from the texture, normals -z.
DepthImage View(const Eigen::Vector3d& center, bool step, const std::string& name) {
  DepthImage image;
  image.name = name;
  image.camera = TestCamera();
  image.cam_from_world = At(center);
  image.depth = DepthMap(kWidth, kHeight);
  image.normals = FloatMap(kWidth, kHeight, 3);
  image.image = cv::Mat(kHeight, kWidth, CV_8UC3);
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      const Eigen::Vector3d ray((x + 0.5 - kWidth / 2.0) / kFocal, (y + 0.5 - kHeight / 2.0) / kFocal, 1.0);
      double z = 4 - center.z();
      Eigen::Vector3d p = center + ray * z;
      if (step) {
        const double zf = 2 - center.z();
        const Eigen::Vector3d q = center + ray * zf;
        if (std::abs(q.x()) <= 0.4 && std::abs(q.y()) <= 0.4) {
          z = zf;
          p = q;
        }
      }
      image.depth.At(x, y) = static_cast<float>(z);
      image.normals.At(x, y, 2) = -1.f;
      image.image.at<cv::Vec3b>(y, x) = Texture(p.x() + (z < 3 ? 0.3 : 0), p.y());
    }
  }
  FlagSamples(&image, 0.0);
  return image;
}

TEST(SplatOptions, DefaultsValidAndRangesChecked) {
  std::string error;
  EXPECT_TRUE(SplatOptions().Check(&error)) << error;
  EXPECT_TRUE(DepthImageOptions().Check(&error)) << error;
  SplatOptions o;
  o.radius_scale = 0;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("radius_scale:", 0), 0u) << error;
  o = SplatOptions();
  o.depth_tolerance = 1;
  EXPECT_FALSE(o.Check(&error));
  EXPECT_EQ(error.rfind("depth_tolerance:", 0), 0u) << error;
  o = SplatOptions();
  o.max_radius_px = 0.1;
  EXPECT_FALSE(o.Check(&error));
  DepthImageOptions d;
  d.tile_size = 2;
  EXPECT_FALSE(d.Check(&error));
  EXPECT_EQ(error.rfind("tile_size:", 0), 0u) << error;
  d = DepthImageOptions();
  d.skin_views = -1;
  EXPECT_FALSE(d.Check(&error));
}

// The consuming form builds the same cloud as the copying one, sample for sample (flagged and
// invalid pixels left out, sources in order, sized exactly), and frees the images.
TEST(Splat, CloudFromConsumedImagesEqualsCloudFromCopies) {
  std::vector<DepthImage> images = {View(Eigen::Vector3d::Zero(), true, "a"), View({0.3, 0, 0}, false, "b"),
                                    View({-0.2, 0.1, 0}, true, "c")};
  images[0].flags[5] |= kSampleMerged;
  images[1].depth.At(7, 3) = 0.f;
  images[2].flags.clear();  // no flags: every valid depth is a sample
  images[2].depth.At(1, 1) = -1.f;
  const SplatCloud copied = CloudFromDepthImages(images);
  ASSERT_EQ(copied.size(), 3u * kWidth * kHeight - 3);
  EXPECT_EQ(copied.positions.capacity(), copied.size());
  std::vector<DepthImage> consumed = images;
  const SplatCloud moved = CloudFromDepthImages(std::move(consumed));
  EXPECT_TRUE(consumed.empty());
  ASSERT_EQ(moved.size(), copied.size());
  ASSERT_EQ(moved.source_centers.size(), 3u);
  for (size_t i = 0; i < copied.size(); ++i) {
    ASSERT_EQ(moved.positions[i], copied.positions[i]) << i;
    ASSERT_EQ(moved.normals[i], copied.normals[i]) << i;
    ASSERT_EQ(moved.colors[i], copied.colors[i]) << i;
    ASSERT_EQ(moved.confidence[i], copied.confidence[i]) << i;
    ASSERT_EQ(moved.footprint[i], copied.footprint[i]) << i;
    ASSERT_EQ(moved.source[i], copied.source[i]) << i;
  }
  EXPECT_EQ(copied.source.front(), 0);
  EXPECT_EQ(copied.source.back(), 2);
}

// A fronto-parallel plane seen at the source resolution: every pixel covered, each by at most two
// splats on average, from the source's own viewpoint and from a slightly moved one.
TEST(Splat, FrontoParallelPlaneHasNoHolesAndBoundedOverlap) {
  std::vector<DepthImage> images = {View(Eigen::Vector3d::Zero(), false, "a")};
  const SplatCloud cloud = CloudFromDepthImages(images);
  ASSERT_EQ(cloud.size(), static_cast<size_t>(kWidth * kHeight));
  for (const Eigen::Vector3d& eye : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.05, 0.03, 0.02)}) {
    const SplatImage out = RenderSplats(cloud, TestCamera(), At(eye), SplatOptions());
    // Inner pixels (the moved view sees past the source's border at its edges).
    size_t inner = 0, holes = 0;
    for (int y = 4; y < kHeight - 4; ++y) {
      for (int x = 4; x < kWidth - 4; ++x) {
        ++inner;
        holes += out.coverage.at<uint8_t>(y, x) == 0;
      }
    }
    EXPECT_EQ(holes, 0u) << "eye " << eye.transpose() << ": " << holes << " of " << inner << " inner pixels uncovered";
    ASSERT_GT(out.covered_pixels, 0u);
    const double overlap = static_cast<double>(out.pixel_hits) / out.covered_pixels;
    EXPECT_GE(overlap, 1.0);
    EXPECT_LE(overlap, 2.0) << "eye " << eye.transpose();
  }
  // Twice too large splats overlap more than twice: the measure can fail.
  SplatOptions large;
  large.radius_scale = 2.2;
  const SplatImage out = RenderSplats(cloud, TestCamera(), At(Eigen::Vector3d::Zero()), large);
  EXPECT_GT(static_cast<double>(out.pixel_hits) / out.covered_pixels, 2.0);
}

// Sparser depth images for model selection: a 2x2-block version of the plane has a quarter of the
// samples, a camera scaled by exactly 1/2 and, splatted at the full resolution, still no holes.
TEST(Splat, BlockDownsampledDepthImagesCoverThePlaneWithAQuarterOfTheSamples) {
  const DepthImage full = View(Eigen::Vector3d::Zero(), false, "a");
  std::vector<DepthImage> half = {DownsampleDepthImage(full, 2)};
  ASSERT_EQ(half[0].width(), kWidth / 2);
  EXPECT_DOUBLE_EQ(half[0].camera.FocalX(), kFocal / 2);
  EXPECT_DOUBLE_EQ(half[0].camera.PrincipalX(), kWidth / 4.0);
  EXPECT_FLOAT_EQ(half[0].depth.At(10, 10), 4.f);
  // The block colour is the mean of its four pixels.
  const cv::Vec3b a = full.image.at<cv::Vec3b>(20, 20), b = full.image.at<cv::Vec3b>(20, 21),
                  c = full.image.at<cv::Vec3b>(21, 20), d = full.image.at<cv::Vec3b>(21, 21);
  EXPECT_NEAR(half[0].image.at<cv::Vec3b>(10, 10)[1], (a[1] + b[1] + c[1] + d[1]) / 4.0, 1.0);
  FlagSamples(&half[0], 0.0);
  const SplatCloud cloud = CloudFromDepthImages(half);
  EXPECT_EQ(cloud.size(), static_cast<size_t>(kWidth * kHeight / 4));
  const SplatImage out = RenderSplats(cloud, TestCamera(), At(Eigen::Vector3d::Zero()), SplatOptions());
  size_t holes = 0;
  for (int y = 2; y < kHeight - 2; ++y) {
    for (int x = 2; x < kWidth - 2; ++x) holes += out.coverage.at<uint8_t>(y, x) == 0;
  }
  EXPECT_EQ(holes, 0u);
}

// A sphere's depth image (radius 1 at distance 4, normals from the depth as the renderer gets
// them) seen from 20 degrees around it: near the desired view's silhouette the surface is
// edge-on, and the footprints, the source pixels laid on the tangent planes [S 5.3], are thin
// across it. Discs facing the viewer would reach past the silhouette by their radius.
TEST(Splat, FootprintsOfAnEdgeOnSurfaceStayInsideTheSilhouette) {
  constexpr int kW = 160, kH = 120;
  constexpr double kF = 140, kAngle = 20 * M_PI / 180;
  const Camera camera = Camera::Pinhole(kW, kH, kF, kF, kW / 2.0, kH / 2.0);
  const Eigen::Vector3d sphere(0, 0, 4);
  // Length along `ray` from `origin` to the sphere, or 0.
  const auto hit = [&](const Eigen::Vector3d& origin, const Eigen::Vector3d& ray) {
    const Eigen::Vector3d o = origin - sphere;
    const double a = ray.squaredNorm(), b = o.dot(ray), c = o.squaredNorm() - 1;
    const double disc = b * b - a * c;
    return disc < 0 ? 0.0 : (-b - std::sqrt(disc)) / a;
  };
  DepthImage source;
  source.name = "source";
  source.camera = camera;
  source.cam_from_world = At(Eigen::Vector3d::Zero());
  source.depth = DepthMap(kW, kH);
  source.image = cv::Mat(kH, kW, CV_8UC3, cv::Scalar(200, 150, 100));
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const Eigen::Vector3d ray((x + 0.5 - kW / 2.0) / kF, (y + 0.5 - kH / 2.0) / kF, 1.0);
      source.depth.At(x, y) = static_cast<float>(hit(Eigen::Vector3d::Zero(), ray));  // z, as the ray has z = 1
    }
  }
  source.normals = NormalsFromDepth(camera, source.depth);
  FlagSamples(&source, 0.0);
  const SplatCloud cloud = CloudFromDepthImages({source});

  // The desired camera on the circle around the sphere, looking at its centre.
  const Eigen::Matrix3d world_from_cam = Eigen::AngleAxisd(kAngle, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::Vector3d center = sphere - world_from_cam.col(2) * 4;
  const Rigid3d desired(world_from_cam.transpose(), -world_from_cam.transpose() * center);
  const SplatImage out = RenderSplats(cloud, camera, desired, SplatOptions());
  int spilled = 0, silhouette = 0;
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      const Eigen::Vector3d ray = world_from_cam * Eigen::Vector3d((x + 0.5 - kW / 2.0) / kF, (y + 0.5 - kH / 2.0) / kF, 1.0);
      const bool inside = hit(center, ray) > 0;
      const bool right_of = x + 1 < kW && hit(center, world_from_cam * Eigen::Vector3d((x + 1.5 - kW / 2.0) / kF, (y + 0.5 - kH / 2.0) / kF, 1.0)) > 0;
      silhouette += inside != right_of;
      spilled += !inside && out.coverage.at<uint8_t>(y, x) != 0;
    }
  }
  ASSERT_GT(silhouette, 40);
  // A pixel centre within a splat's smallest radius of the silhouette may still be drawn: a few.
  EXPECT_LT(spilled, silhouette / 4) << spilled << " pixels outside the sphere drawn, " << silhouette << " silhouette crossings";
}

// Epipole consistency [U 50]: a desired camera at a source camera reproduces that source's photo,
// though other sources see the same surface.
TEST(Splat, DesiredCameraAtASourceReproducesItsImage) {
  std::vector<DepthImage> images = {View({0, 0, 0}, true, "a"), View({0.3, 0, 0}, true, "b"),
                                    View({-0.2, 0.2, 0}, true, "c")};
  const SplatCloud cloud = CloudFromDepthImages(images);
  SplatOptions options;
  const SplatImage out = RenderSplats(cloud, TestCamera(), images[1].cam_from_world, options);
  double squared = 0;
  size_t counted = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      ASSERT_NE(out.coverage.at<uint8_t>(y, x), 0) << "pixel " << x << "," << y << " uncovered";
      const cv::Vec3b a = out.image.at<cv::Vec3b>(y, x), b = images[1].image.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) squared += (a[c] - b[c]) * (a[c] - b[c]);
      counted += 3;
    }
  }
  const double psnr = 10 * std::log10(255.0 * 255.0 / std::max(squared / counted, 1e-12));
  EXPECT_GT(psnr, 40.0);
}

// Passes over bands of rows (SplatOptions::pass_bytes; 1 byte: a pass per band) draw the image of
// one pass, to the bit, from a moved viewpoint where splats straddle the bands, with k = 4 and 0.
TEST(Splat, PassesOverBandsOfRowsDrawAsOnePass) {
  std::vector<DepthImage> images = {View({0, 0, 0}, true, "a"), View({0.3, 0, 0}, true, "b"),
                                    View({-0.2, 0.2, 0}, true, "c")};
  const SplatCloud cloud = CloudFromDepthImages(images);
  for (const int k : {4, 0}) {
    SplatOptions one, many;
    one.k = many.k = k;
    many.pass_bytes = 1;
    const Rigid3d pose = At(Eigen::Vector3d(0.11, -0.07, 0.05));
    const SplatImage a = RenderSplats(cloud, TestCamera(), pose, one), b = RenderSplats(cloud, TestCamera(), pose, many);
    EXPECT_GT(a.covered_pixels, static_cast<size_t>(kWidth * kHeight / 2));
    EXPECT_EQ(cv::norm(a.image, b.image, cv::NORM_INF), 0.0) << "k " << k;
    EXPECT_EQ(cv::norm(a.coverage, b.coverage, cv::NORM_INF), 0.0) << "k " << k;
    EXPECT_EQ(a.depth.data, b.depth.data) << "k " << k;
    EXPECT_EQ(a.covered_pixels, b.covered_pixels);
    EXPECT_EQ(a.splats_drawn, b.splats_drawn);
    EXPECT_EQ(a.pixel_hits, b.pixel_hits);
  }
}

// Leave-one-out (render.exclude_self): a training view rendered without its own samples is drawn
// exactly as from a model built without its depth image; its photo (here a marker colour) shows
// nowhere.
TEST(Splat, ExcludedSourceIsNotDrawn) {
  std::vector<DepthImage> images = {View({0, 0, 0}, false, "a"), View({0.3, 0, 0}, false, "b"),
                                    View({-0.2, 0.2, 0}, false, "c")};
  images[1].image.setTo(cv::Scalar(0, 0, 255));  // a colour the texture never has: its channels stay in [38, 218]
  const SplatCloud cloud = CloudFromDepthImages(images);
  const SplatCloud others = CloudFromDepthImages({images[0], images[2]});
  const Rigid3d at_b = images[1].cam_from_world;
  const auto reddest = [](const SplatImage& out) {  // the largest red excess over blue
    int most = -255;
    for (int y = 0; y < out.image.rows; ++y) {
      for (int x = 0; x < out.image.cols; ++x) {
        const cv::Vec3b& c = out.image.at<cv::Vec3b>(y, x);
        most = std::max(most, static_cast<int>(c[2]) - c[0]);
      }
    }
    return most;
  };
  EXPECT_GT(reddest(RenderSplats(cloud, TestCamera(), at_b, SplatOptions())), 200);  // its own samples weigh most
  const SplatImage without = RenderSplats(cloud, TestCamera(), at_b, SplatOptions(), 1);
  const SplatImage expected = RenderSplats(others, TestCamera(), at_b, SplatOptions());
  EXPECT_LT(reddest(without), 200);
  EXPECT_GT(without.covered_pixels, static_cast<size_t>(kWidth * kHeight / 2));  // the others still cover it
  EXPECT_EQ(without.covered_pixels, expected.covered_pixels);
  EXPECT_EQ(cv::norm(without.image, expected.image, cv::NORM_INF), 0.0);
}

// A depth map of another aspect ratio than its image: the camera scaled by the width ratio would
// put every sample at the wrong height, so loading it fails naming the file and what to re-run.
TEST(DepthImageIo, RejectsDepthMapOfAnotherAspectRatio) {
  const std::filesystem::path root =
      std::filesystem::temp_directory_path() / ("ibmr_depth_io_test_" + std::to_string(::getpid()));
  std::filesystem::remove_all(root);
  std::filesystem::create_directories(root / "images");
  std::filesystem::create_directories(root / "dense/stereo/depth_maps");
  const Workspace workspace(root.string());
  SparseModel model;
  model.cameras[1] = TestCamera();  // 80 x 60
  Image image;
  image.image_id = 1;
  image.camera_id = 1;
  image.name = "a.png";
  model.images[1] = image;
  WriteImage(workspace.ImagesDir() + "/a.png", cv::Mat(kHeight, kWidth, CV_8UC3, cv::Scalar::all(128)));
  const std::string depth_path = workspace.DepthMapPath("a.png", "geometric");
  // Half the width: 40 x 30 is this image's aspect ratio (30 +- 1 accepted), 40 x 40 is not.
  for (const int height : {30, 31, 40}) {
    WriteColmapArray(depth_path, DepthMap(kWidth / 2, height, 1, 2.f));
    if (height != 40) {
      const std::vector<DepthImage> images = LoadDepthImages(workspace, model, {"a.png"}, "geometric");
      ASSERT_EQ(images.size(), 1u);
      EXPECT_EQ(images[0].camera.width, kWidth / 2);
      EXPECT_EQ(images[0].camera.height, kHeight / 2);
      continue;
    }
    try {
      LoadDepthImages(workspace, model, {"a.png"}, "geometric");
      ADD_FAILURE() << "a 40x40 depth map of an 80x60 image was accepted";
    } catch (const InputError& e) {
      const std::string message = e.what();
      EXPECT_NE(message.find(depth_path), std::string::npos) << message;
      EXPECT_NE(message.find("plane_sweep / multi_depth"), std::string::npos) << message;
    }
  }
  std::filesystem::remove_all(root);
}

// Skins [N 4.4]: between a view and one displaced sideways, the connections across the square's
// border (depth 2 to 4) are skins where the other view sees the background through them; no
// connection inside a surface is. A render from between the views draws no sample between the
// two depths.
TEST(Splat, SkinsAcrossADepthStepAreFoundAndNeverDrawn) {
  std::vector<DepthImage> images = {View({0, 0, 0}, true, "a"), View({0.6, 0, 0}, true, "b")};
  DepthImageOptions options;
  options.skin_views = 1;
  const size_t skins = DetectSkins(&images, options);
  EXPECT_GT(skins, 0u);
  const DepthImage& a = images[0];
  size_t flagged = 0, at_step = 0;
  for (int y = 0; y < kHeight; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      if (!(a.flags[y * kWidth + x] & kSampleSkin)) continue;
      ++flagged;
      // A skin end has a 4-neighbour on the other side of the step.
      bool step = false;
      for (const auto& [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        const int nx = x + dx, ny = y + dy;
        if (nx >= 0 && ny >= 0 && nx < kWidth && ny < kHeight) step = step || std::abs(a.depth.At(nx, ny) - a.depth.At(x, y)) > 1;
      }
      at_step += step;
    }
  }
  EXPECT_GT(flagged, 0u);
  EXPECT_EQ(at_step, flagged) << "skin flags away from the depth step";
  // View b sits to the right (+x): it sees behind the square's right border in a, not its left
  // (rows well inside the square: b shares a's height, so the top and bottom borders are grazing).
  int right = 0, left = 0;
  for (int y = 20; y < 40; ++y) {
    for (int x = 0; x < kWidth; ++x) {
      if (!(a.flags[y * kWidth + x] & kSampleSkin)) continue;
      (x > kWidth / 2 ? right : left)++;
    }
  }
  EXPECT_GT(right, 10);
  EXPECT_EQ(left, 0);

  const SplatCloud cloud = CloudFromDepthImages(images);
  const SplatImage out = RenderSplats(cloud, TestCamera(), At({0.3, 0, 0}), SplatOptions());
  size_t between = 0;
  for (const float z : out.depth.data) between += z > 2.1f && z < 3.9f;
  EXPECT_EQ(between, 0u) << "pixels drawn at a depth between the square and the background";
}

// Merging [N 4.6]: two views of one plane hold each surface point twice; merging culls about one of
// each pair and the render still covers what it covered.
TEST(Splat, MergingCullsRedundancyButNoSurface) {
  std::vector<DepthImage> images = {View({0, 0, 0}, false, "a"), View({0.02, 0, 0.5}, false, "b")};
  const SplatCloud all = CloudFromDepthImages(images);
  const SplatImage before = RenderSplats(all, TestCamera(), At({0.01, 0, 0.2}), SplatOptions());
  const size_t culled = MergeTiles(&images, DepthImageOptions());
  EXPECT_GT(culled, static_cast<size_t>(kWidth * kHeight) / 2);
  // View b is nearer the plane: it samples it more densely and keeps its samples.
  size_t culled_b = 0;
  for (const uint8_t flag : images[1].flags) culled_b += (flag & kSampleMerged) != 0;
  EXPECT_LT(culled_b, culled / 10);
  const SplatCloud merged = CloudFromDepthImages(images);
  EXPECT_EQ(merged.size(), all.size() - culled);
  const SplatImage after = RenderSplats(merged, TestCamera(), At({0.01, 0, 0.2}), SplatOptions());
  EXPECT_GE(after.covered_pixels, before.covered_pixels * 99 / 100);
}

// Surfels are discs: drawn facing the camera, not from behind.
TEST(Splat, SurfelsFacingAwayAreNotDrawn) {
  PointCloud surfels;
  surfels.positions = {Eigen::Vector3f(0, 0, 2)};
  surfels.normals = {Eigen::Vector3f(0, 0, -1)};
  surfels.radius = {0.05f};
  surfels.colors = {Color3u8{200, 100, 50}};
  SplatCloud cloud = CloudFromSurfels(surfels, 0.01f);
  SplatImage out = RenderSplats(cloud, TestCamera(), At(Eigen::Vector3d::Zero()), SplatOptions());
  // Radius 70 * 0.05 / 2 = 1.75 px around the centre pixel; colour kept (BGR).
  ASSERT_GT(out.covered_pixels, 0u);
  EXPECT_EQ(out.image.at<cv::Vec3b>(kHeight / 2, kWidth / 2), cv::Vec3b(50, 100, 200));
  cloud.normals[0] = Eigen::Vector3f(0, 0, 1);
  out = RenderSplats(cloud, TestCamera(), At(Eigen::Vector3d::Zero()), SplatOptions());
  EXPECT_EQ(out.covered_pixels, 0u);
}

}  // namespace
}  // namespace ibmr
