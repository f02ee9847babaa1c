// Entries of `render.proxies` parsed into model kinds, and what every model shares (render_model.h).
#include "stages/render/render_model.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <climits>
#include <filesystem>
#include <map>

#include "pipeline/core/errors.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

bool EndsWithPly(const std::string& path) {
  std::string extension = fs::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return extension == ".ply";
}

const RenderModelKind* FindKind(const std::string& keyword) {
  for (const RenderModelKind& kind : RenderModelKinds()) {
    if (kind.keyword == keyword) return &kind;
  }
  return nullptr;
}

// The kinds that take "@N", as the user writes them, and what N counts for each.
std::string DetailKinds(bool meanings) {
  std::string list;
  for (const RenderModelKind& kind : RenderModelKinds()) {
    if (kind.max_detail <= 0) continue;
    list += (list.empty() ? "" : ", ") + (meanings ? kind.detail_meaning : kind.syntax);
  }
  return list;
}

}  // namespace

double RenderModel::ViewBytes(const StageContext& context, double pixels) const {
  const double factor = static_cast<double>(context.params.Int("supersample"));
  return pixels * factor * factor * 88.0;
}

bool RenderModel::FromTruth(const Workspace& workspace) const {
  return SourcePath(workspace).rfind("ground_truth/", 0) == 0;
}

void RenderModel::AddMetrics(nlohmann::json*) const {}

std::string AbsolutePath(const std::string& path, const Workspace& workspace) {
  return fs::path(path).is_absolute() ? path : workspace.Path(path);
}

std::string DescribeRenderModelKinds(const std::string& indent) {
  std::string text;
  for (const RenderModelKind& kind : RenderModelKinds()) text += indent + kind.syntax + ": " + kind.summary + "\n";
  return text;
}

// "name=" and "@N" first (an @N ends at the first `|`), then a keyword, "keyword:option" or a mesh
// path with its fallbacks. A default name: the kind's (a mesh's file stem, prefixed by its folder
// when the stem alone says little: "ground_truth/mesh.ply" -> ground_truth_mesh, "hull/hull.ply"
// -> hull), and "_N" for a detail.
ModelEntry ParseModelEntry(const std::string& text) {
  if (text.empty() || text.back() == '=') throw InputError("empty proxy entry \"" + text + "\"");
  ModelEntry entry;
  entry.entry = text;
  std::string path = text;
  const size_t eq = text.find('=');
  if (eq != std::string::npos) {
    entry.name = text.substr(0, eq);
    path = text.substr(eq + 1);
  }
  std::string detail_text;
  const size_t at = path.find('@');
  if (at != std::string::npos) {
    const size_t end = std::min(path.find('|', at), path.size());
    detail_text = path.substr(at + 1, end - at - 1);
    int value = 0;
    const auto [last, error] = std::from_chars(detail_text.data(), detail_text.data() + detail_text.size(), value);
    entry.detail = error == std::errc() && last == detail_text.data() + detail_text.size() && value > 0 ? value : -1;
    path.erase(at, end - at);
  }
  const size_t colon = path.find(':');
  if (FindKind(path) != nullptr && !path.empty()) {
    entry.keyword = path;
  } else if (colon != std::string::npos && FindKind(path.substr(0, colon)) != nullptr &&
             FindKind(path.substr(0, colon))->takes_option) {
    entry.keyword = path.substr(0, colon);
    entry.option = path.substr(colon + 1);
  } else {
    for (size_t bar = path.rfind('|'); bar != std::string::npos; bar = path.rfind('|')) {
      entry.fallbacks.insert(entry.fallbacks.begin(), path.substr(bar + 1));
      path = path.substr(0, bar);
    }
    if (!EndsWithPly(path) || FindKind("") == nullptr) {
      throw InputError("\"" + text + "\" is no render model; an entry is [name=] one of:\n" +
                       DescribeRenderModelKinds("  "));
    }
    entry.path = path;
  }
  if (entry.name.empty()) {
    const RenderModelKind& kind = KindOf(entry);
    entry.name = (kind.default_name ? kind.default_name(entry) : entry.keyword) +
                 (entry.detail > 0 ? "_" + detail_text : "");
  }
  return entry;
}

const RenderModelKind& KindOf(const ModelEntry& entry) {
  const RenderModelKind* kind = FindKind(entry.keyword);
  if (kind == nullptr) throw InputError("\"" + entry.entry + "\": no render model \"" + entry.keyword + "\"");
  return *kind;
}

std::string CheckModelEntry(const ModelEntry& entry) {
  const RenderModelKind& kind = KindOf(entry);
  const std::string quoted = "\"" + entry.entry + "\": ";
  if (entry.detail < 0) return quoted + "@N needs a positive whole number (" + DetailKinds(true) + ")";
  if (entry.detail > 0 && kind.max_detail <= 0) return quoted + "@N applies to " + DetailKinds(false) + " only";
  if (entry.detail > 0 && (entry.detail < kind.min_detail || entry.detail > kind.max_detail)) {
    return quoted + "@N counts " + kind.detail_meaning + ", at least " + std::to_string(kind.min_detail) +
           (kind.max_detail < INT_MAX ? " and at most " + std::to_string(kind.max_detail) : std::string());
  }
  return kind.check_entry ? kind.check_entry(entry) : std::string();
}

std::string CheckModelEntries(const std::vector<std::string>& entries) {
  if (entries.empty()) return "list at least one proxy (e.g. [plane])";
  std::map<std::string, std::string> entry_of_name;  // each model writes renders/<name>/
  for (const std::string& text : entries) {
    ModelEntry entry;
    try {
      entry = ParseModelEntry(text);
    } catch (const InputError& e) {
      return e.what();
    }
    const auto [named, fresh] = entry_of_name.emplace(entry.name, text);
    if (!fresh) {
      return "\"" + named->second + "\" and \"" + text + "\" are both named \"" + entry.name +
             "\" (both would write renders/" + entry.name + "/); name one, e.g. " + entry.name + "_2=" +
             text.substr(text.find('=') == std::string::npos ? 0 : text.find('=') + 1);
    }
    if (const std::string error = CheckModelEntry(entry); !error.empty()) return error;
  }
  return "";
}

std::unique_ptr<RenderModel> MakeRenderModel(const std::string& text, const Workspace& workspace) {
  ModelEntry entry = ParseModelEntry(text);
  const RenderModelKind& kind = KindOf(entry);
  return kind.make(std::move(entry), workspace);
}

}  // namespace ibmr
