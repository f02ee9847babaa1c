// Displays stage progress: on a terminal, a bar with counts, rate and ETA redrawn in place
// (at most 10 times a second); otherwise (logs, CI) a plain log line every 10% or 10 s.
#pragma once

#include <chrono>
#include <mutex>
#include <string>

#include "pipeline/core/progress.h"

namespace ibmr {

class TerminalProgress : public ProgressReporter {
 public:
  TerminalProgress(std::string stage, bool interactive) : stage_(std::move(stage)), interactive_(interactive) {}
  void Begin(const std::string& phase, size_t total) override;
  void Advance(size_t count, const std::string& item) override;
  void End() override;

  // "12/24 [#####     ] 50% 3.1/s ETA 4s" for a given state (exposed for tests).
  static std::string FormatBar(size_t done, size_t total, double elapsed_seconds, int width);

 private:
  using Clock = std::chrono::steady_clock;
  std::string stage_;
  bool interactive_;
  std::mutex mutex_;
  std::string phase_;
  size_t total_ = 0;
  size_t done_ = 0;
  size_t resumed_ = 0;
  int last_decile_ = -1;
  Clock::time_point start_;
  Clock::time_point last_draw_;
};

}  // namespace ibmr
