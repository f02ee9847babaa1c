// `ibmr run FOLDER`: each layout recognised, its config written once (an edited one kept) and
// loadable as written, the workspace beside the folder, and a folder with nothing to run refused.
#include "pipeline/runner/folder_run.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"
#include "pipeline/runner/builtin_stages.h"
#include "pipeline/runner/config.h"

namespace fs = std::filesystem;

namespace ibmr {
namespace {

class FolderRun : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("ibmr_folder_run_" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    RegisterBuiltinStages(&registry_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path Folder(const std::string& name, const std::vector<std::string>& files) {
    const fs::path folder = dir_ / name;
    for (const std::string& file : files) {
      fs::create_directories((folder / file).parent_path());
      std::ofstream(folder / file) << "x";
    }
    return folder;
  }
  // The plan's config written and loaded as `ibmr run FOLDER` does.
  Config Load(const fs::path& folder, const FolderPlan& plan) {
    const std::string workspace = DefaultWorkspaceFor(folder.string());
    return LoadConfig(PrepareFolderRun(folder.string(), workspace, plan), registry_);
  }

  fs::path dir_;
  StageRegistry registry_;
};

TEST_F(FolderRun, EachLayoutRunsItsChain) {
  const fs::path blender = Folder("lego", {"transforms_train.json", "transforms_test.json", "train/r_0.png"});
  FolderPlan plan = PlanForFolder(blender.string());
  EXPECT_EQ(plan.layout, "blender");
  Config config = Load(blender, plan);
  EXPECT_EQ(config.workspace, (dir_ / "lego.ibmr").string());
  EXPECT_EQ(config.inputs.at("images"), blender.string());
  EXPECT_EQ(config.holdout.split, "test");

  const fs::path llff = Folder("fern", {"poses_bounds.npy", "images_4/a.png"});
  EXPECT_EQ(PlanForFolder(llff.string()).layout, "llff");
  EXPECT_NE(Load(llff, PlanForFolder(llff.string())).FindStage("volume"), nullptr);

  const fs::path photos = Folder("garden", {"IMG_1.JPG", "IMG_2.jpg", "notes.txt"});
  plan = PlanForFolder((photos / "").string());  // a trailing slash as shells complete it
  EXPECT_EQ(plan.layout, "photos");
  EXPECT_EQ(plan.description, "a folder of 2 photos without poses");
  EXPECT_EQ(DefaultWorkspaceFor((photos / "").string()), (dir_ / "garden.ibmr").string());
  EXPECT_NE(Load(photos, plan).FindStage("sfm"), nullptr);

  // A capture that brings its cameras: the photo chain without sfm (undistort works on import's model).
  const fs::path posed = Folder("fountain", {"gt_dense_cameras/0000.png.camera", "images/0000.png"});
  plan = PlanForFolder(posed.string());
  EXPECT_EQ(plan.layout, "posed");
  config = Load(posed, plan);
  EXPECT_EQ(config.FindStage("sfm"), nullptr);
  EXPECT_NE(config.FindStage("undistort"), nullptr);
  EXPECT_EQ(config.FindStage("import")->params.String("format"), "auto");
  EXPECT_NE(config.FindStage("splat_fit"), nullptr);
}

TEST_F(FolderRun, AnEditedConfigIsKept) {
  const fs::path photos = Folder("garden", {"a.png"});
  const FolderPlan plan = PlanForFolder(photos.string());
  const std::string config = PrepareFolderRun(photos.string(), (dir_ / "ws").string(), plan);
  EXPECT_EQ(config, (dir_ / "ws/config.yaml").string());
  WriteFileAtomic(config, "# mine\n" + ReadFile(config));
  PrepareFolderRun(photos.string(), (dir_ / "ws").string(), plan);
  EXPECT_EQ(ReadFile(config).rfind("# mine\n", 0), 0u);
}

TEST_F(FolderRun, NothingToRunIsRefusedNamingTheFolder) {
  const fs::path empty = Folder("empty", {"readme.txt"});
  try {
    PlanForFolder(empty.string());
    FAIL() << "a folder without photos was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(empty.string() + ": no photos"), std::string::npos) << e.what();
  }
  EXPECT_THROW(PlanForFolder((dir_ / "absent").string()), InputError);
}

}  // namespace
}  // namespace ibmr
