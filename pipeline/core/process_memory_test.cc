// Tests of ConfigureHeap's second start with huge pages (process_memory.h): this test program runs
// itself as a child (its own test HeapChild.Report), which calls ConfigureHeap the way ibmr's main
// does; the child reports whether a large block got transparent huge pages and what environment
// its own children would see.
#include "pipeline/core/process_memory.h"

#include <gtest/gtest.h>
#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

extern char** environ;

namespace ibmr {
namespace {

std::string ThpMode() {
  std::ifstream in("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string modes;
  std::getline(in, modes);
  const size_t open = modes.find('['), close = modes.find(']');
  return open == std::string::npos || close == std::string::npos ? "" : modes.substr(open + 1, close - open - 1);
}

// AnonHugePages (kB) of the mapping of /proc/self/smaps that holds `address`; -1 when not found.
long HugePagesKbAt(const void* address) {
  std::ifstream in("/proc/self/smaps");
  std::string line;
  bool inside = false;
  const auto at = reinterpret_cast<uintptr_t>(address);
  while (std::getline(in, line)) {
    unsigned long start = 0, end = 0;
    if (std::sscanf(line.c_str(), "%lx-%lx ", &start, &end) == 2 && line.find(':') > line.find(' ')) {
      inside = start <= at && at < end;
      continue;
    }
    if (inside && line.rfind("AnonHugePages:", 0) == 0) return std::stol(line.substr(14));
  }
  return -1;
}

// Runs this program's HeapChild.Report with `extra` added to the environment; its output (and
// whether it exited with 0).
std::string RunChild(const std::vector<std::string>& extra, bool* ok, pid_t* pid_out = nullptr) {
  std::vector<std::string> variables = {"IBMR_HEAP_TEST_CHILD=1"};
  for (char** e = environ; *e; ++e) {
    const std::string entry = *e;
    if (entry.rfind("GLIBC_TUNABLES=", 0) == 0 || entry.rfind("IBMR_HUGE_PAGES=", 0) == 0) continue;
    variables.push_back(entry);
  }
  variables.insert(variables.end(), extra.begin(), extra.end());
  std::vector<char*> envp;
  for (std::string& v : variables) envp.push_back(v.data());
  envp.push_back(nullptr);
  char self[] = "/proc/self/exe", filter[] = "--gtest_filter=HeapChild.Report";
  char* argv[] = {self, filter, nullptr};
  const std::string output = testing::TempDir() + "heap_child_" + std::to_string(::getpid()) + ".txt";
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, output.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  pid_t pid = 0;
  const int spawned = posix_spawn(&pid, "/proc/self/exe", &actions, nullptr, argv, envp.data());
  posix_spawn_file_actions_destroy(&actions);
  if (pid_out) *pid_out = pid;
  int status = 0;
  *ok = spawned == 0 && waitpid(pid, &status, 0) == pid && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  std::stringstream text;
  text << std::ifstream(output).rdbuf();
  std::remove(output.c_str());
  return text.str();
}

// The value after "key=" on its own line of a child's report.
std::string Field(const std::string& report, const std::string& key) {
  const size_t at = report.find("\n" + key + "=");
  if (at == std::string::npos) return "(absent)";
  const size_t begin = at + key.size() + 2;
  return report.substr(begin, report.find('\n', begin) - begin);
}

// The child: as ibmr's main starts, then a 64 MB block touched, and what it saw.
TEST(HeapChild, Report) {
  if (!std::getenv("IBMR_HEAP_TEST_CHILD")) GTEST_SKIP() << "run as a child by HeapHugePages tests";
  char self[] = "/proc/self/exe", filter[] = "--gtest_filter=HeapChild.Report";
  char* argv[] = {self, filter, nullptr};
  ConfigureHeap(argv);
  const size_t bytes = size_t{64} << 20;
  char* block = static_cast<char*>(std::malloc(bytes));
  ASSERT_NE(block, nullptr);
  std::memset(block, 1, bytes);
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  std::printf("\npid=%d\nhuge_kb=%ld\ntunables=%s\nmarker=%s\n", static_cast<int>(::getpid()), HugePagesKbAt(block + bytes / 2),
              tunables ? tunables : "(unset)", std::getenv("IBMR_HEAP_RESTARTED") ? "set" : "(unset)");
  std::fflush(stdout);
  std::free(block);
}

// A large block is backed by huge pages after the second start, and not without it (on a system
// whose transparent huge pages are given on request only); the children of the program see the
// environment the user gave it (GLIBC_TUNABLES unset, or the user's own value).
TEST(HeapHugePages, LargeBlocksGetHugePagesAndChildrenSeeTheUsersEnvironment) {
  const std::string mode = ThpMode();
  if (mode != "madvise" && mode != "always") GTEST_SKIP() << "transparent huge pages are '" << mode << "' here";
  bool ok = false;
  pid_t pid = 0;
  const std::string unset = RunChild({}, &ok, &pid);
  ASSERT_TRUE(ok) << unset;
  EXPECT_EQ(Field(unset, "pid"), std::to_string(pid)) << "the second start is not the same process: " << unset;
  EXPECT_GT(std::stol(Field(unset, "huge_kb")), 0) << unset;
  EXPECT_EQ(Field(unset, "tunables"), "(unset)") << unset;
  EXPECT_EQ(Field(unset, "marker"), "(unset)") << unset;

  const std::string user = RunChild({"GLIBC_TUNABLES=glibc.malloc.tcache_count=5"}, &ok);
  ASSERT_TRUE(ok) << user;
  EXPECT_GT(std::stol(Field(user, "huge_kb")), 0) << user;
  EXPECT_EQ(Field(user, "tunables"), "glibc.malloc.tcache_count=5") << user;

  const std::string off = RunChild({"IBMR_HUGE_PAGES=0"}, &ok);
  ASSERT_TRUE(ok) << off;
  EXPECT_EQ(Field(off, "tunables"), "(unset)") << off;
  if (mode == "madvise") EXPECT_EQ(std::stol(Field(off, "huge_kb")), 0) << "huge pages without asking: " << off;
}

}  // namespace
}  // namespace ibmr
