// Tiny stages for runner tests: `produce` writes a.txt from an external file and an integer
// parameter; `consume` copies a.txt to b.txt (both count their runs); `per_view` writes one file
// per view of eight in ForEachView, each view said to need 100 MB, and counts the views in flight.
#pragma once

#include <spdlog/spdlog.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <chrono>
#include <thread>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/per_view.h"
#include "pipeline/core/stage_api.h"

namespace ibmr {
namespace testing_stages {

inline std::atomic<int> produce_runs{0};
inline std::atomic<int> consume_runs{0};
// `produce` declares one parameter more, "added" (default 0), as a stage does that gains one in a
// later version of the code.
inline std::atomic<bool> produce_gains_a_parameter{false};

class Produce : public Stage {
 public:
  std::string Name() const override { return "produce"; }
  std::string Summary() const override { return "test: writes a.txt"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override {
    std::vector<ParamSpec> specs = {{"value", ParamType::kInt, "1", "any integer >= 0"},
                                    {"source", ParamType::kPath, "source.txt", "external input"},
                                    {"threads", ParamType::kInt, "1", "resource knob", {}, false},
                                    {"fail", ParamType::kBool, "false", "throw halfway"},
                                    {"scale", ParamType::kDouble, "1", "any finite number"},
                                    {"warn", ParamType::kBool, "false", "log two warnings"}};
    if (produce_gains_a_parameter) specs.push_back({"added", ParamType::kInt, "0", "a parameter added later"});
    return specs;
  }
  std::optional<ParamError> CheckParams(const Params& params) const override {
    if (params.Int("value") < 0) return ParamError{"value", "must be >= 0, got " + std::to_string(params.Int("value"))};
    return std::nullopt;
  }
  std::vector<std::string> Inputs(const StageContext& c) const override { return {c.params.String("source")}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"a.txt"}; }
  void Run(StageContext& c) const override {
    ++produce_runs;
    if (c.params.Bool("fail")) throw std::runtime_error("produce: asked to fail");
    if (c.params.Bool("warn")) {
      spdlog::warn("[produce] the source is thin");
      spdlog::warn("[produce] the source is thin again");
    }
    WriteFileAtomic(c.workspace.Path("a.txt"), ReadFile(c.params.String("source")) + std::to_string(c.params.Int("value")));
    c.metrics["bytes"] = 1;
  }
};

class Consume : public Stage {
 public:
  std::string Name() const override { return "consume"; }
  std::string Summary() const override { return "test: copies a.txt to b.txt"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kTrainingOnly; }
  std::vector<ParamSpec> Parameters() const override {
    return {{"suffix", ParamType::kString, "x", "appended"}, {"output", ParamType::kString, "b.txt", "file written"},
            {"fail", ParamType::kBool, "false", "throw"}};
  }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext&) const override { return {"a.txt"}; }
  std::vector<std::string> Outputs(const StageContext& c) const override { return {c.params.String("output")}; }
  void Run(StageContext& c) const override {
    ++consume_runs;
    if (c.params.Bool("fail")) throw std::runtime_error("consume: a.txt is too thin");
    WriteFileAtomic(c.workspace.Path(c.params.String("output")), ReadFile(c.workspace.Path("a.txt")) + c.params.String("suffix"));
  }
};

inline std::atomic<int> views_in_flight{0};
inline std::atomic<int> most_views_in_flight{0};
inline std::atomic<int> per_view_model_mb{0};  // memory PerView holds (touched) through its loop

class PerView : public Stage {
 public:
  std::string Name() const override { return "per_view"; }
  std::string Summary() const override { return "test: one file per view"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override { return {}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext&) const override { return {}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"views"}; }
  double ViewMemoryMb(const StageContext&) const override { return 100; }
  void Run(StageContext& c) const override {
    std::filesystem::create_directories(c.workspace.Path("views"));
    const std::vector<char> model(static_cast<size_t>(per_view_model_mb) << 20, 1);  // like a loaded model
    ForEachView(c, "per_view", {"v0", "v1", "v2", "v3", "v4", "v5", "v6", "v7"}, [&](const std::string& view) {
      const int now = ++views_in_flight;
      for (int seen = most_views_in_flight; now > seen && !most_views_in_flight.compare_exchange_weak(seen, now);) {
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      WriteFileAtomic(c.workspace.Path("views/" + view), view + (model.empty() ? "" : std::string(1, model.back())));
      --views_in_flight;
      return nlohmann::json();
    });
  }
};

inline std::atomic<int> list_folder_runs{0};

// Reads a folder (as import reads the photo folder): writes the names of its top-level files.
class ListFolder : public Stage {
 public:
  std::string Name() const override { return "list_folder"; }
  std::string Summary() const override { return "test: lists a folder into listing.txt"; }
  std::string Version() const override { return "1"; }
  HoldoutRole Role() const override { return HoldoutRole::kAllViews; }
  std::vector<ParamSpec> Parameters() const override { return {{"folder", ParamType::kPath, ".", "folder read"}}; }
  std::optional<ParamError> CheckParams(const Params&) const override { return std::nullopt; }
  std::vector<std::string> Inputs(const StageContext& c) const override { return {c.params.String("folder")}; }
  std::vector<std::string> Outputs(const StageContext&) const override { return {"listing.txt"}; }
  void Run(StageContext& c) const override {
    ++list_folder_runs;
    std::string listing;
    for (const auto& entry : std::filesystem::directory_iterator(c.params.String("folder"))) {
      if (entry.is_regular_file()) listing += entry.path().filename().string() + "\n";
    }
    WriteFileAtomic(c.workspace.Path("listing.txt"), listing);
  }
};

inline void Register(StageRegistry* registry) {
  registry->Add(std::make_unique<Produce>());
  registry->Add(std::make_unique<Consume>());
  registry->Add(std::make_unique<PerView>());
  registry->Add(std::make_unique<ListFolder>());
}

}  // namespace testing_stages
}  // namespace ibmr
