// The warnings a stage logs while it runs (see stage_warnings.h).
#include "pipeline/runner/stage_warnings.h"

#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <mutex>
#include <tuple>

namespace ibmr {

namespace {

class CollectingSink : public spdlog::sinks::base_sink<std::mutex> {
 public:
  explicit CollectingSink(size_t keep) : keep_(keep) {}
  std::vector<std::string> Messages() {
    std::lock_guard<std::mutex> lock(mutex_);
    return messages_;
  }
  size_t Count() {
    std::lock_guard<std::mutex> lock(mutex_);
    return count_;
  }

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    ++count_;
    if (messages_.size() < keep_) messages_.emplace_back(msg.payload.data(), msg.payload.size());
  }
  void flush_() override {}

 private:
  size_t keep_;
  size_t count_ = 0;
  std::vector<std::string> messages_;
};

}  // namespace

StageWarnings::StageWarnings(size_t keep) : sink_(std::make_shared<CollectingSink>(keep)) {
  sink_->set_level(spdlog::level::warn);
  spdlog::default_logger()->sinks().push_back(sink_);
}

StageWarnings::~StageWarnings() {
  auto& sinks = spdlog::default_logger()->sinks();
  sinks.erase(std::remove(sinks.begin(), sinks.end(), sink_), sinks.end());
}

std::vector<std::string> StageWarnings::Messages() const { return static_cast<CollectingSink&>(*sink_).Messages(); }

size_t StageWarnings::Count() const { return static_cast<CollectingSink&>(*sink_).Count(); }

std::string UpstreamWarnings(const std::vector<std::tuple<std::string, std::vector<std::string>, size_t>>& stages_warnings,
                             size_t max_stages) {
  std::string line;
  size_t stages = 0;
  for (const auto& [stage, messages, count] : stages_warnings) {
    if (messages.empty() || stages == max_stages) continue;
    ++stages;
    std::string first = messages.front();
    const std::string prefix = "[" + stage + "] ";
    if (first.rfind(prefix, 0) == 0) first = first.substr(prefix.size());  // the stage's own tag, once
    line += (line.empty() ? "" : "; ") + prefix + first + (count > 1 ? " (" + std::to_string(count) + " warnings)" : "");
  }
  return line;
}

}  // namespace ibmr
