// The warnings a stage logs while it runs, kept in its record (records/<stage>.json: "warnings",
// "warning_count") so that a later stage's failure can say what went wrong upstream: a chain
// whose stereo found no neighbour views ends with surfels failing on an empty point cloud, and
// the user is owed the first cause, not the last symptom (issue 67: "when a method produces
// nothing, the cell and the run say why").
#pragma once

#include <memory>
#include <string>
#include <tuple>
#include <vector>

namespace spdlog::sinks {
class sink;
}

namespace ibmr {

// While alive, collects the text of every warning (and error) logged through spdlog's default
// logger: the first `keep` messages, and how many there were. Attach between stages only (no
// other thread logging while the sink is added and removed).
class StageWarnings {
 public:
  explicit StageWarnings(size_t keep = 20);
  ~StageWarnings();
  StageWarnings(const StageWarnings&) = delete;
  StageWarnings& operator=(const StageWarnings&) = delete;

  std::vector<std::string> Messages() const;  // the first `keep`, in order
  size_t Count() const;                       // all of them

 private:
  std::shared_ptr<spdlog::sinks::sink> sink_;
};

// One line for a failure's message: the first warning of each stage in `stages_warnings`
// (stage name, its warnings, its warning count), in order, at most `max_stages` of them, e.g.
// "[plane_sweep] view_1.png: no neighbour view ... (5 warnings); [fuse] no point is left: ...".
// Empty when none warned.
std::string UpstreamWarnings(const std::vector<std::tuple<std::string, std::vector<std::string>, size_t>>& stages_warnings,
                             size_t max_stages = 3);

}  // namespace ibmr
