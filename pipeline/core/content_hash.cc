// Content hashes for the stage cache: XXH3-64 of bytes, printed as 16 hex digits. Files are
// hashed by streaming, so large inputs are never held in memory. A folder's hash covers the
// sorted relative paths of its files and each file's hash; temporaries left by atomic writes
// (see atomic_file.h) are skipped, so a killed writer does not make its outputs look changed.
#include "pipeline/core/content_hash.h"

#include <xxhash.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <regex>
#include <vector>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

std::string ToHex(XXH64_hash_t hash) {
  char text[17];
  std::snprintf(text, sizeof(text), "%016llx", static_cast<unsigned long long>(hash));
  return text;
}

struct StateDeleter {
  void operator()(XXH3_state_t* state) const { XXH3_freeState(state); }
};
using StatePtr = std::unique_ptr<XXH3_state_t, StateDeleter>;

StatePtr NewState() {
  StatePtr state(XXH3_createState());
  if (!state || XXH3_64bits_reset(state.get()) != XXH_OK) throw std::bad_alloc();
  return state;
}

// Hash of a file's bytes, read in blocks; equal to HashBytes(file contents).
std::string HashFile(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) throw IoError("cannot hash " + path + ": " + std::strerror(errno));
  StatePtr state = NewState();
  // One buffer per thread for every file: a fresh megabyte per file was mapped and zeroed each
  // time, which cost more than the hashing (ibmr status on templeRing's workspace: 10.7 s).
  thread_local std::vector<char> buffer(1 << 18);
  size_t n;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), file)) > 0) XXH3_64bits_update(state.get(), buffer.data(), n);
  const bool failed = std::ferror(file) != 0;
  const std::string reason = failed ? std::strerror(errno) : "";
  std::fclose(file);
  if (failed) throw IoError("cannot hash " + path + ": " + reason);
  return ToHex(XXH3_64bits_digest(state.get()));
}

// Temporaries of atomic writes: "name.tmp.<pid>" (WriteFileAtomic) and "stem.tmp<pid>.ext"
// (WriteViaTemporary).
bool IsTemporary(const std::string& file_name) {
  static const std::regex kTemporary(R"(.*\.tmp\.?[0-9]+(\.[^.]*)?)");
  return std::regex_match(file_name, kTemporary);
}

std::string HashFolder(const fs::path& folder, const fs::path& exclude) {
  std::vector<std::string> relative_paths;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (!exclude.empty() && it->is_directory() && it->path().lexically_normal() == exclude) {
      it.disable_recursion_pending();
      continue;
    }
    if (!it->is_regular_file() || IsTemporary(it->path().filename().string())) continue;
    relative_paths.push_back(fs::relative(it->path(), folder).generic_string());
  }
  if (ec) throw IoError("cannot list folder " + folder.string() + ": " + ec.message());
  std::sort(relative_paths.begin(), relative_paths.end());
  // The marker keeps an empty folder distinct from an empty file.
  std::string listing = "folder\n";
  for (const std::string& relative : relative_paths) {
    listing += relative + '\0' + HashFile((folder / relative).string()) + '\n';
  }
  return HashBytes(listing);
}

}  // namespace

std::string HashBytes(const std::string& bytes) { return ToHex(XXH3_64bits(bytes.data(), bytes.size())); }

std::string HashPath(const std::string& path, const std::string& exclude) {
  std::error_code ec;
  const fs::file_status status = fs::status(path, ec);
  if (!fs::exists(status)) return "missing";
  if (fs::is_directory(status)) {
    // Compared by normalised absolute path, as the iterator spells its entries from `path`.
    const fs::path root = fs::absolute(path).lexically_normal();
    fs::path excluded = exclude.empty() ? fs::path() : fs::absolute(exclude).lexically_normal();
    if (!excluded.empty() && !excluded.has_filename()) excluded = excluded.parent_path();  // drop a trailing '/'
    return HashFolder(root, excluded);
  }
  return HashFile(path);
}

}  // namespace ibmr
