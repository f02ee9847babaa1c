// Per-view marks: <folder>/<view>.done holds, in CBOR (binary JSON: a piece may carry thousands of
// numbers, which CBOR keeps exact and compact), {"key": cache key, "piece": the view's metrics}.
// A mark only counts when its key equals the current one, so changed inputs or parameters redo
// every view without anyone having to delete stale marks first.
#include "pipeline/core/view_checkpoint.h"

#include <filesystem>
#include <system_error>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

// The mark of a view inside `folder`. A view name may hold folders (an image in a subfolder), but
// an absolute one or one with a ".." step would put its mark outside: refused.
std::string MarkPath(const std::string& folder, const std::string& view) {
  const std::filesystem::path relative(view + ".done");
  bool escapes = view.empty() || relative.is_absolute();
  for (const auto& step : relative) escapes = escapes || step == "..";
  if (escapes) {
    throw InputError("view name '" + view + "' cannot name a mark inside " + folder +
                     " (empty, absolute or with a '..' step); rename the image or the model's entry");
  }
  return (std::filesystem::path(folder) / relative).string();
}

}  // namespace

std::optional<nlohmann::json> ViewCheckpoint::Piece(const std::string& view) const {
  if (folder_.empty()) return std::nullopt;
  const std::string path = MarkPath(folder_, view);
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return std::nullopt;
  try {
    const std::string bytes = ReadFile(path);
    const nlohmann::json mark = nlohmann::json::from_cbor(bytes, /*strict=*/true, /*allow_exceptions=*/false);
    if (!mark.is_object() || mark.value("key", std::string()) != key_ || !mark.contains("piece")) return std::nullopt;
    return mark["piece"];
  } catch (const std::exception&) {
    return std::nullopt;  // unreadable or not a mark of ours
  }
}

void ViewCheckpoint::MarkDone(const std::string& view, const nlohmann::json& piece) const {
  if (folder_.empty()) return;
  const std::vector<std::uint8_t> bytes = nlohmann::json::to_cbor(nlohmann::json{{"key", key_}, {"piece", piece}});
  WriteFileAtomic(MarkPath(folder_, view), std::string(bytes.begin(), bytes.end()));
}

void ViewCheckpoint::Clear() const {
  if (folder_.empty()) return;
  std::error_code ec;
  std::filesystem::remove_all(folder_, ec);
  if (ec) throw IoError("cannot remove checkpoint folder " + folder_ + ": " + ec.message());
}

}  // namespace ibmr
