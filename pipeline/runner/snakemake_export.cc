// Writes a config's Snakefile (see snakemake_export.h).
#include "pipeline/runner/snakemake_export.h"

#include <nlohmann/json.hpp>
#include <algorithm>
#include <filesystem>
#include <sstream>

#include "pipeline/core/errors.h"
#include "pipeline/runner/shell_words.h"

namespace ibmr {
namespace {

// A Python string literal (JSON's escapes are Python's). A path that is not UTF-8 has no such
// literal that names the same file: refuse it by name rather than write a Snakefile that misses it
// (or let dump() throw its opaque "incomplete UTF-8 string").
std::string Py(const std::string& text) {
  try {
    return nlohmann::json(text).dump();
  } catch (const nlohmann::json::type_error&) {
    throw InputError("'" + text + "' is not valid UTF-8, and a Snakefile cannot name it: rename it (or the folder) "
                     "in UTF-8, or run `ibmr run` instead");
  }
}

std::string PyList(const std::vector<std::string>& items) {
  std::string list = "[";
  for (size_t i = 0; i < items.size(); ++i) list += (i ? ", " : "") + Py(items[i]);
  return list + "]";
}

// Braces are Snakemake's placeholders in shell commands: literal ones are doubled.
std::string EscapeBraces(const std::string& text) {
  std::string escaped;
  for (char c : text) escaped += c == '{' ? "{{" : c == '}' ? "}}" : std::string(1, c);
  return escaped;
}

std::string Stamp(const std::string& stage) { return "records/snakemake/" + stage + ".stamp"; }

// A rule's name: stage names may be Python keywords (import), which Snakemake's rule names cannot.
std::string Rule(const std::string& stage) { return "ibmr_" + stage; }

// "a, b, c and 40 more" for the comments above a rule; a per-view stage may name its files only
// once its views are known.
std::string Listed(const std::vector<std::string>& paths, bool per_view) {
  std::string text;
  const size_t shown = std::min<size_t>(paths.size(), 6);
  for (size_t i = 0; i < shown; ++i) text += (i ? ", " : "") + paths[i];
  if (paths.size() > shown) text += " and " + std::to_string(paths.size() - shown) + " more";
  if (text.empty()) return per_view ? "files named per view (listed once sparse/ exists)" : "-";
  return text;
}

}  // namespace

std::string SnakemakeFile(const Runner& runner, const SnakemakeExportOptions& options) {
  const Config& config = runner.config();
  const std::string run = EscapeBraces(CommandLine({options.ibmr, "run"}) + " " + CommandLine(options.run_args));
  std::ostringstream out;
  out << "# Snakefile for " << config.path << ", written by `ibmr export snakemake`.\n"
      << "#   snakemake -s Snakefile --cores 2                 # on this machine\n"
      << "#   snakemake -s Snakefile --cores 2 --jobs 16 --cluster \"sbatch --parsable --cpus-per-task={threads} "
         "--mem={resources.mem_mb} --output=.snakemake/slurm-%j.out\" --cluster-cancel scancel   # on Slurm\n"
      << "#   (--slurm works too where Slurm keeps accounts: Snakemake 7 asks sacct and sacctmgr, which need slurmdbd)\n"
      << "# Each rule runs `ibmr run` for one stage, or for one view of a per-view stage (--views), on the workspace\n"
      << "# below; ibmr's cache decides what is stale, so a rule whose stage is up to date does no work. Snakemake's\n"
      << "# outputs are stamps under records/snakemake/, not the stages' files: Snakemake deletes a job's outputs\n"
      << "# before running it, and ibmr keeps them (the last good outputs of a failed run). Each rule's comment lists\n"
      << "# what the stage reads and writes. Rules before a per-view stage are checkpoints: its views are listed\n"
      << "# (`ibmr views`) once the files they come from exist.\n"
      << "import subprocess\n\n"
      << "IBMR = " << Py(options.ibmr) << "\n"
      << "RUN_ARGS = " << PyList(options.run_args) << "\n\n"
      << "workdir: " << Py(config.workspace) << "\n\n"
      << "def ibmr_views(stage, *flags):\n"
      << "    listed = subprocess.run([IBMR, \"views\", *RUN_ARGS, stage, *flags], check=True, capture_output=True, "
         "text=True)\n"
      << "    return [line for line in listed.stdout.splitlines() if line]\n\n"
      << "# One view's memory, MB: the stage's estimate from image size and parameters, a quarter more for\n"
      << "# what it does not count (2000 when it has none).\n"
      << "IBMR_VIEW_MEMORY = {}\n"
      << "def ibmr_view_memory(stage):\n"
      << "    if stage not in IBMR_VIEW_MEMORY:\n"
      << "        estimate = int(ibmr_views(stage, \"--memory-mb\")[0])\n"
      << "        if estimate <= 0:\n"
      << "            return 2000\n"
      << "        IBMR_VIEW_MEMORY[stage] = int(1.25 * estimate) + 1\n"
      << "    return IBMR_VIEW_MEMORY[stage]\n\n";

  std::vector<std::string> finals;
  for (const StageConfig& stage : config.stages) finals.push_back(Stamp(stage.name));
  out << "rule all:\n    input: " << PyList(finals) << "\n\n";

  for (size_t i = 0; i < config.stages.size(); ++i) {
    const std::string& name = config.stages[i].name;
    const bool per_view = runner.registry().Find(name)->Shardable();
    const std::vector<std::string> reads = runner.DeclaredInputs(i);
    // What Snakemake compares times with: the upstream stages' stamps, ibmr itself and the config
    // (a rebuilt ibmr or an edited config reruns every rule, and ibmr's cache then skips what is
    // current), and the files from outside the workspace the stage reads (a user's image folder).
    std::vector<std::string> upstream_stamps = {options.ibmr, std::filesystem::absolute(config.path).string()};
    std::vector<std::string> upstream_names;
    // The stages whose declared outputs this one reads, and the stage before it in the config:
    // some declarations name per-view files that are unknown until sparse/ exists (multi_depth's
    // .geometric.bin maps), so at export time the declarations alone can miss an edge; the
    // config's order is always a valid one.
    std::vector<size_t> upstream = runner.Upstream(i);
    if (i > 0 && std::find(upstream.begin(), upstream.end(), i - 1) == upstream.end()) upstream.push_back(i - 1);
    for (size_t j : upstream) {
      upstream_stamps.push_back(Stamp(config.stages[j].name));
      upstream_names.push_back(Rule(config.stages[j].name));
    }
    for (const std::string& input : reads) {
      if (std::filesystem::path(input).is_absolute() && std::filesystem::exists(input)) upstream_stamps.push_back(input);
    }
    out << "# " << name << (per_view ? " (per view)" : "") << "\n"
        << "#   reads:  " << Listed(reads, per_view) << "\n"
        << "#   writes: " << Listed(runner.DeclaredOutputs(i), per_view) << "\n";
    std::string view_input;
    if (per_view) {
      out << "rule " << Rule(name) << "_view:\n"
          << "    input: " << PyList(upstream_stamps) << "\n"
          << "    output: temp(touch(\"records/snakemake/" << name << "/{view}.stamp\"))\n"
          << "    threads: " << options.threads_per_view << "\n"
          << "    resources: mem_mb="
          << (options.mem_per_view_mb > 0 ? std::to_string(options.mem_per_view_mb)
                                          : "lambda wildcards: ibmr_view_memory(" + Py(name) + ")")
          << "\n"
          << "    shell: " << Py(run + " --only " + name + " --views {wildcards.view:q} --jobs {threads}") << "\n\n"
          << "def " << Rule(name) << "_views(wildcards):\n";
      for (const std::string& up : upstream_names) out << "    checkpoints." << up << ".get()\n";
      out << "    return expand(\"records/snakemake/" << name << "/{view}.stamp\", view=ibmr_views(" << Py(name)
          << "))\n\n";
      view_input = ", views=" + Rule(name) + "_views";
    }
    // Every stage rule is a checkpoint: cheap, and a later per-view stage may list views from it.
    out << "checkpoint " << Rule(name) << ":\n"
        << "    input: upstream=" << PyList(upstream_stamps) << view_input << "\n"
        << "    output: touch(" << Py(Stamp(name)) << ")\n"
        << "    threads: workflow.cores\n"
        << "    resources: mem_mb=" << options.mem_per_stage_mb << "\n"
        << "    shell: " << Py(run + " --only " + name + " --jobs {threads}") << "\n\n";
  }
  return out.str();
}

}  // namespace ibmr
