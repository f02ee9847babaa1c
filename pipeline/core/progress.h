// The library reports, the caller displays (as MVE's dmrecon progress and Ceres' callbacks):
// a stage announces a phase with its item count and advances it; the runner draws a bar with
// ETA on a terminal or writes plain lines to logs. Advance() is thread-safe.
#pragma once

#include <cstddef>
#include <string>

namespace ibmr {

class ProgressReporter {
 public:
  virtual ~ProgressReporter() = default;
  // Starts a phase of `total` items ("depth maps", 16).
  virtual void Begin(const std::string& phase, size_t total) = 0;
  // `count` more items are done; `item` names the last one (may be empty). Thread-safe.
  virtual void Advance(size_t count = 1, const std::string& item = "") = 0;
  // The phase is over.
  virtual void End() = 0;
};

// Does nothing; for tests and pure functions called without a reporter.
class NullProgress : public ProgressReporter {
 public:
  void Begin(const std::string&, size_t) override {}
  void Advance(size_t, const std::string&) override {}
  void End() override {}
};

}  // namespace ibmr
