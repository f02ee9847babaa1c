// Loads the image codecs module on first use (image_codecs.h says why) and forwards to it.
#include "pipeline/core/image_codecs.h"

#include <dlfcn.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <mutex>

#include "pipeline/core/errors.h"
#include "pipeline/core/image_codecs_abi.h"

#ifndef IBMR_IMAGE_CODECS_MODULE
#define IBMR_IMAGE_CODECS_MODULE ""
#endif

namespace ibmr {
namespace {

constexpr const char* kModuleName = "libibmr_image_codecs.so";

struct Codecs {
  std::string path;
  void (*imread)(const std::string*, int, cv::Mat*) = nullptr;
  bool (*imwrite)(const std::string*, const cv::Mat*, const std::vector<int>*) = nullptr;
  bool (*imencode)(const std::string*, const cv::Mat*, std::vector<uchar>*, const std::vector<int>*) = nullptr;
  void (*imdecode)(const std::vector<uchar>*, int, cv::Mat*) = nullptr;
};

// The places to look, in order: IBMR_IMAGE_CODECS, the build's path, beside the executable.
std::vector<std::string> Candidates() {
  std::vector<std::string> paths;
  if (const char* env = std::getenv("IBMR_IMAGE_CODECS"); env && *env) return {env};
  if (*IBMR_IMAGE_CODECS_MODULE) paths.emplace_back(IBMR_IMAGE_CODECS_MODULE);
  std::error_code ec;
  const std::filesystem::path exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) paths.push_back((exe.parent_path() / kModuleName).string());
  return paths;
}

const Codecs& Loaded() {
  static Codecs codecs;
  static std::once_flag once;
  static std::string failure;
  std::call_once(once, [] {
    std::string tried;
    for (const std::string& candidate : Candidates()) {
      // Absolute, so that dlopen opens the file checked here (a name without a slash would be
      // looked up on the library path instead).
      std::error_code ec;
      const std::string path = std::filesystem::absolute(candidate, ec).string();
      const auto note = [&tried](const std::string& what) { tried += (tried.empty() ? "" : "; ") + what; };
      if (!std::filesystem::exists(path, ec)) {
        note(path + ": " + (ec ? ec.message() : "no such file"));
        continue;
      }
      void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
      if (!handle) {
        const char* error = dlerror();
        note(error ? std::string(error) : path);
        continue;
      }
      // The module stays loaded for the process's life (never dlclose'd: OpenCV keeps state).
      const auto abi = reinterpret_cast<const char* (*)()>(dlsym(handle, "ibmr_codecs_abi"));
      codecs.imread = reinterpret_cast<decltype(codecs.imread)>(dlsym(handle, "ibmr_codecs_imread"));
      codecs.imwrite = reinterpret_cast<decltype(codecs.imwrite)>(dlsym(handle, "ibmr_codecs_imwrite"));
      codecs.imencode = reinterpret_cast<decltype(codecs.imencode)>(dlsym(handle, "ibmr_codecs_imencode"));
      codecs.imdecode = reinterpret_cast<decltype(codecs.imdecode)>(dlsym(handle, "ibmr_codecs_imdecode"));
      if (!abi || !codecs.imread || !codecs.imwrite || !codecs.imencode || !codecs.imdecode) {
        note(path + ": not ibmr's codecs module (an entry point is missing)");
        codecs = Codecs();
        dlclose(handle);
        continue;
      }
      if (std::string(abi()) != IBMR_CODECS_ABI) {
        note(path + ": built for " + abi() + ", this program for " + IBMR_CODECS_ABI + " (a module of another build)");
        codecs = Codecs();
        dlclose(handle);
        continue;
      }
      codecs.path = path;
      return;
    }
    failure = "cannot load the image codecs module " + std::string(kModuleName) + " (" +
              (tried.empty() ? "no place to look" : tried) +
              "): build it with the rest (cmake --build build, target ibmr_image_codecs), or set IBMR_IMAGE_CODECS "
              "to its path";
  });
  if (!failure.empty()) throw IoError(failure);
  return codecs;
}

}  // namespace

cv::Mat DecodeImageFile(const std::string& path, int flags) {
  cv::Mat image;
  Loaded().imread(&path, flags, &image);
  return image;
}

bool EncodeImageFile(const std::string& path, const cv::Mat& image, const std::vector<int>& params) {
  return Loaded().imwrite(&path, &image, &params);
}

bool EncodeImage(const std::string& extension, const cv::Mat& image, std::vector<uchar>* bytes,
                 const std::vector<int>& params) {
  return Loaded().imencode(&extension, &image, bytes, &params);
}

cv::Mat DecodeImage(const std::vector<uchar>& bytes, int flags) {
  cv::Mat image;
  Loaded().imdecode(&bytes, flags, &image);
  return image;
}

}  // namespace ibmr
