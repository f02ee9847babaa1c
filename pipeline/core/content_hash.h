// Content hashes for the stage cache: XXH3-64 of file bytes, hex encoded. A folder hashes the
// sorted list of its files' relative paths and contents, so renaming a file changes the hash.
#pragma once

#include <string>

namespace ibmr {

std::string HashBytes(const std::string& bytes);
// Hash of a file or folder; "missing" when the path does not exist. A folder `exclude` inside
// `path` (the workspace, when it sits in the photo folder it imports) is left out, as if absent:
// its logs and records change on every run, and would make the input look changed every time.
std::string HashPath(const std::string& path, const std::string& exclude = "");

}  // namespace ibmr
