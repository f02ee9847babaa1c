// Progress bar with ETA on a terminal, plain lines elsewhere (see terminal_progress.h).
#include "pipeline/runner/terminal_progress.h"

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdio>

namespace ibmr {

namespace {
std::string FormatSeconds(double s) {
  char buffer[32];
  if (s < 60) {
    std::snprintf(buffer, sizeof(buffer), "%.0fs", s);
  } else if (s < 3600) {
    std::snprintf(buffer, sizeof(buffer), "%dm%02ds", static_cast<int>(s) / 60, static_cast<int>(s) % 60);
  } else {
    std::snprintf(buffer, sizeof(buffer), "%dh%02dm", static_cast<int>(s) / 3600, (static_cast<int>(s) / 60) % 60);
  }
  return buffer;
}
}  // namespace

std::string TerminalProgress::FormatBar(size_t done, size_t total, double elapsed, int width) {
  const double fraction = total ? static_cast<double>(done) / total : 1.0;
  const int filled = static_cast<int>(std::round(fraction * width));
  std::string bar = std::to_string(done) + "/" + std::to_string(total) + " [";
  bar += std::string(filled, '#') + std::string(width - filled, ' ') + "] ";
  bar += std::to_string(static_cast<int>(fraction * 100)) + "%";
  if (done > 0 && elapsed > 0) {
    char rate[32];
    std::snprintf(rate, sizeof(rate), " %.2f/s", done / elapsed);
    bar += rate;
    if (done < total) bar += " ETA " + FormatSeconds(elapsed / done * (total - done));
  }
  return bar;
}

void TerminalProgress::Begin(const std::string& phase, size_t total) {
  std::lock_guard<std::mutex> lock(mutex_);
  phase_ = phase;
  total_ = total;
  done_ = 0;
  resumed_ = 0;
  last_decile_ = -1;
  start_ = last_draw_ = Clock::now();
  spdlog::info("[{}] {}: {} items", stage_, phase_, total_);
}

void TerminalProgress::Advance(size_t count, const std::string& item) {
  std::lock_guard<std::mutex> lock(mutex_);
  done_ += count;
  if (item == "(done by an earlier run)") {
    resumed_ += count;
    spdlog::info("[{}] {}: resuming, {} of {} already done", stage_, phase_, count, total_);
    return;
  }
  const auto now = Clock::now();
  // ETA from the items computed in this run only, so resumed ones do not make it optimistic.
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  const size_t computed = done_ - resumed_;
  const std::string bar = FormatBar(computed, total_ - resumed_, elapsed, 24);
  if (interactive_) {
    if (done_ == total_ || now - last_draw_ > std::chrono::milliseconds(100)) {
      std::fprintf(stderr, "\r\033[K[%s] %s %s %s", stage_.c_str(), phase_.c_str(), bar.c_str(), item.c_str());
      std::fflush(stderr);
      last_draw_ = now;
    }
    return;
  }
  const int decile = total_ ? static_cast<int>(10 * done_ / total_) : 10;
  if (decile != last_decile_ || now - last_draw_ > std::chrono::seconds(10)) {
    spdlog::info("[{}] {} {} {}", stage_, phase_, bar, item);
    last_decile_ = decile;
    last_draw_ = now;
  }
}

void TerminalProgress::End() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (interactive_) {
    std::fprintf(stderr, "\r\033[K");
    std::fflush(stderr);
  }
  const double elapsed = std::chrono::duration<double>(Clock::now() - start_).count();
  spdlog::info("[{}] {}: {} done in {:.2f}s", stage_, phase_, total_, elapsed);
}

}  // namespace ibmr
