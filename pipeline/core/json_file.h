// Reading a JSON file that an earlier stage wrote (renders/renders.json, scores/heldout.json, ...),
// with errors that say which stage to run: missing -> InputError, not JSON -> IoError.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

#include "pipeline/core/atomic_file.h"
#include "pipeline/core/errors.h"

namespace ibmr {

// `path`, written by stage `producer`, read by stage `consumer`.
inline nlohmann::json ReadStageJson(const std::string& path, const std::string& producer, const std::string& consumer) {
  if (!std::filesystem::exists(path)) {
    throw InputError(path + " does not exist; run the " + producer + " stage before " + consumer);
  }
  try {
    return nlohmann::json::parse(ReadFile(path));
  } catch (const nlohmann::json::exception& e) {
    throw IoError(path + ": not valid JSON (" + e.what() + "); re-run the " + producer + " stage");
  }
}

// A JSON file read for a decision that tolerates its absence (a stage's declared outputs, the
// runner's tools), or `fallback` when it is absent or not valid JSON.
inline nlohmann::json ReadJsonOr(const std::string& path, nlohmann::json fallback) {
  if (!std::filesystem::exists(path)) return fallback;
  try {
    return nlohmann::json::parse(ReadFile(path));
  } catch (const std::exception&) {
    return fallback;
  }
}

}  // namespace ibmr
