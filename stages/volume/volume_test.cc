// The volume stage's algorithm (volume.h) and the core volume (plane_volume.h): options, ray order,
// the compositing's gradient against finite differences, monotone descent, recovery of a known
// stack of textured planes, files.
#include "stages/volume/volume.h"

#include <gtest/gtest.h>

#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <random>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

// Looks along +z from `centre`.
Rigid3d Forward(const Eigen::Vector3d& centre) { return Rigid3d(Eigen::Matrix3d::Identity(), -centre); }

// Smooth random texture in [0.1, 0.9].
float Texture(int x, int y, int k, int c) {
  return 0.5f + 0.2f * std::sin(0.45f * x + 1.3f * k + c) * std::cos(0.37f * y - 0.7f * c) +
         0.2f * std::sin(0.21f * (x + y) + 2.0f * k + 0.5f * c);
}

// The truth: 3 planes (depths 2, 3, 5) at 64 x 48: a textured disc on the nearest, a textured
// vertical band on the middle one, a textured opaque background.
PlaneVolume TrueStack(int width = 64, int height = 48) {
  PlaneVolume truth;
  truth.camera = Camera::Pinhole(width, height, 0.9 * width, 0.9 * width, 0.5 * width, 0.5 * height);
  truth.cam_from_world = Forward(Eigen::Vector3d::Zero());
  truth.depths = {2.0, 3.0, 5.0};
  truth.Allocate();
  for (int k = 0; k < 3; ++k) {
    float* plane = truth.Plane(k);
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        float* cell = plane + (static_cast<size_t>(y) * width + x) * 4;
        for (int c = 0; c < 3; ++c) cell[c] = Texture(x, y, k, c);
        const double dx = x - 0.4 * width, dy = y - 0.5 * height;
        cell[3] = k == 2 ? 1.f : k == 0 ? (dx * dx + dy * dy < 0.04 * width * width ? 1.f : 0.f)
                                        : (x > 0.6 * width && x < 0.75 * width ? 1.f : 0.f);
      }
    }
  }
  return truth;
}

// Views on a grid in front of the stack, rendered from it.
std::vector<VolumeView> ViewsOf(const PlaneVolume& truth, const std::vector<Eigen::Vector3d>& centres) {
  std::vector<VolumeView> views;
  for (size_t i = 0; i < centres.size(); ++i) {
    VolumeView view;
    view.name = "view_" + std::to_string(i);
    view.camera = truth.camera;
    view.cam_from_world = Forward(centres[i]);
    cv::Mat colour, coverage;
    CompositePlaneVolume(truth, view.camera, view.cam_from_world, &colour, &coverage);
    colour.convertTo(view.image, CV_8UC3, 255.0);
    views.push_back(view);
  }
  return views;
}

std::vector<Eigen::Vector3d> Grid(int columns, int rows, double spacing) {
  std::vector<Eigen::Vector3d> centres;
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < columns; ++c) {
      centres.emplace_back((c - 0.5 * (columns - 1)) * spacing, (r - 0.5 * (rows - 1)) * spacing, 0.0);
    }
  }
  return centres;
}

double Psnr(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat fa, fb;
  a.convertTo(fa, CV_64F);
  b.convertTo(fb, CV_64F);
  const double mse = cv::norm(fa, fb, cv::NORM_L2SQR) / (static_cast<double>(a.total()) * a.channels());
  return 10 * std::log10(255.0 * 255.0 / std::max(mse, 1e-12));
}

TEST(VolumeOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(VolumeOptions().Check(&error)) << error;
}

TEST(VolumeOptions, EachInvalidRangeIsNamed) {
  const std::vector<std::pair<std::string, std::function<void(VolumeOptions*)>>> cases = {
      {"num_planes", [](VolumeOptions* o) { o->num_planes = 1; }},
      {"resolution", [](VolumeOptions* o) { o->resolution = 0; }},
      {"max_widen", [](VolumeOptions* o) { o->max_widen = 0.5; }},
      {"window_radius", [](VolumeOptions* o) { o->window_radius = -1; }},
      {"vote_temperature", [](VolumeOptions* o) { o->vote_temperature = -1; }},
      {"visibility_rounds", [](VolumeOptions* o) { o->visibility_rounds = 9; }},
      {"levels", [](VolumeOptions* o) { o->levels = 0; }},
      {"iterations", [](VolumeOptions* o) { o->iterations = -1; }},
      {"min_iterations", [](VolumeOptions* o) { o->min_iterations = -1; }},
      {"learning_rate", [](VolumeOptions* o) { o->learning_rate = 0; }},
      {"views_per_step", [](VolumeOptions* o) { o->views_per_step = -1; }},
      {"robust_epsilon", [](VolumeOptions* o) { o->robust_epsilon = 0; }},
      {"smoothness", [](VolumeOptions* o) { o->smoothness = -1; }},
      {"opacity_prior", [](VolumeOptions* o) { o->opacity_prior = -0.1; }},
      {"max_memory_mb", [](VolumeOptions* o) { o->max_memory_mb = 0; }},
  };
  for (const auto& [key, spoil] : cases) {
    VolumeOptions options;
    spoil(&options);
    std::string error;
    EXPECT_FALSE(options.Check(&error)) << key;
    EXPECT_EQ(error.rfind(key, 0), 0u) << error;
  }
}

// Whatever the desired camera's pose, the samples of a ray are the planes ahead of it, ordered by
// their distance along the ray (front to back), and each sample lies on its plane.
TEST(VolumeRays, PlanesAheadFrontToBackForAnyCamera) {
  PlaneVolume volume = TrueStack(32, 24);
  volume.depths = PlaneDepths(1.0, 8.0, 9);
  volume.Allocate();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(-1, 1);
  std::vector<RaySample> samples(volume.Planes());
  const Eigen::Matrix3d k_inv = volume.camera.K().inverse();
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::Vector3d centre(3 * uniform(rng), 3 * uniform(rng), 6 * uniform(rng) + 2);  // some between planes
    const Eigen::Quaterniond q = Eigen::Quaterniond(1 + uniform(rng), uniform(rng), uniform(rng), uniform(rng)).normalized();
    const Rigid3d cam_from_world(q, -(q * centre));
    const Camera camera = Camera::Pinhole(40, 30, 30, 30, 20, 15);
    const VolumeRays rays(volume, camera, cam_from_world);
    const double u = 40 * (0.5 + 0.5 * uniform(rng)), v = 30 * (0.5 + 0.5 * uniform(rng));
    const int n = rays.Samples(u, v, samples.data());
    const Eigen::Vector3d direction = cam_from_world.Inverse().rotation * (camera.K().inverse() * Eigen::Vector3d(u, v, 1));
    double previous = 0;
    for (int i = 0; i < n; ++i) {
      const RaySample& s = samples[i];
      const double z = volume.depths[s.plane];
      // The sample's world point: on plane z in the volume's frame, at the sample's pixel.
      const Eigen::Vector3d in_volume = z * (k_inv * Eigen::Vector3d(s.x + 0.5, s.y + 0.5, 1.0));
      const Eigen::Vector3d world = volume.cam_from_world.Inverse() * in_volume;
      const double along = (world - centre).dot(direction) / direction.squaredNorm();
      EXPECT_GT(along, 0) << "trial " << trial << ": plane " << s.plane << " is behind the camera";
      EXPECT_LT(((centre + along * direction) - world).norm(), 1e-6 * (1 + world.norm())) << "not on the ray";
      EXPECT_GT(along, previous) << "trial " << trial << ": not front to back";
      previous = along;
    }
    int ahead = 0;  // every plane ahead is listed
    for (int k = 0; k < volume.Planes(); ++k) {
      const Eigen::Vector3d o = volume.cam_from_world * centre;
      const Eigen::Vector3d d = volume.cam_from_world.rotation * direction;
      if (d.z() != 0 && (volume.depths[k] - o.z()) / d.z() > 0) ++ahead;
    }
    EXPECT_EQ(n, ahead);
  }
}

// The over operator: two opaque planes, the nearer one hides the farther from the front; from
// behind the volume, looking back, the farther one is in front.
TEST(VolumeComposite, NearestOpaquePlaneWins) {
  PlaneVolume volume = TrueStack(16, 12);
  volume.depths = {2.0, 4.0};
  volume.Allocate();
  for (size_t i = 0; i < volume.PlaneFloats(); i += 4) {
    volume.Plane(0)[i + 2] = 1.f, volume.Plane(0)[i + 3] = 1.f;  // red, near
    volume.Plane(1)[i + 0] = 1.f, volume.Plane(1)[i + 3] = 1.f;  // blue, far
  }
  cv::Mat colour, coverage;
  CompositePlaneVolume(volume, volume.camera, volume.cam_from_world, &colour, &coverage);
  EXPECT_NEAR(colour.at<cv::Vec3f>(6, 8)[2], 1.f, 1e-6);
  EXPECT_NEAR(colour.at<cv::Vec3f>(6, 8)[0], 0.f, 1e-6);
  EXPECT_EQ(coverage.at<uint8_t>(6, 8), 255);
  // From z = 10 looking back (rotated 180 degrees about y): blue first.
  const Eigen::Matrix3d back = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Rigid3d behind(back, -(back * Eigen::Vector3d(0, 0, 10)));
  const Camera narrow = Camera::Pinhole(16, 12, 40, 40, 8, 6);
  CompositePlaneVolume(volume, narrow, behind, &colour, &coverage);
  EXPECT_NEAR(colour.at<cv::Vec3f>(6, 8)[0], 1.f, 1e-6);
  EXPECT_NEAR(colour.at<cv::Vec3f>(6, 8)[2], 0.f, 1e-6);
}

// Drawing plane by plane (warps) and ray by ray agree for a camera in front of the planes (but
// within a pixel of the volume's border); a camera among the planes is refused by the warps.
TEST(VolumeComposite, WarpsAgreeWithRaysInFront) {
  PlaneVolume volume = TrueStack(64, 48);
  for (float& v : volume.cells) v = std::round(v * 255.f) / 255.f;  // as the 8-bit planes hold them
  const std::vector<cv::Mat> planes = PlaneImages(volume);
  const Camera camera = Camera::Pinhole(80, 60, 70, 70, 40, 30);
  const Rigid3d cam_from_world = Forward(Eigen::Vector3d(0.15, -0.1, -0.3));
  cv::Mat by_warps, warps_coverage, by_rays, rays_coverage;
  ASSERT_TRUE(CompositePlaneVolumeByWarps(volume, planes, camera, cam_from_world, &by_warps, &warps_coverage));
  CompositePlaneVolume(volume, camera, cam_from_world, &by_rays, &rays_coverage);
  const VolumeRays rays(volume, camera, cam_from_world);
  int compared = 0;
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      RaySample far;
      ASSERT_TRUE(rays.SampleOn(x + 0.5, y + 0.5, volume.Planes() - 1, &far));
      const bool interior = far.x > 1 && far.y > 1 && far.x < volume.Width() - 2 && far.y < volume.Height() - 2;
      if (!interior) continue;
      ++compared;
      EXPECT_EQ(warps_coverage.at<uint8_t>(y, x), rays_coverage.at<uint8_t>(y, x));
      for (int ch = 0; ch < 3; ++ch) {
        ASSERT_NEAR(by_warps.at<cv::Vec3f>(y, x)[ch], by_rays.at<cv::Vec3f>(y, x)[ch], 0.02) << x << "," << y;
      }
    }
  }
  EXPECT_GT(compared, camera.width * camera.height / 2);
  EXPECT_FALSE(CompositePlaneVolumeByWarps(volume, planes, camera, Forward(Eigen::Vector3d(0, 0, 2.5)), &by_warps,
                                           &warps_coverage))
      << "a camera between the planes";
}

// The objective's central difference in cell value i (step 2e-3), the cell left as it was.
double CentralDifference(PlaneVolume* volume, const std::vector<LevelView>& level, const VolumeOptions& options,
                         size_t i) {
  const float h = 2e-3f, saved = volume->cells[i];
  volume->cells[i] = saved + h;
  const double plus = VolumeObjective(*volume, level, options, nullptr);
  volume->cells[i] = saved - h;
  const double minus = VolumeObjective(*volume, level, options, nullptr);
  volume->cells[i] = saved;
  return (plus - minus) / (2.0 * h);
}

// The analytic gradient of the objective (data term, smoothness, prior) against central finite
// differences, for colour and opacity cells of every plane but the pinned far one.
TEST(VolumeObjective, GradientMatchesFiniteDifferences) {
  const PlaneVolume truth = TrueStack(24, 18);
  const std::vector<VolumeView> views = ViewsOf(truth, Grid(2, 1, 0.2));
  const std::vector<LevelView> level = LevelViews(views, 1.0);
  PlaneVolume volume = truth;
  volume.depths = PlaneDepths(1.8, 6.0, 4);
  volume.Allocate();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> uniform(0.2f, 0.8f);
  for (float& v : volume.cells) v = uniform(rng);
  VolumeOptions options;
  options.robust_epsilon = 0.2;  // smooth enough for differences of 1e-3
  options.smoothness = 0.05;
  options.opacity_prior = 0.02;
  std::vector<float> gradient;
  VolumeObjective(volume, level, options, &gradient);
  std::uniform_int_distribution<int> pick_x(0, volume.Width() - 1), pick_y(0, volume.Height() - 1);
  int checked = 0;
  for (int k = 0; k < volume.Planes() - 1; ++k) {
    for (int channel = 0; channel < 4; ++channel) {
      for (int trial = 0; trial < 3; ++trial) {
        const size_t i = k * volume.PlaneFloats() + (static_cast<size_t>(pick_y(rng)) * volume.Width() + pick_x(rng)) * 4 + channel;
        const double numeric = CentralDifference(&volume, level, options, i);
        EXPECT_NEAR(gradient[i], numeric, 2e-3 * std::abs(numeric) + 2e-6)
            << "plane " << k << " channel " << channel << " cell " << i;
        ++checked;
      }
    }
  }
  EXPECT_EQ(checked, 3 * 4 * 3);
}

// The same check for a camera behind the volume looking back through it: its rays meet the planes
// farthest first, so the data term walks them in the other order.
TEST(VolumeObjective, GradientMatchesFiniteDifferencesLookingBack) {
  PlaneVolume volume = TrueStack(24, 18);
  volume.depths = PlaneDepths(1.8, 6.0, 4);
  volume.Allocate();
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uniform(0.2f, 0.8f);
  for (float& v : volume.cells) v = uniform(rng);
  const Eigen::Matrix3d back = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix();
  LevelView view;
  view.camera = Camera::Pinhole(20, 16, 60, 60, 10, 8);
  view.cam_from_world = Rigid3d(back, -(back * Eigen::Vector3d(0.1, 0, 12)));
  view.image.create(16, 20, CV_32FC3);
  cv::randu(view.image, 0.0, 1.0);
  const VolumeRays rays(volume, view.camera, view.cam_from_world);
  ASSERT_FALSE(rays.RayAt(10, 8).forward) << "the camera should look toward smaller z";
  const std::vector<LevelView> level = {view};
  VolumeOptions options;
  options.robust_epsilon = 0.2;
  options.smoothness = 0;
  options.opacity_prior = 0;
  std::vector<float> gradient;
  VolumeObjective(volume, level, options, &gradient);
  // Cells the view sees: those with a non-zero gradient, 3 per plane and channel at random.
  int checked = 0;
  for (int k = 0; k < volume.Planes() - 1; ++k) {
    for (int channel = 0; channel < 4; ++channel) {
      std::vector<size_t> seen;
      for (size_t c = 0; c < volume.PlaneFloats() / 4; ++c) {
        const size_t i = k * volume.PlaneFloats() + c * 4 + channel;
        if (std::abs(gradient[i]) > 1e-5f) seen.push_back(i);
      }
      ASSERT_FALSE(seen.empty()) << "plane " << k << " is not seen from behind";
      std::shuffle(seen.begin(), seen.end(), rng);
      for (size_t t = 0; t < std::min<size_t>(3, seen.size()); ++t) {
        const size_t i = seen[t];
        const double numeric = CentralDifference(&volume, level, options, i);
        EXPECT_NEAR(gradient[i], numeric, 2e-3 * std::abs(numeric) + 2e-6) << "plane " << k << " channel " << channel;
        ++checked;
      }
    }
  }
  EXPECT_EQ(checked, 3 * 4 * 3);
}

// The objective and its gradient are the same bits on one thread and on several, with the view's
// rows split into several bands (64 planes of a 256-pixel-wide view: 32 rows per band).
TEST(VolumeObjective, TheSameBitsOnOneThreadAndOnMany) {
  PlaneVolume volume = TrueStack(200, 150);
  volume.depths = PlaneDepths(1.8, 6.0, 64);
  volume.Allocate();
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> uniform(0.f, 0.3f);
  for (float& v : volume.cells) v = uniform(rng);
  std::vector<LevelView> level(2);
  for (int i = 0; i < 2; ++i) {
    level[i].camera = Camera::Pinhole(256, 200, 230, 230, 128, 100);
    level[i].cam_from_world = Forward(Eigen::Vector3d(0.1 * i - 0.05, 0.03 * i, -0.2));
    level[i].image.create(200, 256, CV_32FC3);
    cv::randu(level[i].image, 0.0, 1.0);
  }
  const VolumeOptions options;
  std::vector<float> one, many;
  double objective_one = 0, objective_many = 0;
  {
    tbb::global_control control(tbb::global_control::max_allowed_parallelism, 1);
    objective_one = VolumeObjective(volume, level, options, &one);
  }
  {
    tbb::global_control control(tbb::global_control::max_allowed_parallelism, 8);
    objective_many = VolumeObjective(volume, level, options, &many);
  }
  EXPECT_EQ(objective_one, objective_many);
  ASSERT_EQ(one.size(), many.size());
  size_t differ = 0, nonzero = 0;
  for (size_t i = 0; i < one.size(); ++i) {
    differ += std::memcmp(&one[i], &many[i], sizeof(float)) != 0;
    nonzero += one[i] != 0.f;
  }
  EXPECT_EQ(differ, 0u);
  EXPECT_GT(nonzero, one.size() / 2);
}

// Plain gradient descent at a safe step never raises the objective.
TEST(VolumeRefine, GradientDescentNeverIncreasesTheError) {
  const PlaneVolume truth = TrueStack(32, 24);
  const std::vector<VolumeView> views = ViewsOf(truth, Grid(3, 2, 0.15));
  const std::vector<LevelView> level = LevelViews(views, 1.0);
  PlaneVolume volume = truth;
  volume.depths = PlaneDepths(1.8, 6.0, 6);
  volume.Allocate();
  VolumeOptions options;
  options.optimizer = VolumeOptimizer::kGradientDescent;
  options.views_per_step = 0;  // the whole objective at every step
  options.learning_rate = 0.5;
  InitializeVolume(level, options, &volume);
  std::vector<VolumeCurvePoint> curve;
  RefineVolume(level, options, 0, 30, &volume, &curve);
  ASSERT_EQ(curve.size(), 31u);
  for (size_t i = 1; i < curve.size(); ++i) EXPECT_LE(curve[i].objective, curve[i - 1].objective + 1e-12) << i;
  EXPECT_LT(curve.back().objective, curve.front().objective);
}

// A stack of textured fronto-parallel planes seen by a 4 x 3 grid: the fitted volume puts the
// opacity on the true planes and reproduces a held-out view.
TEST(FitPlaneVolume, RecoversAStackOfTexturedPlanes) {
  const PlaneVolume truth = TrueStack();
  std::vector<Eigen::Vector3d> centres = Grid(4, 3, 0.12);
  const std::vector<VolumeView> views = ViewsOf(truth, centres);
  const std::vector<VolumeView> heldout = ViewsOf(truth, {Eigen::Vector3d(0.05, 0.03, 0.0)});
  VolumeOptions options;
  options.num_planes = 10;  // 1/z from 1/2 to 1/5 in 9 steps of 1/30: planes 0, 5 and 9 are the true ones
  options.levels = 2;
  options.iterations = 150;
  const VirtualCamera virtual_camera = ChooseVirtualCamera(views, -1, 2.0, 5.0, options);
  const VolumeResult result = FitPlaneVolume(views, virtual_camera, options);
  const PlaneVolume& volume = result.volume;
  // Composite weight a_k T_k along the central rays, summed per plane, where the truth's disc is.
  std::vector<double> mass(volume.Planes(), 0.0);
  std::vector<RaySample> samples(volume.Planes());
  const VolumeRays rays(volume, truth.camera, truth.cam_from_world);
  double disc_pixels = 0;
  for (int y = 0; y < truth.Height(); ++y) {
    for (int x = 0; x < truth.Width(); ++x) {
      if (truth.Plane(0)[(static_cast<size_t>(y) * truth.Width() + x) * 4 + 3] < 1.f) continue;
      const int n = rays.Samples(x + 0.5, y + 0.5, samples.data());
      float t = 1.f;
      for (int i = 0; i < n; ++i) {
        float cell[4];
        SampleCell(volume.Plane(samples[i].plane), Footprint(volume.Width(), volume.Height(), samples[i].x, samples[i].y), cell);
        mass[samples[i].plane] += cell[3] * t;
        t *= 1.f - cell[3];
      }
      ++disc_pixels;
    }
  }
  // The disc (z = 2) is plane 0.
  EXPECT_GT(mass[0] / disc_pixels, 0.8) << "the disc's opacity is not on its plane";
  cv::Mat colour, coverage, rendered;
  CompositePlaneVolume(volume, heldout[0].camera, heldout[0].cam_from_world, &colour, &coverage);
  colour.convertTo(rendered, CV_8UC3, 255.0);
  const double psnr = Psnr(rendered, heldout[0].image);
  RecordProperty("heldout_psnr", std::to_string(psnr));
  RecordProperty("disc_mass_on_plane_0", std::to_string(mass[0] / disc_pixels));
  EXPECT_GT(psnr, 30.0) << "held-out view";
  EXPECT_LT(result.final_data, result.initial_data);
}

TEST(PlaneVolumeFiles, RoundTripAndErrors) {
  const std::string folder = (std::filesystem::temp_directory_path() / "ibmr_volume_files").string();
  std::filesystem::remove_all(folder);
  const PlaneVolume truth = TrueStack(20, 10);
  WritePlaneVolume(folder, truth);
  const PlaneVolume back = ReadPlaneVolume(folder);
  ASSERT_EQ(back.Planes(), truth.Planes());
  EXPECT_EQ(back.depths, truth.depths);
  EXPECT_NEAR(back.camera.FocalX(), truth.camera.FocalX(), 1e-12);
  for (size_t i = 0; i < truth.cells.size(); ++i) ASSERT_NEAR(back.cells[i], truth.cells[i], 0.5 / 255 + 1e-6);
  std::filesystem::remove(folder + "/plane_001.png");
  EXPECT_THROW(ReadPlaneVolume(folder), InputError);
  WriteFileAtomic(folder + "/volume.json", "{\"format\": \"ibmr_plane_volume\", \"width\": 3}");
  try {
    ReadPlaneVolume(folder);
    FAIL() << "a volume.json without a camera was read";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("volume.json"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ReadPlaneVolume(folder + "/missing"), InputError);
  std::filesystem::remove_all(folder);
}

TEST(FitPlaneVolume, RefusesOneView) {
  const PlaneVolume truth = TrueStack(16, 12);
  const std::vector<VolumeView> views = ViewsOf(truth, {Eigen::Vector3d::Zero()});
  const VirtualCamera virtual_camera = ChooseVirtualCamera(views, -1, 2.0, 5.0, VolumeOptions());
  EXPECT_THROW(FitPlaneVolume(views, virtual_camera, VolumeOptions()), std::invalid_argument);
}

}  // namespace
}  // namespace ibmr
