// The cache of a model folder's image names (sparse_image_names.h).
#include "pipeline/core/sparse_image_names.h"

#include <sys/stat.h>

#include <array>
#include <exception>
#include <map>
#include <mutex>

#include "pipeline/core/colmap_text_io.h"

namespace ibmr {
namespace {

// One file's version: exists, inode, size, modification time in ns.
using FileVersion = std::array<long long, 4>;
using FolderVersion = std::array<FileVersion, 3>;

FileVersion VersionOf(const std::string& path) {
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0) return {0, 0, 0, 0};
  return {1, static_cast<long long>(info.st_ino), static_cast<long long>(info.st_size),
          static_cast<long long>(info.st_mtim.tv_sec) * 1000000000LL + info.st_mtim.tv_nsec};
}

constexpr size_t kKeptFolders = 8;

}  // namespace

SparseImageNames ReadSparseImageNamesCached(const std::string& sparse_dir) {
  static std::mutex mutex;
  static std::map<std::string, std::pair<FolderVersion, SparseImageNames>> cache;
  const FolderVersion version = {VersionOf(sparse_dir + "/cameras.txt"), VersionOf(sparse_dir + "/images.txt"),
                                 VersionOf(sparse_dir + "/points3D.txt")};
  {
    std::lock_guard<std::mutex> lock(mutex);
    if (const auto found = cache.find(sparse_dir); found != cache.end() && found->second.first == version) {
      return found->second.second;
    }
  }
  SparseImageNames result;
  if (version[1][0] != 0) {  // images.txt exists
    try {
      const SparseModel model = ReadSparseModelText(sparse_dir);
      for (int id : model.ImageIdsByName()) result.names.push_back(model.images.at(id).name);
      result.readable = true;
    } catch (const std::exception& e) {
      result.error = e.what();
    }
  }
  std::lock_guard<std::mutex> lock(mutex);
  if (cache.size() >= kKeptFolders && !cache.count(sparse_dir)) cache.erase(cache.begin());
  cache[sparse_dir] = {version, result};
  return result;
}

}  // namespace ibmr
