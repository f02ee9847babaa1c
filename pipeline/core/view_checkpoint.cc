// Per-view resumption marks: <folder>/<view>.done holds the cache key of the run that finished
// the view. A mark only counts when its key equals the current one, so changed inputs or
// parameters redo every view without anyone having to delete stale marks first.
#include "pipeline/core/view_checkpoint.h"

#include <filesystem>
#include <system_error>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

std::string MarkPath(const std::string& folder, const std::string& view) {
  return (std::filesystem::path(folder) / (view + ".done")).string();
}

}  // namespace

bool ViewCheckpoint::Done(const std::string& view) const {
  if (folder_.empty()) return false;
  const std::string path = MarkPath(folder_, view);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return false;
  try {
    return ReadFile(path) == key_;
  } catch (const IoError&) {
    return false;  // an unreadable mark only means the view is done again
  }
}

void ViewCheckpoint::MarkDone(const std::string& view) const {
  if (folder_.empty()) return;
  WriteFileAtomic(MarkPath(folder_, view), key_);
}

void ViewCheckpoint::Clear() const {
  if (folder_.empty()) return;
  std::error_code ec;
  std::filesystem::remove_all(folder_, ec);
  if (ec) throw IoError("cannot remove checkpoint folder " + folder_ + ": " + ec.message());
}

}  // namespace ibmr
