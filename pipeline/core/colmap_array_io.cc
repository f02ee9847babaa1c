// COLMAP's dense array files (depth and normal maps): "W&H&C&" in ASCII, then W*H*C float32
// little-endian values, channel-planar. FloatMap uses the same planar order, so the payload is
// read and written as one block, straight from and to the map.
#include "pipeline/core/colmap_array_io.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "COLMAP arrays are little-endian; add byte swapping");

constexpr long long kMaxDim = 1 << 20;  // bounds W*H*C well inside size_t
constexpr char kExpected[] = "expected a COLMAP array header \"WIDTH&HEIGHT&CHANNELS&\" then float32 values";

// Parses one positive decimal integer followed by '&' starting at `*pos`; advances `*pos`.
bool ParseField(const std::string& bytes, size_t* pos, long long* value) {
  size_t p = *pos;
  long long v = 0;
  const size_t start = p;
  while (p < bytes.size() && std::isdigit(static_cast<unsigned char>(bytes[p])) && p - start < 10) {
    v = v * 10 + (bytes[p] - '0');
    ++p;
  }
  if (p == start || p >= bytes.size() || bytes[p] != '&') return false;
  *value = v;
  *pos = p + 1;
  return true;
}

}  // namespace

FloatMap ReadColmapArray(const std::string& path) {
  // The header from the first bytes, then the payload read straight into the map (not through a
  // string of the whole file and a copy: multi_depth and fuse read dozens of maps a view).
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!file) throw IoError("cannot read " + path + ": " + std::strerror(errno));
  std::error_code ec;
  const size_t file_size = static_cast<size_t>(std::filesystem::file_size(path, ec));
  if (ec) throw IoError("cannot read " + path + ": " + ec.message());
  std::string bytes(std::min<size_t>(file_size, 64), '\0');
  if (std::fread(bytes.data(), 1, bytes.size(), file.get()) != bytes.size()) throw IoError("cannot read " + path + ": short read");
  size_t pos = 0;
  long long width = 0, height = 0, channels = 0;
  if (!ParseField(bytes, &pos, &width) || !ParseField(bytes, &pos, &height) || !ParseField(bytes, &pos, &channels)) {
    throw IoError(path + ": bad header; " + kExpected);
  }
  if (width <= 0 || height <= 0 || channels <= 0 || width > kMaxDim || height > kMaxDim || channels > kMaxDim) {
    throw IoError(path + ": header gives size " + std::to_string(width) + "x" + std::to_string(height) + "x" +
                  std::to_string(channels) + "; every dimension must be in [1, " + std::to_string(kMaxDim) + "]");
  }
  const size_t count = static_cast<size_t>(width) * height * channels;
  const size_t payload = file_size - pos;
  if (payload != count * sizeof(float)) {
    throw IoError(path + ": header says " + std::to_string(width) + "&" + std::to_string(height) + "&" +
                  std::to_string(channels) + "& (" + std::to_string(count * sizeof(float)) +
                  " bytes of float32) but the file holds " + std::to_string(payload) +
                  " bytes after the header (truncated or not a COLMAP array)");
  }
  FloatMap map(static_cast<int>(width), static_cast<int>(height), static_cast<int>(channels));
  if (std::fseek(file.get(), static_cast<long>(pos), SEEK_SET) != 0 ||
      std::fread(map.data.data(), 1, payload, file.get()) != payload) {
    throw IoError(path + ": cannot read its " + std::to_string(payload) + " bytes of float32 (file changed while reading?)");
  }
  return map;
}

void WriteColmapArray(const std::string& path, const FloatMap& map) {
  const size_t count = static_cast<size_t>(map.width) * map.height * map.channels;
  if (map.width <= 0 || map.height <= 0 || map.channels <= 0 || map.data.size() != count) {
    throw IoError("cannot write " + path + ": the map is empty or its data size does not match " +
                  std::to_string(map.width) + "x" + std::to_string(map.height) + "x" + std::to_string(map.channels));
  }
  const std::string header = std::to_string(map.width) + "&" + std::to_string(map.height) + "&" +
                             std::to_string(map.channels) + "&";
  WriteFileAtomic(path, {header, std::string_view(reinterpret_cast<const char*>(map.data.data()), count * sizeof(float))});
}

FloatMap ReadColmapArrayMatching(const std::string& path, const FloatMap& depth, int channels) {
  if (!std::filesystem::exists(path)) return FloatMap();
  FloatMap map = ReadColmapArray(path);
  if (map.width != depth.width || map.height != depth.height || map.channels != channels) {
    throw InputError(path + ": expected " + std::to_string(depth.width) + "x" + std::to_string(depth.height) + "x" +
                     std::to_string(channels) + " like its depth map; rerun the stage that wrote it");
  }
  return map;
}

}  // namespace ibmr
