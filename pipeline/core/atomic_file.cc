// Atomic file writes (temporary file in the same folder, flushed to the disk, then rename(2)) and
// whole-file reads. rename within one file system replaces the target in one step, so readers and
// a later run only ever see the previous complete file or the new complete file, after a crash
// too.
#include "pipeline/core/atomic_file.h"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <regex>
#include <system_error>

#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

namespace fs = std::filesystem;

std::string ErrnoText() { return std::strerror(errno); }

void CreateParentFolders(const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  if (parent.empty()) return;
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec) throw IoError("cannot create folder " + parent.string() + " for " + path + ": " + ec.message());
}

// Renames `tmp_path` onto `path` once its data is on the disk (fsync): without that, a crash or a
// power cut soon after can leave the new name on an empty or partial file (the rename reaches the
// disk before the delayed data), and a disk that fills up reports it only when the data is
// written back, after the file was called complete. Removes the temporary and throws when either
// step fails.
// A file system that cannot flush (EINVAL, ENOTSUP: some special and FUSE file systems) is
// taken as it is: the write still replaces the file in one step.
void CommitTemporary(const std::string& tmp_path, const std::string& path) {
  const int fd = ::open(tmp_path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    const std::string reason = ErrnoText();
    std::remove(tmp_path.c_str());
    throw IoError("cannot write " + path + ": cannot reopen its temporary " + tmp_path + " to flush it (" + reason + ")");
  }
  const bool synced = ::fsync(fd) == 0 || errno == EINVAL || errno == ENOTSUP;
  const std::string sync_error = synced ? "" : ErrnoText();
  ::close(fd);
  if (!synced) {
    std::remove(tmp_path.c_str());
    throw IoError("cannot write " + path + ": its data did not reach the disk (" + sync_error +
                  "); free space on the disk or check it, then run again");
  }
  if (std::rename(tmp_path.c_str(), path.c_str()) != 0) {
    const std::string reason = ErrnoText();
    std::remove(tmp_path.c_str());
    throw IoError("cannot rename " + tmp_path + " to " + path + ": " + reason);
  }
  // The new name is an entry of the folder, which reaches the disk on its own schedule: flushed
  // too, so that what is written after this file (the stage's record saying it is done, a view's
  // mark) never reaches the disk before it does. After a power cut the record could otherwise say
  // done over the old file.
  const fs::path parent = fs::path(path).parent_path();
  const std::string folder = parent.empty() ? "." : parent.string();
  const int dir = ::open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir < 0) return;  // a folder that cannot be opened for reading: the rename stands as it is
  const bool dir_synced = ::fsync(dir) == 0 || errno == EINVAL || errno == ENOTSUP || errno == EBADF;
  const std::string dir_error = dir_synced ? "" : ErrnoText();
  ::close(dir);
  if (!dir_synced) {
    throw IoError("cannot write " + path + ": its folder's new entry did not reach the disk (" + dir_error +
                  "); check the disk, then run again");
  }
}

// "dir/x.png" -> "dir/x.tmp<pid>.png": the extension stays last so that writers choosing a
// codec by extension (cv::imwrite) still choose the right one.
std::string TemporaryKeepingExtension(const std::string& path) {
  const fs::path p(path);
  const std::string tmp_name = p.stem().string() + ".tmp" + std::to_string(::getpid()) + p.extension().string();
  return (p.parent_path() / tmp_name).string();
}

}  // namespace

void WriteFileAtomic(const std::string& path, const std::string& bytes) {
  WriteFileAtomic(path, {std::string_view(bytes)});
}

void WriteFileAtomic(const std::string& path, std::initializer_list<std::string_view> pieces) {
  CreateParentFolders(path);
  const std::string tmp_path = path + ".tmp." + std::to_string(::getpid());
  std::FILE* file = std::fopen(tmp_path.c_str(), "wb");
  if (file == nullptr) throw IoError("cannot write " + path + " (temporary " + tmp_path + "): " + ErrnoText());
  bool write_ok = true;
  for (const std::string_view piece : pieces) {
    if (write_ok && !piece.empty()) write_ok = std::fwrite(piece.data(), 1, piece.size(), file) == piece.size();
  }
  const std::string write_error = write_ok ? "" : ErrnoText();
  const bool close_ok = std::fclose(file) == 0;
  if (!write_ok || !close_ok) {
    const std::string reason = write_ok ? ErrnoText() : write_error;
    std::remove(tmp_path.c_str());
    throw IoError("cannot write " + path + " (temporary " + tmp_path + "): " + reason);
  }
  CommitTemporary(tmp_path, path);
}

void WriteViaTemporary(const std::string& path, const std::function<void(const std::string& tmp_path)>& write) {
  CreateParentFolders(path);
  const std::string tmp_path = TemporaryKeepingExtension(path);
  try {
    write(tmp_path);
  } catch (...) {
    std::remove(tmp_path.c_str());
    throw;
  }
  std::error_code ec;
  if (!fs::is_regular_file(tmp_path, ec)) {
    throw IoError("cannot write " + path + ": the writer produced no file " + tmp_path);
  }
  CommitTemporary(tmp_path, path);
}

std::string ReadFile(const std::string& path) {
  std::FILE* file = std::fopen(path.c_str(), "rb");
  if (file == nullptr) throw IoError("cannot read " + path + ": " + ErrnoText());
  // One allocation of the file's size, filled in place: appending block by block re-copied the
  // bytes at every growth of the string, and each new block of memory costs page faults (a
  // third of multi_depth's time on templeRing, which reads 19 maps a view).
  std::string bytes;
  std::error_code ec;
  const auto size = std::filesystem::file_size(path, ec);
  if (!ec) bytes.resize(static_cast<size_t>(size));
  size_t filled = std::fread(bytes.data(), 1, bytes.size(), file);
  bytes.resize(filled);
  char buffer[1 << 16];
  size_t n;
  while ((n = std::fread(buffer, 1, sizeof(buffer), file)) > 0) bytes.append(buffer, n);  // grew meanwhile
  const bool failed = std::ferror(file) != 0;
  const std::string reason = failed ? ErrnoText() : "";
  std::fclose(file);
  if (failed) throw IoError("cannot read " + path + ": " + reason);
  return bytes;
}

size_t RemoveStaleTemporaries(const std::string& path) {
  static const std::regex kTemporary(R"(.*\.tmp\.?(\d+)(\.[^.]+)?$)");
  std::error_code ec;
  const fs::path root(path);
  const fs::path folder = fs::is_directory(root, ec) ? root : root.parent_path();
  const std::string prefix = fs::is_directory(root, ec) ? "" : root.filename().stem().string();
  if (folder.empty() || !fs::is_directory(folder, ec)) return 0;
  size_t removed = 0;
  const auto consider = [&](const fs::directory_entry& entry) {
    if (!entry.is_regular_file(ec)) return;
    const std::string name = entry.path().filename().string();
    if (!prefix.empty() && name.rfind(prefix, 0) != 0) return;  // a file's own temporaries only
    std::smatch match;
    if (!std::regex_match(name, match, kTemporary)) return;
    const long pid = std::stol(match[1]);
    if (pid <= 0 || pid == ::getpid() || (::kill(static_cast<pid_t>(pid), 0) == 0 || errno == EPERM)) return;
    if (fs::remove(entry.path(), ec)) ++removed;
  };
  if (prefix.empty()) {
    for (fs::recursive_directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) consider(*it);
  } else {
    for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) consider(*it);
  }
  return removed;
}

}  // namespace ibmr
