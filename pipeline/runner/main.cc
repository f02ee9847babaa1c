// The ibmr command line: run a config, list stages, show what is stale. Thin: parses
// arguments, sets up logging, and calls the runner.
#include <CLI/CLI.hpp>
#include <spdlog/sinks/basic_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "pipeline/core/capture_info.h"
#include "pipeline/core/capture_shape.h"
#include "pipeline/core/colmap_text_io.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/process_memory.h"
#include "pipeline/runner/builtin_stages.h"
#include "pipeline/runner/config.h"
#include "pipeline/runner/folder_run.h"
#include "pipeline/runner/runner.h"
#include "pipeline/runner/slurm_executor.h"
#include "pipeline/runner/snakemake_export.h"
#include "pipeline/runner/report.h"
#include "pipeline/runner/stage_listing.h"
#include "pipeline/runner/sweep.h"

namespace {

// Terminal and logs/ibmr.log in the workspace.
void SetUpLogging(const std::string& workspace) {
  auto console = std::make_shared<spdlog::sinks::stderr_color_sink_mt>();
  console->set_pattern("%^%L%$ %H:%M:%S %v");
  std::vector<spdlog::sink_ptr> sinks{console};
  std::string problem;
  if (!workspace.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(workspace + "/logs", ec);
    problem = ec ? ec.message() : "";
    if (!ec) {
      try {
        auto file = std::make_shared<spdlog::sinks::basic_file_sink_mt>(workspace + "/logs/ibmr.log");
        file->set_pattern("%Y-%m-%d %H:%M:%S.%e %l [pid %P] %v");
        sinks.push_back(file);
      } catch (const spdlog::spdlog_ex& e) {  // a read-only or full workspace: log to the terminal only
        problem = e.what();
      }
    }
  }
  auto logger = std::make_shared<spdlog::logger>("ibmr", sinks.begin(), sinks.end());
  logger->flush_on(spdlog::level::info);
  spdlog::set_default_logger(logger);
  if (!problem.empty()) {
    spdlog::warn("cannot write the log {}/logs/ibmr.log ({}); logging to the terminal only", workspace, problem);
  }
}

}  // namespace

int main(int argc, char** argv) {
  ibmr::ConfigureHeap(argv);  // first: it may start the program again (see process_memory.h)
  // stderr from the start: spdlog's own default logger writes to stdout, where a warning before
  // the workspace's log is set up corrupted `ibmr export snakemake CONFIG > Snakefile` and `status`.
  SetUpLogging("");
  CLI::App app{"ibmr: photographs to 3D models and image-based renderings, stage by stage"};
  app.require_subcommand(1);

  std::string config_path, workspace;
  std::vector<std::string> overrides;
  ibmr::RunOptions options;
  auto* run = app.add_subcommand("run", "Run the stale stages of a config (a finished config does no work)");
  run->add_option("config", config_path,
                  "YAML config, or a capture folder (photos, an LLFF or Blender-layout capture): the matching shipped "
                  "config runs in FOLDER.ibmr beside it and the report's path is printed")
      ->required()
      ->check(CLI::ExistingPath);
  run->add_option("--workspace", workspace, "Workspace folder (overrides the config's)");
  run->add_option("--only", options.only, "Run only this stage");
  run->add_option("--from", options.from, "Run from this stage on");
  run->add_option("--to", options.to, "Run up to this stage");
  run->add_flag("--force", options.force, "Run the selected stages even when up to date");
  run->add_option("--set", overrides, "Override a parameter: stage.key=value (repeatable)")->allow_extra_args(false);
  run->add_flag("--dry-run", options.dry_run, "List what would run and why; change nothing");
  std::vector<std::string> with_stages;
  run->add_option("--with", with_stages,
                  "Run these stages even where the capture's kind is one their model does not serve (capture.json; "
                  "comma-separated, or all)")
      ->delimiter(',');
  run->add_option("--jobs", options.jobs, "Worker threads (default: all cores)")->check(CLI::PositiveNumber);
  run->add_option("--memory-limit", options.memory_limit_mb,
                  "Memory of a per-view stage's views in flight together, MB (default: what is available when "
                  "the stage starts); fewer views run at once when theirs would exceed it")
      ->check(CLI::PositiveNumber);
  bool write_report = false;
  run->add_flag("--report", write_report, "Then write the workspace's report page and print its path");
  run->add_option("--views", options.views,
                  "With --only STAGE (a per-view stage): compute just these views, comma-separated (a shard); "
                  "a run without --views then merges")
      ->delimiter(',');
  std::string executor = "local";
  ibmr::SlurmOptions slurm;
  std::string sbatch_args;
  run->add_option("--executor", executor, "local (default) or slurm: per-view stages as job arrays, the others as "
                                          "jobs, on the cluster SLURM_CONF names")
      ->check(CLI::IsMember({"local", "slurm"}));
  run->add_option("--retries", slurm.retries, "slurm: resubmissions of what a killed or failed job left undone (default 1)");
  run->add_option("--sbatch-args", sbatch_args, "slurm: more sbatch options for every job, e.g. \"--partition=gpu\"");
  run->add_option("--mem-per-view", slurm.mem_per_view_mb,
                  "slurm: memory of one view's job, MB (default: the stage's estimate from image size and parameters)");

  ibmr::SnakemakeExportOptions export_options;
  std::string export_format;
  auto* export_cmd = app.add_subcommand("export", "Print a config as a workflow for another engine: "
                                                  "`ibmr export snakemake CONFIG > Snakefile`");
  export_cmd->add_option("format", export_format, "snakemake")->required()->check(CLI::IsMember({"snakemake"}));
  export_cmd->add_option("config", config_path, "YAML config")->required()->check(CLI::ExistingFile);
  export_cmd->add_option("--workspace", workspace, "Workspace folder (overrides the config's)");
  export_cmd->add_option("--set", overrides, "Override a parameter: stage.key=value (repeatable)")->allow_extra_args(false);
  export_cmd->add_option("--threads-per-view", export_options.threads_per_view, "Threads of a per-view job (default 1)")
      ->check(CLI::PositiveNumber);
  export_cmd->add_option("--mem-per-view", export_options.mem_per_view_mb,
                         "Memory of a per-view job, MB (default: the stage's estimate, `ibmr views --memory-mb`)")
      ->check(CLI::NonNegativeNumber);

  std::string views_stage;
  auto* views = app.add_subcommand("views", "Print a per-view stage's views, one per line (what --views takes)");
  views->add_option("config", config_path, "YAML config")->required()->check(CLI::ExistingFile);
  views->add_option("stage", views_stage, "A per-view stage of the config")->required();
  views->add_option("--workspace", workspace, "Workspace folder (overrides the config's)");
  views->add_option("--set", overrides, "Override a parameter: stage.key=value (repeatable)")->allow_extra_args(false);
  bool memory_mb = false;
  views->add_flag("--memory-mb", memory_mb, "Print instead the stage's estimate of one view's peak memory, MB "
                                            "(0: none yet; its inputs are not there)");

  auto* status = app.add_subcommand("status", "Show which stages are up to date and why the others are stale");
  status->add_option("config", config_path, "YAML config")->required()->check(CLI::ExistingFile);
  status->add_option("--workspace", workspace, "Workspace folder (overrides the config's)");
  status->add_option("--set", overrides, "Override a parameter: stage.key=value (repeatable)")->allow_extra_args(false);
  status->add_option("--with", with_stages, "As for run: stages to run whatever the capture's kind")->delimiter(',');

  std::string capture_path;
  auto* capture = app.add_subcommand("capture", "Print the shape of a capture (forward_facing, object or general) and "
                                                "the figures that decide it, from a workspace or a sparse model folder");
  capture->add_option("path", capture_path, "Workspace (its latest model: dense/sparse, sfm/sparse or sparse) or a "
                                            "folder with cameras.txt and images.txt")
      ->required()
      ->check(CLI::ExistingDirectory);

  auto* stages = app.add_subcommand("stages", "List every stage: inputs, outputs, parameters with defaults");

  ibmr::SweepOptions sweep_options;
  auto* sweep = app.add_subcommand("sweep", "Run a config's variants (parameter overrides) sharing upstream outputs; "
                                            "collect time, memory, model size and held-out scores into sweep.json");
  sweep->add_option("config", sweep_options.config_path, "YAML config")->required()->check(CLI::ExistingFile);
  sweep->add_option("--vary", sweep_options.vary, "stage.key=v1,v2,... (repeatable; the lists are crossed)");
  sweep->add_option("--variant", sweep_options.listed,
                    "\"stage.key=v stage.key=v\": one listed combination (repeatable)");
  sweep->add_option("--out", sweep_options.out, "Sweep folder (default: the config's workspace + .sweep)");
  sweep->add_option("--metric", sweep_options.metric, "Held-out mean charted against time (default photo_psnr: holes count as black)");
  sweep->add_option("--jobs", sweep_options.jobs, "Worker threads (default: all cores)")->check(CLI::PositiveNumber);

  ibmr::ReportOptions report_options;
  auto* report = app.add_subcommand("report", "Write report/index.html for a workspace or a sweep folder: charts "
                                              "(Chart.js, inlined), tables, held-out renders; opens from disk");
  report->add_option("path", report_options.path, "Workspace or sweep folder")->required()->check(CLI::ExistingDirectory);
  report->add_option("--out", report_options.out, "Page to write (default: PATH/report/index.html)");
  report->add_option("--max-faces", report_options.viewer.max_faces,
                     "report.max_faces: the 3D viewer decimates larger meshes to this many faces")->capture_default_str();
  report->add_option("--max-points", report_options.viewer.max_points,
                     "report.max_points: the 3D viewer shows at most this many fused points")->capture_default_str();

  ibmr::StageRegistry registry;
  ibmr::RegisterBuiltinStages(&registry);
  std::vector<std::pair<CLI::App*, const ibmr::StageCommand*>> commands;
  for (const ibmr::StageCommand& command : registry.Commands()) {
    CLI::App* sub = app.add_subcommand(command.name, command.help);
    sub->prefix_command();  // the stage parses its own arguments, --help included
    sub->set_help_flag();
    commands.emplace_back(sub, &command);
  }
  CLI11_PARSE(app, argc, argv);
  for (const auto& [sub, command] : commands) {
    if (!sub->parsed()) continue;
    SetUpLogging("");
    try {
      return command->main(sub->remaining());
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 1;
    }
  }

  if (capture->parsed()) {
    try {
      const std::string model_dir = ibmr::FindModelFolder(capture_path);
      const ibmr::SparseModel model = ibmr::ReadSparseModelText(model_dir);
      const ibmr::CaptureShape shape = ibmr::AnalyseCapture(model, ibmr::CaptureHasAlpha(ibmr::Workspace(capture_path)));
      std::cout << model_dir << ": " << shape.Describe() << "\n" << shape.ToJson().dump(2) << "\n";
      return 0;
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 1;
    }
  }
  if (stages->parsed()) {
    std::cout << ibmr::DescribeStages(registry);
    return 0;
  }
  if (report->parsed()) {
    SetUpLogging("");
    try {
      std::cout << ibmr::WriteReport(report_options) << "\n";
      return 0;
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 1;
    }
  }
  if (sweep->parsed()) {
    try {
      SetUpLogging(ibmr::SweepFolder(sweep_options, ibmr::LoadConfig(sweep_options.config_path, registry)));
      sweep_options.interactive = isatty(STDERR_FILENO);
      return ibmr::RunSweep(sweep_options, registry);
    } catch (const ibmr::ConfigError& e) {
      std::cerr << "error: " << e.what() << "\n";
      return 2;
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 1;
    }
  }

  if (run->parsed() && std::filesystem::is_directory(config_path)) {  // ibmr run FOLDER
    try {
      const ibmr::FolderPlan plan = ibmr::PlanForFolder(config_path);
      if (workspace.empty()) workspace = ibmr::DefaultWorkspaceFor(config_path);
      workspace = std::filesystem::absolute(workspace).lexically_normal().string();
      config_path = ibmr::PrepareFolderRun(config_path, workspace, plan, options.dry_run);
      write_report = true;
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 2;
    }
  }
  ibmr::Config config;
  try {
    config = ibmr::LoadConfig(config_path, registry);
    if (!workspace.empty()) {
      config.workspace = std::filesystem::absolute(workspace).lexically_normal().string();
      if (std::filesystem::path(config.workspace).relative_path().empty()) {  // as LoadConfig refuses it
        throw ibmr::ConfigError("--workspace " + workspace + " is the filesystem root: give a folder of its own");
      }
    }
    for (const std::string& assignment : overrides) ibmr::ApplyOverride(assignment, registry, &config);
    ibmr::ApplyWith(with_stages, &config);
  } catch (const ibmr::ConfigError& e) {
    std::cerr << "error: " << e.what() << "\n";
    return 2;
  }
  ibmr::Runner runner(config, registry);
  try {
    if (const std::string shared = runner.SharedOutputs(); !shared.empty()) {
      std::cerr << "error: " << shared << "\n";
      return 2;
    }
  } catch (const std::exception& e) {  // a config problem found with the workspace (holdout.images)
    spdlog::error("{}", e.what());
    return 2;
  }
  // What a job or a Snakemake rule passes to `ibmr run` to see this config as this process does.
  std::vector<std::string> run_args = {std::filesystem::absolute(config_path).lexically_normal().string(),
                                       "--workspace", config.workspace};
  for (const std::string& assignment : overrides) run_args.insert(run_args.end(), {"--set", assignment});
  for (const std::string& name : with_stages) run_args.insert(run_args.end(), {"--with", name});
  const std::string self = std::filesystem::read_symlink("/proc/self/exe").string();
  if (export_cmd->parsed()) {
    export_options.ibmr = self;
    export_options.run_args = run_args;
    try {
      std::cout << ibmr::SnakemakeFile(runner, export_options);
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 1;
    }
    return 0;
  }
  if (views->parsed()) {
    try {
      const ibmr::Stage* stage = registry.Find(views_stage);
      if (stage == nullptr || !stage->Shardable() || config.FindStage(views_stage) == nullptr) {
        spdlog::error("'{}' is not a per-view stage of {} ({})", views_stage, config_path,
                      runner.ShardableStagesText());
        return 2;
      }
      if (memory_mb) {
        std::cout << static_cast<long>(std::ceil(runner.ViewMemoryMb(views_stage))) << "\n";
        return 0;
      }
      for (const std::string& name : runner.ShardViews(views_stage)) std::cout << name << "\n";
      return 0;
    } catch (const std::exception& e) {
      spdlog::error("{}", e.what());
      return 1;
    }
  }
  // A wrong selection (--only with --from) is refused before the workspace gets its logs/.
  if (run->parsed() && options.views.empty()) {
    std::vector<size_t> selected;
    if (!runner.SelectStages(options, &selected)) return 2;
  }
  // Looking (status, --dry-run) leaves a workspace that is not there yet as it was: no logs/.
  if ((status->parsed() || options.dry_run) && !std::filesystem::exists(config.workspace)) {
    spdlog::info("workspace {} does not exist yet: every stage would run", config.workspace);
  } else {
    SetUpLogging(config.workspace);
  }
  try {
    if (status->parsed()) {
      for (const auto& s : runner.Status()) {
        std::cout << (s.skipped ? "  skip   " : s.up_to_date ? "  ok     " : "  stale  ") << s.name << ": " << s.reason;
        // A per-view stage part done (shards, or a run that was killed): how far it got.
        const size_t views = s.up_to_date ? 0 : runner.ShardViews(s.name).size();
        const size_t left = views > 0 ? runner.UnfinishedViews(s.name).size() : 0;
        if (views > 0 && left < views) std::cout << " (" << views - left << " of " << views << " views done)";
        std::cout << "\n";
      }
      return 0;
    }
    options.interactive = isatty(STDERR_FILENO);
    int code = 0;
    if (executor == "slurm") {
      slurm.ibmr = self;
      slurm.run_args = run_args;
      if (options.force) slurm.run_args.push_back("--force");
      std::istringstream words(sbatch_args);
      for (std::string word; words >> word;) slurm.sbatch_args.push_back(word);
      code = ibmr::RunOnSlurm(runner, options, slurm);
    } else {
      code = runner.Run(options);
    }
    if (code == 0 && write_report && !options.dry_run) {
      ibmr::ReportOptions page;
      page.path = config.workspace;
      try {
        std::cout << "report: " << ibmr::WriteReport(page) << "\n";
      } catch (const std::exception& e) {  // the run succeeded; only the page is missing
        spdlog::warn("the run is complete, but its report was not written: {}", e.what());
      }
    }
    return code;
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 1;
  }
}
