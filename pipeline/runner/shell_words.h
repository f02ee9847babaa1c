// Quoting for command lines the runner writes for others to run (Slurm job scripts, Snakefiles):
// every word in single quotes, so spaces and shell characters in paths stay literal.
#pragma once

#include <string>
#include <vector>

namespace ibmr {

inline std::string ShellQuote(const std::string& word) {
  std::string quoted = "'";
  for (char c : word) quoted += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return quoted + "'";
}

inline std::string CommandLine(const std::vector<std::string>& words) {
  std::string line;
  for (const std::string& word : words) line += (line.empty() ? "" : " ") + ShellQuote(word);
  return line;
}

}  // namespace ibmr
