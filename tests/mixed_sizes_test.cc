// Photos of different sizes in one folder work: import gives each photo a camera of its own size,
// and sfm, seeing two sizes, has COLMAP use one camera per photo (a single shared camera would make
// COLMAP skip the photos of the other size). Real data: five Sceaux castle photos, every other one
// downscaled by a further 2/3; skipped where COLMAP or the photos are absent. The capture's kind
// from sfm's poses is checked here too, where COLMAP has already run.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/json_file.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

TEST(MixedSizes, PhotosOfTwoSizesAreAllRegistered) {
  const fs::path castle = fs::path(IBMR_SOURCE_DIR) / "../shared/datasets/openmvg_sceaux_castle";
  if (ibmr_e2e::RunCommand("command -v colmap").exit_code != 0) GTEST_SKIP() << "colmap is not installed; skipped";
  if (!fs::exists(castle / "100_7100.JPG")) GTEST_SKIP() << castle << " is absent; real-data test skipped";
  const fs::path root = fs::temp_directory_path() / ("ibmr_mixed_sizes_" + std::to_string(::getpid()));
  fs::remove_all(root);
  fs::create_directories(root / "photos");
  for (int i = 0; i < 5; ++i) {
    const cv::Mat photo = cv::imread((castle / ("100_710" + std::to_string(i) + ".JPG")).string());
    ASSERT_FALSE(photo.empty());
    const double scale = i % 2 ? 0.25 * 2 / 3 : 0.25;  // 708x532 and 472x355
    cv::Mat small;
    cv::resize(photo, small, cv::Size(), scale, scale, cv::INTER_AREA);
    cv::imwrite((root / "photos" / ("p" + std::to_string(i) + ".jpg")).string(), small);
  }
  std::ofstream(root / "c.yaml") << "workspace: ws\ninputs:\n  images: photos\nstages:\n"
                                    "  - import: {format: folder}\n"
                                    "  - sfm: {known_intrinsics: false, max_image_size: 708, max_attempts: 2}\n";
  const auto run = ibmr_e2e::RunCommand(std::string(IBMR_BINARY) + " run '" + (root / "c.yaml").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("photos of 2 sizes"), std::string::npos) << run.output;
  // The capture's shape from sfm's poses (issue 66): a walk along the castle's front, neither
  // forward-facing (its baselines are long against the near depth) nor round an object.
  const nlohmann::json capture = ibmr::ReadJsonOr((root / "ws/capture.json").string(), nullptr);
  EXPECT_EQ(capture["kind"], "general") << capture.dump();
  EXPECT_EQ(capture["model"], "sfm/sparse") << capture.dump();
  EXPECT_NE(run.output.find("capture: general ("), std::string::npos) << run.output;
  const ibmr::SparseModel model = ibmr::ReadSparseModelText((root / "ws/sfm/sparse").string());
  EXPECT_EQ(model.images.size(), 5u) << run.output;
  for (const auto& [id, image] : model.images) {
    const ibmr::Camera& camera = model.CameraOf(image);
    EXPECT_EQ(camera.width, image.name == "p1.jpg" || image.name == "p3.jpg" ? 472 : 708) << image.name;
  }
  fs::remove_all(root);
}

}  // namespace
