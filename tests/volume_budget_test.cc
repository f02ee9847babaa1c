// A memory budget the volume plans with (issue 66): a volume that would need more than
// volume.max_memory_mb lowers its widening and resolution until it fits, says what it chose and
// records it; with fit_memory false it refuses as before, naming the remedies.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "pipeline/core/json_file.h"
#include "tests/run_command.h"

namespace fs = std::filesystem;

namespace {

TEST(VolumeBudget, SizesItselfToTheBudget) {
  const fs::path dir = fs::temp_directory_path() / ("ibmr_volume_budget_" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  auto write = [&](const std::string& volume) {
    std::ofstream(dir / "c.yaml") << "workspace: ws\nstages:\n"
                                     "  - synth: {scene: forward_facing, views: 8, width: 96, height: 72, supersample: 1}\n"
                                     "  - volume: {num_planes: 8, levels: 1, iterations: 2, min_iterations: 1, resolution: 2, "
                                  << volume << "}\n";
  };
  const std::string ibmr = std::string(IBMR_BINARY) + " run " + (dir / "c.yaml").string();
  // The unconstrained size first, for its estimate.
  write("max_memory_mb: 100000");
  auto run = ibmr_e2e::RunCommand(ibmr);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  nlohmann::json volume = ibmr::ReadJsonOr((dir / "ws/records/volume.json").string(), nullptr)["metrics"]["volumes"][0];
  const double full_mb = volume["memory_estimate_mb"].get<double>();
  const int full_width = volume["width"].get<int>();
  // A budget of half of it: fitted smaller, within the budget, saying so.
  const double budget = full_mb / 2;
  write("max_memory_mb: " + std::to_string(budget));
  run = ibmr_e2e::RunCommand(ibmr);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("would need more than volume.max_memory_mb"), std::string::npos) << run.output;
  volume = ibmr::ReadJsonOr((dir / "ws/records/volume.json").string(), nullptr)["metrics"]["volumes"][0];
  EXPECT_LE(volume["memory_estimate_mb"].get<double>(), budget);
  EXPECT_LT(volume["width"].get<int>(), full_width);
  EXPECT_LT(volume["resolution"].get<double>() * volume["max_widen"].get<double>(), 2.0 * 1.5);  // as asked: 2, 1.5
  // Refused when asked not to size itself.
  write("max_memory_mb: " + std::to_string(budget) + ", fit_memory: false");
  run = ibmr_e2e::RunCommand(ibmr);
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("more than volume.max_memory_mb"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("or set volume.fit_memory: true"), std::string::npos) << run.output;
  fs::remove_all(dir);
}

}  // namespace
