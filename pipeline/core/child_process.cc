// Child-process runner (see child_process.h).
#include "pipeline/core/child_process.h"

#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <fstream>

extern char** environ;

namespace ibmr {

std::string FindExecutable(const std::string& program) {
  namespace fs = std::filesystem;
  if (program.find('/') != std::string::npos) return fs::exists(program) ? program : "";
  const char* path = std::getenv("PATH");
  std::string dirs = path ? path : "/usr/bin:/bin";
  size_t start = 0;
  while (start <= dirs.size()) {
    const size_t end = dirs.find(':', start);
    const std::string dir = dirs.substr(start, end == std::string::npos ? std::string::npos : end - start);
    const fs::path candidate = fs::path(dir.empty() ? "." : dir) / program;
    if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return "";
}

ProcessResult RunProcess(const std::vector<std::string>& args, const std::string& log_path,
                         const std::function<void(const std::string& line)>& on_line,
                         const std::vector<std::string>& extra_env) {
  ProcessResult result;
  int pipe_fds[2];
  if (::pipe(pipe_fds) != 0) return result;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], 1);
  posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], 2);
  posix_spawn_file_actions_addclose(&actions, pipe_fds[0]);
  std::vector<std::string> env_strings;
  for (char** e = environ; *e; ++e) {
    const std::string variable(*e);
    bool replaced = false;
    for (const std::string& extra : extra_env) {
      const std::string name = extra.substr(0, extra.find('=') + 1);
      replaced |= variable.rfind(name, 0) == 0;
    }
    if (!replaced) env_strings.push_back(variable);
  }
  env_strings.insert(env_strings.end(), extra_env.begin(), extra_env.end());
  std::vector<char*> env, argv;
  for (std::string& s : env_strings) env.push_back(s.data());
  env.push_back(nullptr);
  std::vector<std::string> args_copy = args;
  for (std::string& s : args_copy) argv.push_back(s.data());
  argv.push_back(nullptr);
  const auto start = std::chrono::steady_clock::now();
  pid_t pid = 0;
  const int spawn_error = posix_spawnp(&pid, argv[0], &actions, nullptr, argv.data(), env.data());
  posix_spawn_file_actions_destroy(&actions);
  ::close(pipe_fds[1]);
  if (spawn_error != 0) {
    ::close(pipe_fds[0]);
    result.last_lines = "could not start " + args[0];
    return result;
  }
  std::ofstream log;
  if (!log_path.empty()) log.open(log_path, std::ios::app);
  std::deque<std::string> tail;
  FILE* stream = ::fdopen(pipe_fds[0], "r");
  char* buffer = nullptr;
  size_t capacity = 0;
  ssize_t length;
  while ((length = ::getline(&buffer, &capacity, stream)) >= 0) {
    std::string line(buffer, length);
    while (!line.empty() && (line.back() == '\n' || line.back() == '\r')) line.pop_back();
    if (log.is_open()) log << line << '\n';
    tail.push_back(line);
    if (tail.size() > 12) tail.pop_front();
    on_line(line);
  }
  std::free(buffer);
  std::fclose(stream);
  int status = 0;
  struct rusage usage {};
  ::wait4(pid, &status, 0, &usage);
  result.wall_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  result.cpu_seconds = static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
                       1e-6 * static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
  result.peak_memory_mb = usage.ru_maxrss / 1024.0;
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  for (const std::string& line : tail) result.last_lines += line + "\n";
  return result;
}

}  // namespace ibmr
