// Tests of ConfigureHeap's second start with huge pages (process_memory.h): this test program runs
// itself as a child (its own test HeapChild.Report), which calls ConfigureHeap the way ibmr's main
// does; the child reports whether huge pages were asked for a large block and what environment
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

// What /proc/self/smaps says of the mapping that holds `address`: whether huge pages were asked
// for it (VmFlags "hg", set by madvise(MADV_HUGEPAGE) whether or not the kernel could give them)
// and how many it holds (AnonHugePages, kB; depends on the free memory's state). False, -1 when
// the mapping is not found.
bool HugePagesAskedAt(const void* address, long* huge_kb) {
  std::ifstream in("/proc/self/smaps");
  std::string line;
  bool inside = false;
  *huge_kb = -1;
  const auto at = reinterpret_cast<uintptr_t>(address);
  while (std::getline(in, line)) {
    unsigned long start = 0, end = 0;
    if (std::sscanf(line.c_str(), "%lx-%lx ", &start, &end) == 2 && line.find(':') > line.find(' ')) {
      inside = start <= at && at < end;
      continue;
    }
    if (!inside) continue;
    if (line.rfind("AnonHugePages:", 0) == 0) *huge_kb = std::stol(line.substr(14));
    if (line.rfind("VmFlags:", 0) == 0) return (line + " ").find(" hg ") != std::string::npos;
  }
  return false;
}

// Runs this program's HeapChild.Report with `extra` added to the environment; its output (and
// whether it exited with 0).
std::string RunChild(const std::vector<std::string>& extra, bool* ok, pid_t* pid_out = nullptr) {
  std::vector<std::string> variables = {"IBMR_HEAP_TEST_CHILD=1"};
  for (char** e = environ; *e; ++e) {
    const std::string entry = *e;
    if (entry.rfind("GLIBC_TUNABLES=", 0) == 0 || entry.rfind("IBMR_HUGE_PAGES=", 0) == 0 ||
        entry.rfind("IBMR_HEAP_RESTARTED=", 0) == 0) {
      continue;
    }
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
  const bool restarted = ConfigureHeap(argv);
  const size_t bytes = size_t{64} << 20;
  char* block = static_cast<char*>(std::malloc(bytes));
  ASSERT_NE(block, nullptr);
  std::memset(block, 1, bytes);
  long huge_kb = -1;
  const bool asked = HugePagesAskedAt(block + bytes / 2, &huge_kb);
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  std::printf("\npid=%d\nrestarted=%d\nasked=%d\nhuge_kb=%ld\ntunables=%s\nmarker=%s\n", static_cast<int>(::getpid()),
              restarted, asked, huge_kb, tunables ? tunables : "(unset)",
              std::getenv("IBMR_HEAP_RESTARTED") ? std::getenv("IBMR_HEAP_RESTARTED") : "(unset)");
  std::fflush(stdout);
  std::free(block);
}

// The second start asks for huge pages on large blocks, in the same process, and leaves the
// tunable (after the user's own ones) for its children; without it (turned off, or the user's own
// setting of the tunable) no huge pages are asked for. A marker inherited from another process
// is not taken for a second start.
TEST(HeapHugePages, TheSecondStartAsksForHugePagesAndPassesTheTunableOn) {
  const std::string mode = ThpMode();
  if (mode != "madvise") GTEST_SKIP() << "transparent huge pages are '" << mode << "' here, not 'madvise': no second start";
  bool ok = false;
  pid_t pid = 0;
  const std::string plain = RunChild({}, &ok, &pid);
  ASSERT_TRUE(ok) << plain;
  EXPECT_EQ(Field(plain, "restarted"), "1") << plain;
  EXPECT_EQ(Field(plain, "pid"), std::to_string(pid)) << "the second start is not the same process: " << plain;
  EXPECT_EQ(Field(plain, "asked"), "1") << plain;
  EXPECT_EQ(Field(plain, "tunables"), "glibc.malloc.hugetlb=1") << plain;
  EXPECT_EQ(Field(plain, "marker"), "(unset)") << plain;

  const std::string user = RunChild({"GLIBC_TUNABLES=glibc.malloc.tcache_count=5"}, &ok);
  ASSERT_TRUE(ok) << user;
  EXPECT_EQ(Field(user, "restarted"), "1") << user;
  EXPECT_EQ(Field(user, "asked"), "1") << user;
  EXPECT_EQ(Field(user, "tunables"), "glibc.malloc.tcache_count=5:glibc.malloc.hugetlb=1") << user;

  const std::string stale = RunChild({"IBMR_HEAP_RESTARTED=1"}, &ok);
  ASSERT_TRUE(ok) << stale;
  EXPECT_EQ(Field(stale, "restarted"), "1") << "an inherited marker was taken for a second start: " << stale;
  EXPECT_EQ(Field(stale, "asked"), "1") << stale;
  EXPECT_EQ(Field(stale, "tunables"), "glibc.malloc.hugetlb=1") << stale;
  EXPECT_EQ(Field(stale, "marker"), "(unset)") << stale;

  for (const std::string& without : {std::string("IBMR_HUGE_PAGES=0"), std::string("GLIBC_TUNABLES=glibc.malloc.hugetlb=0")}) {
    const std::string report = RunChild({without}, &ok);
    ASSERT_TRUE(ok) << report;
    EXPECT_EQ(Field(report, "restarted"), "0") << without << ": " << report;
    EXPECT_EQ(Field(report, "asked"), "0") << without << ": " << report;
    const std::string given = without.rfind("GLIBC_TUNABLES=", 0) == 0 ? without.substr(15) : "(unset)";
    EXPECT_EQ(Field(report, "tunables"), given) << without << ": " << report;
  }
}

}  // namespace
}  // namespace ibmr
