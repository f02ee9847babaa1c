// COLMAP's dense-workspace configuration files, written beside the project's depth maps so that
// COLMAP's own tools (patch_match_stereo, stereo_fusion --workspace_path dense) run on them:
//   dense/stereo/patch-match.cfg   per reference image two lines: its name, then its source
//                                  images (the plane sweep's neighbours), comma-separated
//   dense/stereo/fusion.cfg        the images whose depth maps are fused, one name per line
// (COLMAP's src/mvs/workspace and stereo_fusion read them; names as in images.txt).
#pragma once

#include <map>
#include <string>
#include <vector>

namespace ibmr {

constexpr const char* kPatchMatchConfig = "dense/stereo/patch-match.cfg";
constexpr const char* kFusionConfig = "dense/stereo/fusion.cfg";

// `sources`: reference image -> its source images, in order of preference.
inline std::string FormatPatchMatchConfig(const std::map<std::string, std::vector<std::string>>& sources) {
  std::string text;
  for (const auto& [reference, names] : sources) {
    text += reference + "\n";
    for (size_t i = 0; i < names.size(); ++i) text += (i ? ", " : "") + names[i];
    text += "\n";
  }
  return text;
}

inline std::string FormatFusionConfig(const std::vector<std::string>& names) {
  std::string text;
  for (const std::string& name : names) text += name + "\n";
  return text;
}

}  // namespace ibmr
