// The splat rasterizer: analytic gradients of every parameter kind against central differences on
// a few overlapping discs (one seen nearly edge-on, where the screen-space floor decides, and
// discs at the silhouette over the background); the front-to-back order in every tile; splats
// behind the camera ignored; the PLY layout round trip and a file laid out as a 3D Gaussian
// splatting trainer writes it.
#include "pipeline/core/splat_rasterizer.h"

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <random>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

SplatCamera TestCamera() {
  SplatCamera camera;
  camera.width = 48;
  camera.height = 40;
  camera.fx = camera.fy = 50;
  camera.cx = 24;
  camera.cy = 20;
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
