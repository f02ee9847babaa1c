// Per-stage locks on a workspace, so that two ibmr processes never run one stage at once.
//
// Without them a second `ibmr run` on a workspace whose stage was still running elsewhere read
// the record's "running" as an interrupted run, started the stage again, removed the first
// process's temporary files as left-overs and raced it for the outputs and the record.
//
// A lock is an advisory flock(2) on records/<stage>.lock, taken without waiting:
//  * a whole-stage run (and a merge of shards) takes it exclusively and writes its pid and host
//    into the file, for the message another process prints;
//  * a shard (`--only STAGE --views ...`) takes it shared: shards of one stage run side by side,
//    as the cluster path starts them, but not beside a whole run or a merge of the same stage.
// The kernel drops a lock when its process ends, however it ends: a killed run leaves no stale
// lock. The file itself stays (removing it would let a third process lock a new file while a
// second still holds the old one). On a filesystem without flock (some network mounts) the run
// goes on unlocked, with a warning.
#pragma once

#include <string>

namespace ibmr {

class StageLock {
 public:
  StageLock() = default;
  StageLock(const StageLock&) = delete;
  StageLock& operator=(const StageLock&) = delete;
  ~StageLock();  // releases the lock

  // Takes the lock at `path` (created if missing) without waiting for a holder (a few retries over
  // 100 ms ride out another process's probe): true when taken, or when the filesystem has no
  // locks. False when another process holds it; `holder` then says who ("pid 1234 on host" or
  // "shards (--views) of the stage").
  bool TryLock(const std::string& path, bool exclusive, std::string* holder);

 private:
  int fd_ = -1;
};

// Who holds the lock at `path` now, as TryLock says it, or "" when nobody does. It takes and drops
// the lock for an instant to find out (a probe, not a claim); TryLock's retries ride that out.
std::string LockHolder(const std::string& path);

}  // namespace ibmr
