// Tests of the carve stage: options, the octree file round trip, the synthetic object ring with
// exact masks at level 7 (no ground-truth-occupied voxel carved, IoU >= 0.99 with the object's
// visual hull by brute force on the same grid; leaf_test box equals the brute-force projected-box
// test and contains it; hull mesh encloses the object), depth bounds against true
// depth, the held-out level choice through the adapter, and bad input (wrong-size mask, empty
// silhouette, a camera that does not see the volume).
#include "stages/carve/carve.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/ply_io.h"
#include "pipeline/core/stage_api.h"
#include "stages/synth/synth.h"

namespace fs = std::filesystem;

namespace ibmr {
void RegisterStage_carve(StageRegistry* registry);

namespace {

// A small object ring rendered once for all tests: scene, exact masks and depth maps. 960x720, so
// that a level-7 cell spans about four pixels: the masks resolve the grid. (At 240x180 a cell is
// about one pixel, and the half-pixel tolerance that keeps every object voxel against masks sampled
// at pixel centres is itself a shell of half a cell: IoU 0.962 with the centre-sample hull.)
struct Ring {
  SynthOptions options;
  SynthScene scene;
  std::vector<SynthView> rendered;
  std::vector<CarveView> views;
};

const Ring& TheRing() {
  static const Ring* ring = [] {
    auto* r = new Ring;
    r->options.views = 16;
    r->options.width = 960;
    r->options.height = 720;
    r->options.supersample = 1;
    r->options.subdivision = 4;
    r->options.sparse_points = 0;
    r->scene = BuildSynthScene(r->options);
    for (int i = 0; i < static_cast<int>(r->scene.views.size()); ++i) {
      r->rendered.push_back(RenderSynthView(r->scene, i, r->options));
      r->views.push_back(CarveView{r->scene.views[i].name, r->scene.camera, r->scene.views[i].cam_from_world,
                                   r->rendered.back().mask});
    }
    return r;
  }();
  return *ring;
}

// Inside test of a closed mesh on a dense grid (x fastest, n per side) by ray parity along +z: per
// (x, y) column, the crossings of the triangles with the column's line, sorted.
std::vector<uint8_t> InsideMesh(const TriangleMesh& mesh, const Eigen::Vector3d& origin, double cell, int n) {
  std::vector<std::vector<double>> crossings(static_cast<size_t>(n) * n);
  for (const Eigen::Vector3i& face : mesh.faces) {
    const Eigen::Vector3d a = mesh.vertices[face[0]].cast<double>(), b = mesh.vertices[face[1]].cast<double>(),
                          c = mesh.vertices[face[2]].cast<double>();
    const double x0 = std::min({a.x(), b.x(), c.x()}), x1 = std::max({a.x(), b.x(), c.x()});
    const double y0 = std::min({a.y(), b.y(), c.y()}), y1 = std::max({a.y(), b.y(), c.y()});
    const int i0 = std::max(0, static_cast<int>(std::ceil((x0 - origin.x()) / cell - 0.5)));
    const int i1 = std::min(n - 1, static_cast<int>(std::floor((x1 - origin.x()) / cell - 0.5)));
    const int j0 = std::max(0, static_cast<int>(std::ceil((y0 - origin.y()) / cell - 0.5)));
    const int j1 = std::min(n - 1, static_cast<int>(std::floor((y1 - origin.y()) / cell - 0.5)));
    const double det = (b.x() - a.x()) * (c.y() - a.y()) - (c.x() - a.x()) * (b.y() - a.y());
    if (std::abs(det) < 1e-18) continue;
    for (int j = j0; j <= j1; ++j) {
      for (int i = i0; i <= i1; ++i) {
        // Tiny offsets keep column lines off shared edges and vertices.
        const double px = origin.x() + (i + 0.5) * cell + 1.3e-7, py = origin.y() + (j + 0.5) * cell + 0.7e-7;
        const double s = ((px - a.x()) * (c.y() - a.y()) - (c.x() - a.x()) * (py - a.y())) / det;
        const double t = ((b.x() - a.x()) * (py - a.y()) - (px - a.x()) * (b.y() - a.y())) / det;
        if (s < 0 || t < 0 || s + t > 1) continue;
        crossings[static_cast<size_t>(j) * n + i].push_back(a.z() + s * (b.z() - a.z()) + t * (c.z() - a.z()));
      }
    }
  }
  std::vector<uint8_t> inside(static_cast<size_t>(n) * n * n, 0);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      auto& zs = crossings[static_cast<size_t>(j) * n + i];
      std::sort(zs.begin(), zs.end());
      for (size_t k = 0; k + 1 < zs.size(); k += 2) {
        for (int z = 0; z < n; ++z) {
          const double pz = origin.z() + (z + 0.5) * cell;
          if (pz > zs[k] && pz < zs[k + 1]) inside[(static_cast<size_t>(z) * n + j) * n + i] = 1;
        }
      }
    }
  }
  return inside;
}

// The textbook visual hull on the same grid: a voxel is kept when its centre projects inside every
// silhouette (out of an image: kept unless that view treats outside as empty).
std::vector<uint8_t> CentreSampleHull(const std::vector<CarveView>& views, const std::vector<bool>& outside_empty,
                                      const Eigen::Vector3d& origin, double cell, int n) {
  std::vector<uint8_t> hull(static_cast<size_t>(n) * n * n, 1);
  for (int z = 0; z < n; ++z) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d centre = origin + cell * Eigen::Vector3d(i + 0.5, j + 0.5, z + 0.5);
        uint8_t& keep = hull[(static_cast<size_t>(z) * n + j) * n + i];
        for (size_t v = 0; v < views.size() && keep; ++v) {
          const Eigen::Vector3d in_cam = views[v].cam_from_world * centre;
          const Eigen::Vector2d pixel = views[v].camera.ImgFromCam(in_cam);
          const int px = static_cast<int>(std::floor(pixel.x())), py = static_cast<int>(std::floor(pixel.y()));
          const bool inside_image = in_cam.z() > 0 && px >= 0 && py >= 0 && px < views[v].mask.cols && py < views[v].mask.rows;
          if (!inside_image) {
            keep = !outside_empty[v];
          } else if (views[v].mask.at<uint8_t>(py, px) == 0) {
            keep = 0;
          }
        }
      }
    }
  }
  return hull;
}

double GridIou(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b) {
  size_t both = 0, either = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    both += a[i] && b[i];
    either += a[i] || b[i];
  }
  return either ? static_cast<double>(both) / either : 1.0;
}

// Root cube around the scene's foreground bounds with a 10% margin.
void RingCube(const Ring& ring, Eigen::Vector3d* origin, double* size) {
  const Eigen::AlignedBox3d& box = ring.scene.foreground_bounds;
  *size = 1.2 * box.sizes().maxCoeff();
  *origin = box.center() - Eigen::Vector3d::Constant(0.5 * *size);
}

// The ring's views carved to `levels` with the default options in the ring's cube.
CarveResult CarveRing(int levels, Eigen::Vector3d* origin, double* size) {
  const Ring& ring = TheRing();
  RingCube(ring, origin, size);
  CarveOptions options;
  options.levels = levels;
  return CarveOctree(ring.views, *origin, *size, options);
}

TEST(CarveOptions, DefaultsAreValid) {
  std::string error;
  EXPECT_TRUE(CarveOptions().Check(&error)) << error;
}

TEST(CarveOptions, RejectsOutOfRange) {
  const std::vector<std::pair<std::string, std::function<void(CarveOptions*)>>> cases = {
      {"levels", [](CarveOptions* o) { o->levels = 0; }},
      {"levels", [](CarveOptions* o) { o->levels = 11; }},
      {"smooth_iterations", [](CarveOptions* o) { o->smooth_iterations = -1; }},
      {"smooth_lambda", [](CarveOptions* o) { o->smooth_lambda = 1.0; }},
      {"smooth_mu", [](CarveOptions* o) { o->smooth_mu = -0.4; }},
      {"max_displacement", [](CarveOptions* o) { o->max_displacement = 1.0; }},
      {"max_mesh_level", [](CarveOptions* o) { o->max_mesh_level = 10; }},
      {"mesh_dilation", [](CarveOptions* o) { o->mesh_dilation = 3; }},
      {"level_tolerance", [](CarveOptions* o) { o->level_tolerance = -0.1; }},
  };
  for (const auto& [key, mutate] : cases) {
    CarveOptions options;
    mutate(&options);
    std::string error;
    EXPECT_FALSE(options.Check(&error)) << key;
    EXPECT_EQ(error.rfind(key, 0), 0u) << error;
  }
}

TEST(CarveSynthetic, Level7ContainsTheObjectAndMatchesBruteForce) {
  const Ring& ring = TheRing();
  Eigen::Vector3d origin;
  double size;
  RingCube(ring, &origin, &size);
  CarveOptions options;
  options.levels = 7;
  const CarveResult result = CarveOctree(ring.views, origin, size, options);
  EXPECT_TRUE(result.views_not_seeing_volume.empty());
  const int n = 128;
  const double cell = size / n;
  const std::vector<uint8_t> hull = DenseHull(result.octree, 7);
  const std::vector<uint8_t> truth = InsideMesh(ring.scene.mesh, origin, cell, n);
  size_t truth_count = 0, carved_truth = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    truth_count += truth[i];
    carved_truth += truth[i] && !hull[i];
  }
  ASSERT_GT(truth_count, 50000u);
  EXPECT_EQ(carved_truth, 0u) << "ground-truth-occupied voxels carved";
  // The object's visual hull by brute force on the same grid (a voxel is kept when its centre
  // projects into every silhouette): the default leaf test decides the finest partial cells the
  // same way, and coarser full/empty nodes agree with it.
  const std::vector<uint8_t> centre_hull = CentreSampleHull(ring.views, result.outside_empty, origin, cell, n);
  const double iou = GridIou(hull, centre_hull);
  EXPECT_GE(iou, 0.99);
  EXPECT_EQ(result.stats[7].partial, 0u);
  EXPECT_GT(result.stats[7].leaves_kept_by_centre, 0u);
  EXPECT_GT(result.stats[7].leaves_dropped_by_centre, 0u);

  // leaf_test box: every partial leaf kept, a conservative hull equal to the brute-force per-voxel
  // projected-box test, containing the centre-sample hull and up to one cell fatter.
  CarveOptions box_options = options;
  box_options.leaf_test = LeafTest::kBox;
  const CarveResult box_result = CarveOctree(ring.views, origin, size, box_options);
  const std::vector<uint8_t> box_hull = DenseHull(box_result.octree, 7);
  const std::vector<uint8_t> brute = CarveBruteForce(ring.views, result.outside_empty, origin, size, 7);
  EXPECT_GE(GridIou(box_hull, brute), 0.9999);
  size_t centre_missing = 0, hull_missing = 0;
  for (size_t i = 0; i < hull.size(); ++i) {
    centre_missing += centre_hull[i] && !box_hull[i];
    hull_missing += hull[i] && !box_hull[i];
  }
  EXPECT_EQ(centre_missing, 0u) << "the conservative hull must contain the centre-sample hull";
  EXPECT_EQ(hull_missing, 0u) << "the conservative hull must contain the centre-test hull";
  const double box_centre_iou = GridIou(box_hull, centre_hull);
  EXPECT_LT(box_centre_iou, iou);
  std::cout << "[carve test] level 7: IoU vs centre-sample visual hull " << iou << " (leaf_test centre), "
            << box_centre_iou << " (leaf_test box, which equals the brute-force box test)" << std::endl;
  // Node counts grow like the surface (~4x per level), not the volume (8x).
  for (int level = 4; level <= 7; ++level) {
    const double ratio = static_cast<double>(result.stats[level].nodes) / result.stats[level - 1].nodes;
    EXPECT_LT(ratio, 6.0) << "level " << level;
    EXPECT_GT(ratio, 2.5) << "level " << level;
  }
  // Informational: volume IoU with the object itself (the visual hull cannot see the dents).
  std::cout << "[carve test] level 7: " << truth_count << " object voxels, 0 carved; IoU vs object " << GridIou(hull, truth) << std::endl;

  // The smoothed mesh still encloses every object voxel and the hull.
  HullMeshStats stats;
  const TriangleMesh mesh = HullMesh(result.octree, 7, options, &stats);
  ASSERT_FALSE(mesh.faces.empty());
  EXPECT_EQ(mesh.comments.front(), "ibmr conservative_hull 1");
  EXPECT_TRUE(mesh.Validate().empty()) << mesh.Validate();
  const std::vector<uint8_t> in_mesh = InsideMesh(mesh, origin, cell, n);
  size_t truth_in_mesh = 0, hull_count = 0, hull_in_mesh = 0;
  for (size_t i = 0; i < truth.size(); ++i) {
    truth_in_mesh += truth[i] && in_mesh[i];
    hull_count += hull[i];
    hull_in_mesh += hull[i] && in_mesh[i];
  }
  const double containment = static_cast<double>(truth_in_mesh) / truth_count;
  std::cout << "[carve test] mesh: " << mesh.faces.size() << " faces, encloses " << containment
            << " of object voxels, " << static_cast<double>(hull_in_mesh) / hull_count << " of hull voxels, "
            << stats.duplicated_vertices << " duplicated vertices" << std::endl;
  EXPECT_GE(containment, 0.9999);

  // Without the dilation the mesh hugs the hull: it no longer claims to be conservative, it holds
  // fewer voxels outside the hull, and it still holds nearly all of the hull.
  CarveOptions tight = options;
  tight.mesh_dilation = 0;
  const TriangleMesh tight_mesh = HullMesh(result.octree, 7, tight);
  EXPECT_EQ(tight_mesh.comments.front(), "ibmr conservative_hull 0");
  const std::vector<uint8_t> in_tight = InsideMesh(tight_mesh, origin, cell, n);
  size_t outside_hull = 0, tight_outside_hull = 0, tight_hull_in = 0;
  for (size_t i = 0; i < hull.size(); ++i) {
    outside_hull += !hull[i] && in_mesh[i];
    tight_outside_hull += !hull[i] && in_tight[i];
    tight_hull_in += hull[i] && in_tight[i];
  }
  EXPECT_LT(tight_outside_hull * 2, outside_hull) << "the undilated mesh should be much tighter";
  EXPECT_GE(static_cast<double>(tight_hull_in) / hull_count, 0.9);
}

TEST(CarveSynthetic, DepthBoundsEncloseTrueDepth) {
  const Ring& ring = TheRing();
  Eigen::Vector3d origin;
  double size;
  const CarveResult result = CarveRing(6, &origin, &size);
  const std::vector<HullCell> cells = HullCells(result.octree, 6);
  for (size_t i = 0; i < ring.views.size(); ++i) {
    double near_z, far_z;
    ASSERT_TRUE(HullDepthBounds(cells, ring.views[i].camera, ring.views[i].cam_from_world, &near_z, &far_z));
    const DepthMap& depth = ring.rendered[i].depth;
    float lo = 1e30f, hi = 0;
    for (int r = 0; r < depth.height; ++r) {
      for (int c = 0; c < depth.width; ++c) {
        const float z = depth.At(c, r);
        if (IsValidDepth(z)) {
          lo = std::min(lo, z);
          hi = std::max(hi, z);
        }
      }
    }
    EXPECT_LE(near_z, lo) << ring.views[i].name;
    EXPECT_GE(far_z, hi) << ring.views[i].name;
    // Not loose: the near bound is within two cells of the visible surface, the far one within the
    // object's extent (the back of the object is not in the depth map).
    EXPECT_GT(near_z, lo - 2 * std::sqrt(3.0) * size / 64) << ring.views[i].name;
    EXPECT_LT(far_z, lo + ring.scene.foreground_bounds.sizes().norm() + 2 * std::sqrt(3.0) * size / 64)
        << ring.views[i].name;
  }
}

// The silhouette of the surface cells is the hull's (every view of the ring, at two levels: one
// with coarse full nodes inside, one of the finest cells), from fewer cells; and no surface cell
// has all six face neighbours in the hull.
TEST(CarveSynthetic, SurfaceCellsDrawTheHullsSilhouette) {
  const Ring& ring = TheRing();
  Eigen::Vector3d origin;
  double size;
  const CarveResult result = CarveRing(6, &origin, &size);
  for (const int level : {4, 6}) {
    const std::vector<HullCell> all = HullCells(result.octree, level);
    const std::vector<HullCell> surface = SurfaceHullCells(result.octree, level);
    ASSERT_FALSE(surface.empty());
    EXPECT_LT(surface.size(), all.size()) << "level " << level;
    for (const CarveView& view : ring.views) {
      const cv::Mat expected = ProjectHull(all, view.camera, view.cam_from_world);
      const cv::Mat got = ProjectHullSurface(result.octree, level, surface, view.camera, view.cam_from_world);
      ASSERT_GT(cv::countNonZero(expected), 100) << view.name;
      EXPECT_EQ(cv::countNonZero(expected != got), 0) << view.name << " level " << level;
    }
    // A camera inside the carving cube, looking through the hull: cells behind it are not drawn,
    // and inner cells can show; ProjectHullSurface then draws every cell, as ProjectHull does.
    const CarveView& view = ring.views.front();
    Rigid3d inside = view.cam_from_world;
    inside.translation = view.cam_from_world.rotation * (-(origin + Eigen::Vector3d::Constant(0.5 * size)));
    const cv::Mat expected = ProjectHull(all, view.camera, inside);
    ASSERT_GT(cv::countNonZero(expected), 100);
    EXPECT_EQ(cv::countNonZero(expected != ProjectHullSurface(result.octree, level, surface, view.camera, inside)), 0)
        << "level " << level;
    // Surface cells touch the outside: at least one finest-level voxel beside a face is empty.
    const std::vector<uint8_t> dense = DenseHull(result.octree, level);
    const int n = 1 << level;
    const double voxel = size / n;
    for (const HullCell& cell : surface) {
      const Eigen::Vector3i lo = ((cell.min - origin) / voxel).array().round().cast<int>();
      const int span = static_cast<int>(std::lround(cell.size / voxel));
      bool open = false;
      for (int a = 0; a < span && !open; ++a) {
        for (int b = 0; b < span && !open; ++b) {
          const Eigen::Vector3i beside[6] = {{lo.x() - 1, lo.y() + a, lo.z() + b}, {lo.x() + span, lo.y() + a, lo.z() + b},
                                             {lo.x() + a, lo.y() - 1, lo.z() + b}, {lo.x() + a, lo.y() + span, lo.z() + b},
                                             {lo.x() + a, lo.y() + b, lo.z() - 1}, {lo.x() + a, lo.y() + b, lo.z() + span}};
          for (const Eigen::Vector3i& v : beside) {
            const bool inside = (v.array() >= 0).all() && (v.array() < n).all();
            open = open || !inside || !dense[(static_cast<size_t>(v.z()) * n + v.y()) * n + v.x()];
          }
        }
      }
      ASSERT_TRUE(open) << "an enclosed cell among the surface cells, level " << level;
    }
  }
}

TEST(Octree, FileRoundTripAndErrors) {
  Eigen::Vector3d origin;
  double size;
  const CarveResult result = CarveRing(4, &origin, &size);
  const std::string bytes = SerializeOctree(result.octree);
  const Octree back = DeserializeOctree(bytes);
  ASSERT_EQ(back.levels.size(), result.octree.levels.size());
  EXPECT_EQ(back.origin, result.octree.origin);
  EXPECT_EQ(back.size, result.octree.size);
  for (size_t l = 0; l < back.levels.size(); ++l) {
    ASSERT_EQ(back.levels[l].size(), result.octree.levels[l].size());
    for (size_t i = 0; i < back.levels[l].size(); ++i) {
      EXPECT_EQ(back.levels[l][i].x, result.octree.levels[l][i].x);
      EXPECT_EQ(back.levels[l][i].z, result.octree.levels[l][i].z);
      EXPECT_EQ(back.levels[l][i].state, result.octree.levels[l][i].state);
    }
  }
  EXPECT_THROW(DeserializeOctree(bytes.substr(0, bytes.size() - 1)), std::runtime_error);
  EXPECT_THROW(DeserializeOctree("NOTANOCTREE"), std::runtime_error);
}

TEST(CarveOctree, CameraThatDoesNotSeeTheVolumeIsListed) {
  const Ring& ring = TheRing();
  Eigen::Vector3d origin;
  double size;
  RingCube(ring, &origin, &size);
  std::vector<CarveView> views(ring.views.begin(), ring.views.begin() + 6);
  views[2].cam_from_world.translation += Eigen::Vector3d(0, 0, -100);  // the volume is behind it
  CarveOptions options;
  options.levels = 4;
  const CarveResult result = CarveOctree(views, origin, size, options);
  ASSERT_EQ(result.views_not_seeing_volume.size(), 1u);
  EXPECT_EQ(result.views_not_seeing_volume[0], views[2].name);
  EXPECT_FALSE(HullCells(result.octree, 4).empty());
  views[3].mask = cv::Mat::zeros(10, 10, CV_8UC1);
  try {
    CarveOctree(views, origin, size, options);
    FAIL() << "expected an error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(views[3].name), std::string::npos) << e.what();
  }
}

// A workspace of the ring: sparse/, masks/ for training views, heldout/masks/ for held-out ones.
std::string RingWorkspace(const std::string& tag, const std::set<std::string>& heldout) {
  const Ring& ring = TheRing();
  const fs::path root = fs::temp_directory_path() / ("ibmr_carve_" + tag + "_" + std::to_string(::getpid()));
  fs::remove_all(root);
  SparseModel model;
  model.cameras[1] = ring.scene.camera;
  model.cameras[1].camera_id = 1;
  for (size_t i = 0; i < ring.views.size(); ++i) {
    Image image = ring.scene.views[i];
    image.camera_id = 1;
    model.images[image.image_id] = image;
    const bool held = heldout.count(image.name) > 0;
    WriteImage((root / (held ? "heldout/masks" : "masks") / (image.name + ".png")).string(), ring.rendered[i].mask);
  }
  WriteSparseModelText((root / "sparse").string(), model);
  return root.string();
}

StageContext CarveContext(const Stage& stage, const std::string& root, NullProgress* progress) {
  StageContext context;
  context.workspace = Workspace(root);
  context.role = stage.Role();
  context.progress = progress;
  context.params.Set("levels", int64_t{6});
  context.params.Set("outside", std::string("auto"));
  context.params.Set("leaf_test", std::string("centre"));
  context.params.Set("volume", std::string("auto"));
  context.params.Set("bbox", std::vector<double>{});
  context.params.Set("volume_margin", 0.05);
  context.params.Set("exclude_views", std::vector<std::string>{});
  context.params.Set("smooth_iterations", int64_t{10});
  context.params.Set("smooth_lambda", 0.5);
  context.params.Set("smooth_mu", -0.53);
  context.params.Set("max_displacement", 0.5);
  context.params.Set("max_mesh_level", int64_t{8});
  context.params.Set("mesh_dilation", int64_t{1});
  context.params.Set("mesh_at_finest", false);
  context.params.Set("level_tolerance", 0.002);
  return context;
}

TEST(CarveStage, AdapterWritesHullAndChoosesALevelFromHeldOutViews) {
  StageRegistry registry;
  RegisterStage_carve(&registry);
  const Stage* stage = registry.Find("carve");
  ASSERT_NE(stage, nullptr);
  EXPECT_EQ(stage->Role(), HoldoutRole::kTrainingOnly);
  const Ring& ring = TheRing();
  const std::set<std::string> heldout = {ring.views[3].name, ring.views[11].name};
  const std::string root = RingWorkspace("adapter", heldout);
  NullProgress progress;
  StageContext context = CarveContext(*stage, root, &progress);
  context.heldout_images = heldout;
  ASSERT_FALSE(stage->CheckParams(context.params).has_value());
  stage->Run(context);  // volume from the frustums (no bbox given)
  for (const char* file : {"hull/octree.bin", "hull/hull.ply", "hull/levels.json", "hull/depth_bounds.json"}) {
    EXPECT_TRUE(fs::exists(root + "/" + file)) << file;
  }
  std::ifstream in(root + "/hull/levels.json");
  const nlohmann::json levels = nlohmann::json::parse(in);
  EXPECT_EQ(levels["finest_level"], 6);
  const int chosen = levels["chosen_level"];
  EXPECT_GE(chosen, 3);
  ASSERT_TRUE(levels["levels"][6].contains("heldout_iou_mean"));
  std::cout << "[carve test] adapter: " << context.metrics.dump() << std::endl;
  // Finer levels predict the held-out silhouettes better until the cells are about a pixel wide.
  EXPECT_GT(levels["levels"][6]["heldout_iou_mean"].get<double>(), levels["levels"][4]["heldout_iou_mean"].get<double>());
  EXPECT_GT(levels["levels"][6]["heldout_iou_mean"].get<double>(), 0.8);
  EXPECT_GT(context.metrics["training_iou_median_finest"].get<double>(), 0.8);
  EXPECT_EQ(levels["training_views"].size(), ring.views.size() - 2);  // held-out views not carved from
  std::ifstream bounds_in(root + "/hull/depth_bounds.json");
  const nlohmann::json bounds = nlohmann::json::parse(bounds_in);
  EXPECT_EQ(bounds.size(), ring.views.size() - 2);
  EXPECT_FALSE(bounds.contains(ring.views[3].name));
  const TriangleMesh mesh = ReadMeshPly(root + "/hull/hull.ply");
  EXPECT_GT(mesh.faces.size(), 100u);
  EXPECT_NE(std::find(mesh.comments.begin(), mesh.comments.end(), "ibmr conservative_hull 1"), mesh.comments.end());
  fs::remove_all(root);
}

TEST(CarveStage, BadMasksAreNamed) {
  StageRegistry registry;
  RegisterStage_carve(&registry);
  const Stage* stage = registry.Find("carve");
  const Ring& ring = TheRing();
  const std::string root = RingWorkspace("bad", {});
  NullProgress progress;
  // An empty silhouette: skipped with a warning, listed in the record.
  WriteImage(root + "/masks/" + ring.views[5].name + ".png", cv::Mat::zeros(ring.options.height, ring.options.width, CV_8UC1));
  StageContext context = CarveContext(*stage, root, &progress);
  context.params.Set("levels", int64_t{4});
  stage->Run(context);
  ASSERT_EQ(context.metrics["skipped_empty_silhouettes"].size(), 1u);
  EXPECT_EQ(context.metrics["skipped_empty_silhouettes"][0], ring.views[5].name);
  // A wrong-size mask: an error naming the view and the sizes.
  WriteImage(root + "/masks/" + ring.views[7].name + ".png", cv::Mat::zeros(90, 120, CV_8UC1));
  StageContext again = CarveContext(*stage, root, &progress);
  try {
    stage->Run(again);
    FAIL() << "expected an error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(ring.views[7].name), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("120x90"), std::string::npos) << e.what();
  }
  // Every silhouette empty: a clear error, not an empty hull reported as success.
  for (const CarveView& view : ring.views) {
    WriteImage(root + "/masks/" + view.name + ".png", cv::Mat::zeros(ring.options.height, ring.options.width, CV_8UC1));
  }
  StageContext empty = CarveContext(*stage, root, &progress);
  EXPECT_THROW(stage->Run(empty), InputError);
  fs::remove_all(root);
}

}  // namespace
}  // namespace ibmr
