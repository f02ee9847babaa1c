// splits.json and background.json (see capture_info.h).
#include "pipeline/core/capture_info.h"

#include <filesystem>
#include <nlohmann/json.hpp>
#include <sstream>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

nlohmann::json ParseFile(const std::string& path) {
  try {
    return nlohmann::json::parse(ReadFile(path));
  } catch (const nlohmann::json::exception& e) {
    throw IoError(path + ": not valid JSON (" + e.what() + "); re-run the import stage");
  }
}

}  // namespace

ImageSplits ReadImageSplits(const Workspace& workspace) {
  const std::string path = workspace.Path(kSplitsFile);
  ImageSplits splits;
  if (!fs::exists(path)) return splits;
  const nlohmann::json j = ParseFile(path);
  if (!j.is_object()) throw IoError(path + ": expected a map of image names to split names; re-run the import stage");
  for (const auto& [name, split] : j.items()) {
    if (!split.is_string()) throw IoError(path + ": the split of \"" + name + "\" is not a string; re-run the import stage");
    splits[name] = split.get<std::string>();
  }
  return splits;
}

void WriteImageSplits(const Workspace& workspace, const ImageSplits& splits) {
  WriteFileAtomic(workspace.Path(kSplitsFile), nlohmann::json(splits).dump(2) + "\n");
}

std::optional<CaptureBackground> ReadCaptureBackground(const Workspace& workspace) {
  const std::string path = workspace.Path(kBackgroundFile);
  if (!fs::exists(path)) return std::nullopt;
  const nlohmann::json j = ParseFile(path);
  if (j.is_object() && j.contains("bgr") && j["bgr"].is_null()) return std::nullopt;  // the capture has none
  const auto bgr = j.is_object() ? j.find("bgr") : j.end();
  if (!j.is_object() || bgr == j.end() || !bgr->is_array() || bgr->size() != 3) {
    throw IoError(path + ": expected {\"bgr\": [b, g, r]}; re-run the import stage");
  }
  CaptureBackground background;
  for (int c = 0; c < 3; ++c) {
    const nlohmann::json& v = (*bgr)[c];
    if (!v.is_number_integer() || v.get<int>() < 0 || v.get<int>() > 255) {
      throw IoError(path + ": \"bgr\" must hold three integers in [0, 255]; re-run the import stage");
    }
    background.bgr[c] = static_cast<uint8_t>(v.get<int>());
  }
  background.source = j.value("source", "");
  return background;
}

void WriteCaptureBackground(const Workspace& workspace, const std::optional<CaptureBackground>& background) {
  const std::string path = workspace.Path(kBackgroundFile);
  if (!background) {
    WriteFileAtomic(path, "{\"bgr\": null, \"source\": \"the photos have no alpha composited on a colour\"}\n");
    return;
  }
  const cv::Vec3b& c = background->bgr;
  const nlohmann::json j = {{"bgr", {c[0], c[1], c[2]}}, {"source", background->source}};
  WriteFileAtomic(path, j.dump(2) + "\n");
}

bool ParseBackgroundColor(const std::string& text, cv::Vec3b* bgr, std::string* error) {
  if (text == "white") {
    *bgr = cv::Vec3b(255, 255, 255);
    return true;
  }
  if (text == "black") {
    *bgr = cv::Vec3b(0, 0, 0);
    return true;
  }
  std::string cleaned = text;
  for (char& ch : cleaned) {
    if (ch == '[' || ch == ']' || ch == ',') ch = ' ';
  }
  std::istringstream in(cleaned);
  int rgb[3];
  int count = 0;
  std::string word;
  while (in >> word) {
    size_t used = 0;
    int value = -1;
    try {
      value = std::stoi(word, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (count == 3 || used != word.size() || value < 0 || value > 255) {
      count = -1;
      break;
    }
    rgb[count++] = value;
  }
  if (count != 3) {
    *error = "expected white, black or [r, g, b] with integers in [0, 255], got \"" + text + "\"";
    return false;
  }
  *bgr = cv::Vec3b(static_cast<uint8_t>(rgb[2]), static_cast<uint8_t>(rgb[1]), static_cast<uint8_t>(rgb[0]));
  return true;
}

bool CaptureHasAlpha(const Workspace& workspace) {
  std::error_code ec;
  const std::string folder = workspace.Path(kAlphaFolder);
  return std::filesystem::is_directory(folder, ec) && !std::filesystem::is_empty(folder, ec);
}

}  // namespace ibmr
