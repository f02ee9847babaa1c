// The splat rasterizer: analytic gradients of every parameter kind against central differences on
// a few overlapping discs (one seen nearly edge-on, where the screen-space floor decides, and
// discs at the silhouette over the background); the vectorised tile loops against a per-pixel
// definition, and every instruction set's build against the others; the vectorised exp within its
// bound; the front-to-back order in every tile; splats behind the camera ignored; the PLY layout
// round trip and a file laid out as a 3D Gaussian splatting trainer writes it.
#include "pipeline/core/splat_rasterizer.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <cmath>
#include <filesystem>
#include <limits>
#include <random>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/splat_tiles.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

SplatCamera TestCamera(int width = 48, int height = 40, float focal = 50) {
  SplatCamera camera;
  camera.width = width;
  camera.height = height;
  camera.fx = camera.fy = focal;
  camera.cx = 0.5f * width;
  camera.cy = 0.5f * height;
  return camera;  // at the origin, looking along +z
}

// Overlapping discs at depths 2.6 .. 3.4 in front of the camera; the last one nearly edge-on.
GaussianSplats TestSplats(int sh_degree) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> unit(-1, 1);
  GaussianSplats splats;
  splats.sh_degree = sh_degree;
  const Eigen::Vector3f centres[5] = {{-0.25f, -0.1f, 2.6f}, {0.1f, 0.05f, 2.8f}, {0.3f, -0.2f, 3.0f},
                                      {-0.1f, 0.3f, 3.2f}, {0.05f, -0.05f, 3.4f}};
  for (int i = 0; i < 5; ++i) {
    Eigen::Vector3f normal(0.3f * unit(rng), 0.3f * unit(rng), -1.0f);
    if (i == 4) normal = Eigen::Vector3f(1.0f, 0.02f, 0.015f);  // seen nearly edge-on
    Eigen::Vector4f rotation = RotationWithNormal(normal.normalized());
    rotation += Eigen::Vector4f(0.05f * unit(rng), 0.05f * unit(rng), 0.05f * unit(rng), 0.05f * unit(rng));
    splats.Add(centres[i], rotation * 1.3f, Eigen::Vector2f(std::log(0.12f + 0.05f * i), std::log(0.2f - 0.02f * i)),
               0.45f + 0.08f * i, Eigen::Vector3f(0.3f + 0.1f * i, 0.6f - 0.05f * i, 0.5f));
    float* sh = splats.Sh(splats.size() - 1);
    for (int k = 3; k < splats.ShCount() * 3; ++k) sh[k] = 0.15f * unit(rng);
  }
  return splats;
}

struct Problem {
  SplatCamera camera = TestCamera();
  SplatRasterOptions options;
  cv::Mat weights;  // the loss: sum of weights * image

  Problem() {
    options.background = Eigen::Vector3f(0.2f, 0.7f, 0.4f);
    // A smooth image: no alpha threshold, footprints out to where the falloff is below 1e-7 (the
    // rendering's cut-offs are steps a central difference would see).
    options.min_alpha = 0.0f;
    options.extent_sigmas = 6.0f;
    weights.create(camera.height, camera.width, CV_32FC3);
    cv::randu(weights, -1.0, 1.0);
  }
  double Loss(const GaussianSplats& splats) const {
    SplatFrame frame;
    RenderSplats(splats, camera, options, &frame);
    double sum = 0;
    for (int y = 0; y < camera.height; ++y) {
      for (int x = 0; x < camera.width; ++x) {
        for (int c = 0; c < 3; ++c) sum += static_cast<double>(frame.image.at<cv::Vec3f>(y, x)[c]) * weights.at<cv::Vec3f>(y, x)[c];
      }
    }
    return sum;
  }
  SplatGradients Gradients(const GaussianSplats& splats) const {
    SplatFrame frame;
    RenderSplats(splats, camera, options, &frame);
    SplatGradients gradients;
    gradients.Reset(splats);
    BackwardSplats(splats, camera, frame, weights, &gradients);
    return gradients;
  }
};

// Central difference of the loss in one float of the splats, against the analytic value.
void ExpectDerivative(const Problem& problem, GaussianSplats& splats, float* value, float step, double analytic,
                      const std::string& what) {
  const float original = *value;
  *value = original + step;
  const double plus = problem.Loss(splats);
  *value = original - step;
  const double minus = problem.Loss(splats);
  *value = original;
  const double numeric = (plus - minus) / (2.0 * step);
  EXPECT_NEAR(analytic, numeric, 0.03 * std::max(std::abs(numeric), std::abs(analytic)) + 0.02) << what;
}

TEST(SplatGradients, EveryParameterKindAgreesWithCentralDifferences) {
  Problem problem;
  problem.options.sh_degree = 0;  // the SH view direction is held fixed: check geometry at degree 0
  GaussianSplats splats = TestSplats(0);
  const SplatGradients g = problem.Gradients(splats);
  for (size_t i = 0; i < splats.size(); ++i) {
    // The edge-on disc's footprint is about 0.07 px thick: its position and rotation need a step
    // ten times smaller for the central difference to resolve it.
    const std::string at = " of splat " + std::to_string(i);
    for (int a = 0; a < 3; ++a) {
      GaussianSplats copy = splats;
      ExpectDerivative(problem, copy, &copy.position[i][a], i == 4 ? 1e-4f : 1e-3f, g.position[i][a], "position " + std::to_string(a) + at);
    }
    for (int a = 0; a < 4; ++a) {
      GaussianSplats copy = splats;
      ExpectDerivative(problem, copy, &copy.rotation[i][a], i == 4 ? 1e-4f : 1e-3f, g.rotation[i][a], "rotation " + std::to_string(a) + at);
    }
    for (int a = 0; a < 2; ++a) {
      GaussianSplats copy = splats;
      ExpectDerivative(problem, copy, &copy.log_scale[i][a], 1e-3f, g.log_scale[i][a], "log scale " + std::to_string(a) + at);
    }
    GaussianSplats copy = splats;
    ExpectDerivative(problem, copy, &copy.opacity_logit[i], 1e-3f, g.opacity_logit[i], "opacity" + at);
  }
  EXPECT_GT(g.position[4].norm(), 0.0f) << "the edge-on disc is drawn by its screen-space floor and moves with it";
}

TEST(SplatGradients, EverySphericalHarmonicDegreeAgreesWithCentralDifferences) {
  for (int degree = 0; degree <= 3; ++degree) {
    Problem problem;
    GaussianSplats splats = TestSplats(degree);
    const SplatGradients g = problem.Gradients(splats);
    for (size_t i = 0; i < splats.size(); ++i) {
      for (int k = 0; k < splats.ShCount() * 3; k += 2) {
        GaussianSplats copy = splats;
        ExpectDerivative(problem, copy, &copy.Sh(i)[k], 1e-2f, g.sh[i * splats.ShCount() * 3 + k],
                         "degree " + std::to_string(degree) + " coefficient " + std::to_string(k) + " of splat " +
                             std::to_string(i));
      }
    }
  }
}

TEST(SplatGradients, AtASilhouetteOverTheBackground) {
  // One disc half out of the picture's object: its edge over the background colour.
  Problem problem;
  problem.options.sh_degree = 0;
  GaussianSplats splats;
  splats.Add({0.4f, 0.1f, 3.0f}, RotationWithNormal({0.1f, 0.2f, -1.0f}), {std::log(0.3f), std::log(0.15f)}, 0.8f,
             {0.9f, 0.2f, 0.1f});
  const SplatGradients g = problem.Gradients(splats);
  for (int a = 0; a < 3; ++a) {
    GaussianSplats copy = splats;
    ExpectDerivative(problem, copy, &copy.position[0][a], 1e-3f, g.position[0][a], "silhouette position " + std::to_string(a));
  }
  for (int a = 0; a < 2; ++a) {
    GaussianSplats copy = splats;
    ExpectDerivative(problem, copy, &copy.log_scale[0][a], 1e-3f, g.log_scale[0][a], "silhouette scale " + std::to_string(a));
  }
}

// Every instruction set this build has tile loops for and this CPU runs.
std::vector<splat_tiles::Isa> RunnableIsas() {
  std::vector<splat_tiles::Isa> isas;
  for (splat_tiles::Isa isa : {splat_tiles::Isa::kPortable, splat_tiles::Isa::kAvx2, splat_tiles::Isa::kAvx512}) {
    if (splat_tiles::IsaSupported(isa)) isas.push_back(isa);
  }
  return isas;
}

TEST(SplatExp, StaysWithinItsBound) {
  // Against double exp over the range the falloff uses with min_alpha 1/255 ([-5.6, 0]), over
  // [-20, 0] and down to -87, where it stops.
  double worst = 0;
  float worst_at = 0;
  for (const float lowest : {-5.6f, -20.0f, -87.0f}) {
    const int samples = 1000000;
    for (int k = 0; k <= samples; ++k) {
      const float x = lowest * static_cast<float>(k) / samples;
      const double truth = std::exp(static_cast<double>(x));
      const double error = std::abs(splat_tiles::ExpNonPositive(x) - truth) / truth;
      if (error > worst) worst = error, worst_at = x;
    }
  }
  EXPECT_LE(worst, splat_tiles::kExpMaxRelativeError) << "at " << worst_at;
  EXPECT_EQ(splat_tiles::ExpNonPositive(0.0f), 1.0f);
  EXPECT_GT(splat_tiles::ExpNonPositive(-87.0f), 0.0f);
  EXPECT_EQ(splat_tiles::ExpNonPositive(-87.01f), 0.0f) << "below -87: 0";
  EXPECT_EQ(splat_tiles::ExpNonPositive(-std::numeric_limits<float>::infinity()), 0.0f);
}

// What a pixel shows, drawn one pixel at a time with std::exp from the per-splat quantities
// RenderSplats computed (the rasterizer's definition in splat_rasterizer.h, as the scalar loop
// before the vectorised one wrote it, falloffs below exp(-87) taken as 0 as the header says).
struct PixelByPixel {
  cv::Mat image, transmittance, depth;
  std::vector<int> last_splat;  // per pixel: the last splat composited (-1: none)
  int ended = 0;                 // pixels whose walk a splat ended (no more light would pass)
};

PixelByPixel DrawPixelByPixel(const SplatFrame& frame) {
  const SplatRasterOptions& options = frame.options;
  const float cutoff = SplatCutoffSquared(options);
  const float inv_two_sigma2 = 1.0f / (2.0f * options.lowpass_sigma * options.lowpass_sigma);
  PixelByPixel out;
  out.image.create(frame.height, frame.width, CV_32FC3);
  out.transmittance.create(frame.height, frame.width, CV_32FC1);
  out.depth.create(frame.height, frame.width, CV_32FC1);
  out.last_splat.assign(static_cast<size_t>(frame.width) * frame.height, -1);
  for (int row = 0; row < frame.height; ++row) {
    for (int column = 0; column < frame.width; ++column) {
      // The splats whose footprint box holds the pixel, front to back (ties in index order).
      std::vector<int> splats;
      for (size_t i = 0; i < frame.visible.size(); ++i) {
        const Eigen::Vector4i& b = frame.box[i];
        if (frame.visible[i] && column >= b[0] && column <= b[2] && row >= b[1] && row <= b[3]) splats.push_back(static_cast<int>(i));
      }
      std::stable_sort(splats.begin(), splats.end(), [&](int a, int b) { return frame.view_depth[a] < frame.view_depth[b]; });
      const float x = column + 0.5f, y = row + 0.5f;
      float transmit = 1.0f, depth = 0.0f;
      Eigen::Vector3f colour = Eigen::Vector3f::Zero();
      for (const int i : splats) {
        const Eigen::Matrix3f& a = frame.inverse[i];
        const float w0 = a(0, 0) * x + a(0, 1) * y + a(0, 2);
        const float w1 = a(1, 0) * x + a(1, 1) * y + a(1, 2);
        const float w2 = a(2, 0) * x + a(2, 1) * y + a(2, 2);
        float g = 0, gl = 0;
        if (w2 > 0) {
          const float u = w0 / w2, v = w1 / w2;
          const float r2 = u * u + v * v;
          if (r2 < cutoff && 0.5f * r2 <= 87.0f) g = std::exp(-0.5f * r2);
        }
        const float dx = x - frame.centre[i].x(), dy = y - frame.centre[i].y();
        const float d2 = (dx * dx + dy * dy) * inv_two_sigma2;
        if (d2 < 0.5f * cutoff && d2 <= 87.0f) gl = std::exp(-d2);
        const bool object = g > 0 && g >= gl;
        const float alpha = std::min(0.99f, frame.opacity[i] * (object ? g : gl));
        if (alpha < options.min_alpha || alpha <= 0.0f) continue;
        const float next = transmit * (1.0f - alpha);
        if (next < 1e-4f) {
          ++out.ended;
          break;
        }
        colour += frame.colour[i].cwiseMax(0.0f) * (alpha * transmit);
        if (depth == 0.0f && alpha >= 0.5f) depth = object ? 1.0f / w2 : frame.view_depth[i];
        transmit = next;
        out.last_splat[static_cast<size_t>(row) * frame.width + column] = i;
      }
      for (int c = 0; c < 3; ++c) out.image.at<cv::Vec3f>(row, column)[c] = colour[c] + transmit * options.background[c];
      out.transmittance.at<float>(row, column) = transmit;
      out.depth.at<float>(row, column) = depth;
    }
  }
  return out;
}

// The discs of TestSplats, eight nearly opaque ones in front of them whose middle no light passes
// (saturated pixels: the tile loops stop there), and one across the picture's right edge.
GaussianSplats OverlappingSaturatedAndCutSplats() {
  GaussianSplats splats = TestSplats(1);
  for (int k = 0; k < 8; ++k) {
    splats.Add({0.02f * k - 0.08f, 0.01f * k, 2.0f + 0.05f * k}, RotationWithNormal(Eigen::Vector3f(0.05f * k, 0.1f, -1.0f).normalized()),
               {std::log(0.25f), std::log(0.2f)}, 0.99f, {0.9f - 0.1f * k, 0.2f + 0.1f * k, 0.5f});
  }
  splats.Add({0.95f, 0.2f, 2.5f}, RotationWithNormal({0.2f, 0.0f, -1.0f}), {std::log(0.2f), std::log(0.25f)}, 0.8f, {0.1f, 0.9f, 0.3f});
  return splats;
}

TEST(SplatRaster, TheTileLoopsDrawWhatAPixelByPixelDefinitionDraws) {
  const GaussianSplats splats = OverlappingSaturatedAndCutSplats();
  SplatRasterOptions drawn;  // the defaults: min_alpha 1/255, 3 sigmas
  drawn.background = Eigen::Vector3f(0.2f, 0.7f, 0.4f);
  SplatRasterOptions smooth = Problem().options;  // the gradient tests': no alpha threshold, 6 sigmas
  const splat_tiles::Isa was = splat_tiles::ActiveIsa();
  for (const splat_tiles::Isa isa : RunnableIsas()) {
    ASSERT_TRUE(splat_tiles::SetIsa(isa));
    for (const SplatRasterOptions& options : {drawn, smooth}) {
      const std::string what = std::string(splat_tiles::IsaName(isa)) + (options.min_alpha > 0 ? ", min_alpha" : ", smooth");
      SplatFrame frame;
      RenderSplats(splats, TestCamera(), options, &frame);
      const PixelByPixel reference = DrawPixelByPixel(frame);
      int silhouette = 0;
      for (int row = 0; row < frame.height; ++row) {
        for (int column = 0; column < frame.width; ++column) {
          const size_t p = static_cast<size_t>(row) * frame.width + column;
          for (int c = 0; c < 3; ++c) {
            ASSERT_NEAR(frame.image.at<cv::Vec3f>(row, column)[c], reference.image.at<cv::Vec3f>(row, column)[c], 1e-5f)
                << what << " at " << column << ", " << row;
          }
          ASSERT_NEAR(frame.transmittance.at<float>(row, column), reference.transmittance.at<float>(row, column), 1e-5f) << what;
          ASSERT_NEAR(frame.depth.at<float>(row, column), reference.depth.at<float>(row, column), 1e-5f) << what;
          // `last` counts into the pixel's tile list: it names the same splat as the reference's last.
          const int tile = (row / kSplatTile) * frame.tiles_x + column / kSplatTile;
          const int last = frame.last[p] == 0 ? -1 : static_cast<int>(frame.tile_splats[frame.tile_start[tile] + frame.last[p] - 1]);
          ASSERT_EQ(last, reference.last_splat[p]) << what << " at " << column << ", " << row;
          silhouette += column == frame.width - 1 && reference.transmittance.at<float>(row, column) < 0.9f;
        }
      }
      EXPECT_GT(reference.ended, 20) << what << ": the scene has pixels no more light passes";
      EXPECT_GT(silhouette, 2) << what << ": a disc crosses the picture's edge";
    }
  }
  splat_tiles::SetIsa(was);
}

TEST(SplatGradients, EveryInstructionSetGivesTheSameGradients) {
  // The AVX builds contract to FMA and add per lane in another order: the same to float rounding.
  Problem problem;
  const GaussianSplats splats = OverlappingSaturatedAndCutSplats();
  const splat_tiles::Isa was = splat_tiles::ActiveIsa();
  ASSERT_TRUE(splat_tiles::SetIsa(splat_tiles::Isa::kPortable));
  const SplatGradients portable = problem.Gradients(splats);
  for (const splat_tiles::Isa isa : RunnableIsas()) {
    ASSERT_TRUE(splat_tiles::SetIsa(isa));
    const SplatGradients g = problem.Gradients(splats);
    for (size_t i = 0; i < splats.size(); ++i) {
      const std::string what = std::string(splat_tiles::IsaName(isa)) + " splat " + std::to_string(i);
      EXPECT_LE((g.position[i] - portable.position[i]).norm(), 1e-4f * portable.position[i].norm() + 1e-5f) << what;
      EXPECT_LE((g.rotation[i] - portable.rotation[i]).norm(), 1e-4f * portable.rotation[i].norm() + 1e-5f) << what;
      EXPECT_LE((g.log_scale[i] - portable.log_scale[i]).norm(), 1e-4f * portable.log_scale[i].norm() + 1e-5f) << what;
      EXPECT_NEAR(g.opacity_logit[i], portable.opacity_logit[i], 1e-4f * std::abs(portable.opacity_logit[i]) + 1e-5f) << what;
    }
    for (size_t k = 0; k < g.sh.size(); ++k) EXPECT_NEAR(g.sh[k], portable.sh[k], 1e-4f * std::abs(portable.sh[k]) + 1e-5f);
  }
  splat_tiles::SetIsa(was);
}

// The gradients are the same bits whatever the threads: each tile's sums are kept per entry of its
// list and added per splat in the lists' order, not into per-thread buffers in the order the
// threads happen to take the tiles (a fit must give the same file run after run).
TEST(SplatGradients, TheSameBitsOnOneThreadAndOnMany) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> unit(-1, 1);
  GaussianSplats splats;
  splats.sh_degree = 1;
  for (int i = 0; i < 400; ++i) {
    splats.Add({0.8f * unit(rng), 0.6f * unit(rng), 2.5f + unit(rng)}, RotationWithNormal(Eigen::Vector3f(unit(rng), unit(rng), -2.0f).normalized()),
               {std::log(0.05f + 0.03f * unit(rng)), std::log(0.05f + 0.03f * unit(rng))}, 0.6f, {0.5f + 0.4f * unit(rng), 0.5f, 0.5f});
  }
  const SplatCamera camera = TestCamera(160, 120, 120);
  cv::Mat d_image(camera.height, camera.width, CV_32FC3);
  cv::randu(d_image, -1.0, 1.0);
  const auto gradients = [&](int threads) {
    tbb::task_arena arena(threads);
    SplatGradients g;
    arena.execute([&] {
      SplatFrame frame;
      RenderSplats(splats, camera, SplatRasterOptions(), &frame);
      g.Reset(splats);
      for (int pass = 0; pass < 2; ++pass) BackwardSplats(splats, camera, frame, d_image, &g);  // scratch reused
    });
    return g;
  };
  const SplatGradients one = gradients(1), many = gradients(8);
  ASSERT_EQ(one.sh.size(), many.sh.size());
  EXPECT_EQ(std::memcmp(one.sh.data(), many.sh.data(), one.sh.size() * sizeof(float)), 0);
  EXPECT_EQ(std::memcmp(one.opacity_logit.data(), many.opacity_logit.data(), one.opacity_logit.size() * sizeof(float)), 0);
  EXPECT_EQ(std::memcmp(one.screen.data(), many.screen.data(), one.screen.size() * sizeof(float)), 0);
  for (size_t i = 0; i < splats.size(); ++i) {
    ASSERT_EQ(one.position[i], many.position[i]) << i;
    ASSERT_EQ(one.rotation[i], many.rotation[i]) << i;
    ASSERT_EQ(one.log_scale[i], many.log_scale[i]) << i;
  }
  double norm = 0;
  for (const float v : one.opacity_logit) norm += std::abs(v);
  EXPECT_GT(norm, 0.0) << "the splats are drawn and get gradients";
}

TEST(SplatRaster, TilesAreFrontToBackAndSplatsBehindTheCameraAreIgnored) {
  GaussianSplats splats = TestSplats(1);
  splats.Add({0.0f, 0.0f, -2.0f}, RotationWithNormal({0, 0, 1}), {0.0f, 0.0f}, 0.9f, {1, 1, 1});  // behind
  SplatCamera camera = TestCamera();
  // A second view from the side: every tile's list is still ordered by that view's depth.
  for (const Eigen::Vector3f eye : {Eigen::Vector3f(0, 0, 0), Eigen::Vector3f(1.5f, 0.2f, 0.5f)}) {
    const Eigen::Vector3f forward = (Eigen::Vector3f(0, 0, 3) - eye).normalized();
    const Eigen::Vector3f right = forward.cross(Eigen::Vector3f(0, -1, 0)).normalized();
    const Eigen::Vector3f down = forward.cross(right);
    camera.rotation.row(0) = right;
    camera.rotation.row(1) = down;
    camera.rotation.row(2) = forward;
    camera.translation = -camera.rotation * eye;
    SplatFrame frame;
    RenderSplats(splats, camera, SplatRasterOptions(), &frame);
    EXPECT_FALSE(frame.visible[5]) << "a splat behind the camera is not drawn";
    for (int t = 0; t + 1 < static_cast<int>(frame.tile_start.size()); ++t) {
      for (uint32_t j = frame.tile_start[t] + 1; j < frame.tile_start[t + 1]; ++j) {
        EXPECT_LE(frame.view_depth[frame.tile_splats[j - 1]], frame.view_depth[frame.tile_splats[j]]);
        EXPECT_NE(frame.tile_splats[j], 5u);
      }
    }
    EXPECT_GT(frame.drawn, 0u);
  }
}

// The footprint box is the projected cut-off circle's (a conic's) box: every pixel a disc reaches
// (in front of its plane's horizon, within the cut-off) lies in its box, and over discs turned
// every way the boxes are much smaller than the extent square's projected corners give.
TEST(SplatRaster, TheFootprintBoxHoldsEveryPixelTheDiscReachesAndLittleMore) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> unit(-1, 1);
  GaussianSplats splats;
  for (int i = 0; i < 300; ++i) {
    const Eigen::Vector3f normal(unit(rng), unit(rng), unit(rng));
    if (normal.norm() < 0.1f) continue;
    splats.Add({0.8f * unit(rng), 0.6f * unit(rng), 2.5f + unit(rng)}, RotationWithNormal(normal.normalized()),
               {std::log(0.02f + 0.04f * (1 + unit(rng))), std::log(0.02f + 0.04f * (1 + unit(rng)))}, 0.8f, {1, 1, 1});
  }
  const SplatCamera camera = TestCamera(160, 120, 120);
  const SplatRasterOptions options;
  SplatFrame frame;
  RenderSplats(splats, camera, options, &frame);
  const double cutoff = SplatCutoffSquared(options);
  double box_area = 0, corner_area = 0;
  int reached = 0;
  for (size_t i = 0; i < splats.size(); ++i) {
    if (!frame.visible[i]) continue;
    const Eigen::Matrix3d inverse = frame.m[i].cast<double>().inverse();
    const Eigen::Vector4i& b = frame.box[i];
    for (int row = 0; row < camera.height; ++row) {
      for (int column = 0; column < camera.width; ++column) {
        const Eigen::Vector3d w = inverse * Eigen::Vector3d(column + 0.5, row + 0.5, 1.0);
        if (!(w.z() > 0)) continue;
        const double u = w.x() / w.z(), v = w.y() / w.z();
        if (u * u + v * v >= cutoff) continue;
        ++reached;
        ASSERT_TRUE(column >= b[0] && column <= b[2] && row >= b[1] && row <= b[3])
            << "splat " << i << " reaches pixel " << column << ", " << row << " outside its box";
      }
    }
    float x0 = 1e30f, y0 = 1e30f, x1 = -1e30f, y1 = -1e30f;  // the square's projected corners
    for (const float a : {-options.extent_sigmas, options.extent_sigmas}) {
      for (const float c : {-options.extent_sigmas, options.extent_sigmas}) {
        const Eigen::Vector3f p = frame.m[i] * Eigen::Vector3f(a, c, 1.0f);
        x0 = std::min(x0, p.x() / p.z()), x1 = std::max(x1, p.x() / p.z());
        y0 = std::min(y0, p.y() / p.z()), y1 = std::max(y1, p.y() / p.z());
      }
    }
    const auto clamp_x = [&](float x) { return std::clamp(x, 0.0f, static_cast<float>(camera.width)); };
    const auto clamp_y = [&](float y) { return std::clamp(y, 0.0f, static_cast<float>(camera.height)); };
    corner_area += (clamp_x(x1) - clamp_x(x0) + 1) * (clamp_y(y1) - clamp_y(y0) + 1);
    box_area += (b[2] - b[0] + 1.0) * (b[3] - b[1] + 1.0);
  }
  EXPECT_GT(reached, 10000) << "the discs reach pixels";
  EXPECT_LT(box_area, 0.85 * corner_area) << "boxes " << box_area << " px, corners' boxes " << corner_area << " px";
}

TEST(SplatRaster, AnOpaqueDiscCoversItsPixelsAtItsDepth) {
  GaussianSplats splats;
  splats.Add({0, 0, 2}, RotationWithNormal({0, 0, -1}), {std::log(0.2f), std::log(0.2f)}, 0.99f, {1.0f, 0.5f, 0.25f});
  SplatFrame frame;
  SplatRasterOptions options;
  options.background = Eigen::Vector3f(0, 0, 1);
  RenderSplats(splats, TestCamera(), options, &frame);
  const cv::Vec3f centre = frame.image.at<cv::Vec3f>(20, 24);
  EXPECT_NEAR(centre[0], 0.99f * 1.0f, 0.01f);
  EXPECT_NEAR(centre[2], 0.99f * 0.25f + 0.01f, 0.01f);
  EXPECT_NEAR(frame.depth.at<float>(20, 24), 2.0f, 1e-4f);
  EXPECT_NEAR(frame.transmittance.at<float>(0, 0), 1.0f, 1e-6f) << "a corner beyond 3 sigma";
}

TEST(GaussianSplatsPly, RoundTripAndATrainersLayout) {
  const fs::path dir = fs::temp_directory_path() / ("ibmr_splats_ply_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  GaussianSplats splats = TestSplats(3);
  splats.rotation[0] = splats.rotation[0].normalized();
  WriteGaussianSplatsPly((dir / "a.ply").string(), splats, "test");
  const GaussianSplats back = ReadGaussianSplatsPly((dir / "a.ply").string());
  ASSERT_EQ(back.size(), splats.size());
  EXPECT_EQ(back.sh_degree, 3);
  for (size_t i = 0; i < splats.size(); ++i) {
    EXPECT_EQ(back.position[i], splats.position[i]);
    EXPECT_LT((back.rotation[i] - splats.rotation[i].normalized()).norm(), 1e-6f);
    EXPECT_EQ(back.log_scale[i], splats.log_scale[i]);
    EXPECT_EQ(back.opacity_logit[i], splats.opacity_logit[i]);
    for (int k = 0; k < splats.ShCount() * 3; ++k) EXPECT_EQ(back.Sh(i)[k], splats.Sh(i)[k]);
  }
  const std::string header = ReadFile((dir / "a.ply").string()).substr(0, 2000);
  for (const char* property : {"property float f_dc_0", "property float f_rest_44", "property float opacity",
                               "property float scale_2", "property float rot_3", "property float nx"}) {
    EXPECT_NE(header.find(property), std::string::npos) << property;
  }
  // A file as a trainer writes it: its properties in its own order, plus ones this reader ignores.
  std::string trainer = "ply\nformat binary_little_endian 1.0\nelement vertex 1\n";
  const std::vector<std::string> names = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                                          "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "extra"};
  for (const std::string& name : names) trainer += "property float " + name + "\n";
  trainer += "end_header\n";
  const float values[18] = {1, 2, 3, 0, 0, 1, 0.5f, -0.5f, 0.25f, 2.0f, -1, -2, -3, 1, 0, 0, 0, 9};
  trainer.append(reinterpret_cast<const char*>(values), sizeof(values));
  WriteFileAtomic((dir / "trainer.ply").string(), trainer);
  const GaussianSplats read = ReadGaussianSplatsPly((dir / "trainer.ply").string());
  ASSERT_EQ(read.size(), 1u);
  EXPECT_EQ(read.sh_degree, 0);
  EXPECT_EQ(read.position[0], Eigen::Vector3f(1, 2, 3));
  EXPECT_EQ(read.log_scale[0], Eigen::Vector2f(-1, -2));
  EXPECT_EQ(read.opacity_logit[0], 2.0f);
  EXPECT_EQ(read.Sh(0)[1], -0.5f);
  // Missing properties and truncation name the file and what is wrong.
  WriteFileAtomic((dir / "bad.ply").string(), "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n");
  try {
    ReadGaussianSplatsPly((dir / "bad.ply").string());
    ADD_FAILURE() << "read a file without splat properties";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("bad.ply"), std::string::npos) << e.what();
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace ibmr
