// Per-stage workspace locks (see stage_lock.h).
#include "pipeline/runner/stage_lock.h"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <string>
#include <thread>

namespace ibmr {

namespace {

const char* const kShards = "shards (--views) of the stage";

// What the holder of an exclusive lock writes into the file: enough to find the process.
std::string Description() {
  char host[256] = {0};
  if (gethostname(host, sizeof(host) - 1) != 0) std::strcpy(host, "?");
  return "pid " + std::to_string(getpid()) + " on " + host;
}

// The filesystem cannot lock (some network mounts): run unlocked.
bool LocksUnsupported(int error) { return error == ENOLCK || error == EOPNOTSUPP || error == ENOSYS || error == EINVAL; }

std::string ReadDescription(int fd) {
  char buffer[512] = {0};
  const ssize_t n = pread(fd, buffer, sizeof(buffer) - 1, 0);
  const std::string text = n > 0 ? std::string(buffer, static_cast<size_t>(n)) : std::string();
  return text.empty() ? "another ibmr process" : text;
}

// Who holds the lock that made flock fail on `fd`: shards (a shared lock can still be had) or an
// exclusive holder (its description).
std::string HolderOf(int fd) {
  if (flock(fd, LOCK_SH | LOCK_NB) == 0) {
    flock(fd, LOCK_UN);
    return kShards;
  }
  return ReadDescription(fd);
}

}  // namespace

StageLock::~StageLock() {
  if (fd_ >= 0) close(fd_);  // closing the descriptor releases the lock
}

bool StageLock::TryLock(const std::string& path, bool exclusive, std::string* holder) {
  const int fd = open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    spdlog::warn("cannot open the lock file {} ({}); running without a lock", path, std::strerror(errno));
    return true;
  }
  // A few tries over 100 ms: another process's LockHolder probe, or HolderOf below, holds the lock
  // for microseconds; a stage that runs holds it for its whole run.
  int result = -1;
  for (int attempt = 0; attempt < 20; ++attempt) {
    result = flock(fd, (exclusive ? LOCK_EX : LOCK_SH) | LOCK_NB);
    if (result == 0 || errno != EWOULDBLOCK) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (result != 0) {
    const int error = errno;
    if (LocksUnsupported(error)) {
      close(fd);
      spdlog::warn("the filesystem of {} has no file locks ({}); two runs of a stage at once go undetected", path,
                   std::strerror(error));
      return true;
    }
    if (holder != nullptr) *holder = error == EWOULDBLOCK ? HolderOf(fd) : std::strerror(error);
    close(fd);
    return false;
  }
  if (exclusive) {
    const std::string text = Description();
    if (ftruncate(fd, 0) != 0 || pwrite(fd, text.data(), text.size(), 0) != static_cast<ssize_t>(text.size())) {
      spdlog::warn("cannot write {}; the lock holds, but other runs will not see who holds it", path);
    }
  }
  if (fd_ >= 0) close(fd_);
  fd_ = fd;
  return true;
}

std::string LockHolder(const std::string& path) {
  // Read-write where allowed: NFS emulates flock by fcntl locks, whose exclusive form needs it.
  int fd = open(path.c_str(), O_RDWR | O_CLOEXEC);
  if (fd < 0) fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return "";  // never locked
  std::string holder;
  if (flock(fd, LOCK_SH | LOCK_NB) != 0) {  // an exclusive holder: a whole run or a merge
    if (errno == EWOULDBLOCK) holder = ReadDescription(fd);
  } else {
    flock(fd, LOCK_UN);
    if (flock(fd, LOCK_EX | LOCK_NB) == 0) {
      flock(fd, LOCK_UN);  // nobody
    } else if (errno == EWOULDBLOCK) {
      holder = kShards;
    }
  }
  close(fd);
  return holder;
}

}  // namespace ibmr
