// Runs one external command (COLMAP, sbatch, squeue) with its output piped line by line to a
// callback and a log file, measuring its wall time and peak memory (wait4 rusage of the child).
#pragma once

#include <functional>
#include <string>
#include <vector>

namespace ibmr {

struct ProcessResult {
  int exit_code = -1;        // -1 when it could not start or was killed by a signal
  double wall_seconds = 0;
  double cpu_seconds = 0;     // the child's user + system time
  double peak_memory_mb = 0;  // the child's maximum resident set size
  std::string last_lines;     // the last lines of output (for error messages)
};

// Full path of `program` found on PATH (or `program` itself when it holds a '/' and exists);
// empty when not found.
std::string FindExecutable(const std::string& program);

// Runs args[0] (found on PATH) with args in this process's environment plus `extra_env`
// ("NAME=value", replacing a variable of that name), appends stdout+stderr to `log_path` (none
// when empty) and calls `on_line` per output line.
ProcessResult RunProcess(const std::vector<std::string>& args, const std::string& log_path,
                         const std::function<void(const std::string& line)>& on_line,
                         const std::vector<std::string>& extra_env = {});

}  // namespace ibmr
