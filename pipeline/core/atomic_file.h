// Atomic writes: data goes to "<path>.tmp.<pid>" in the same folder, is flushed to the disk
// (fsync), then rename(2) replaces the target in one step, so a process killed halfway, or a
// machine that loses power, leaves the previous good file or the new one, never a partial one. The
// folder is flushed after the rename, so that files written later (a stage's record) never reach
// the disk before this one's new name does (1052 flushes cost 0.15 s in the synthetic room's run).
#pragma once

#include <functional>
#include <initializer_list>
#include <string>
#include <string_view>

namespace ibmr {

// Writes `bytes` to `path` atomically; creates parent folders. Throws IoError.
void WriteFileAtomic(const std::string& path, const std::string& bytes);
// The same with the file's bytes in pieces, written one after the other (a header and a payload
// that lives elsewhere: no copy of the whole into one string, whose fresh pages a multi-megabyte
// map would first fault in and fill).
void WriteFileAtomic(const std::string& path, std::initializer_list<std::string_view> pieces);
// Calls `write(tmp_path)` to produce the file under a temporary name, then renames it onto
// `path`. For writers that need a path of their own (cv::imwrite). Throws IoError.
void WriteViaTemporary(const std::string& path, const std::function<void(const std::string& tmp_path)>& write);
// Removes the temporaries that killed writers left under `path` (a file's folder siblings, or a
// folder's files, recursively): names "<name>.tmp.<pid>" and "<stem>.tmp<pid><ext>" as written
// above, whose process no longer exists. Returns how many were removed; never throws.
size_t RemoveStaleTemporaries(const std::string& path);
// Reads a whole file; throws IoError naming the path when it cannot.
std::string ReadFile(const std::string& path);

}  // namespace ibmr
