// Stage parameters: each stage declares its keys (type, default, one-line doc); the runner
// parses the YAML config against these declarations (type errors and unknown keys name the file
// and line) and hands the stage a typed `Params`. Strings become enums in the stage adapter.
#pragma once

#include <cstdint>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <variant>
#include <vector>

namespace ibmr {

enum class ParamType { kInt, kDouble, kBool, kString, kPath, kIntList, kDoubleList, kStringList };
std::string ParamTypeName(ParamType type);  // "integer", "number", "boolean", ...

struct ParamSpec {
  std::string key;
  ParamType type = ParamType::kString;
  std::string default_yaml;          // default value as YAML text ("64", "zncc", "[]", "\"\"")
  std::string doc;                   // one line: meaning, unit, valid range
  std::vector<std::string> choices;  // allowed values of a string parameter; empty: any
  bool affects_result = true;        // false for resource knobs (threads, caches): never make a stage stale
  // A string that may also be written as a flow list of scalars (import.background: [255, 255, 255]),
  // read as its text "[255, 255, 255]" for the stage to parse; other strings refuse a list.
  bool list_as_text = false;
};

using ParamValue = std::variant<int64_t, double, bool, std::string, std::vector<int64_t>,
                                std::vector<double>, std::vector<std::string>>;

// A parameter error: the key and a message fit for the user ("must be > 0, got -3").
struct ParamError {
  std::string key;
  std::string message;
  // From an Options::Check() message "key: what is wrong" (the whole message when it has no key).
  static ParamError FromCheck(const std::string& check_message);
};

class Params {
 public:
  void Set(const std::string& key, ParamValue value) { values_[key] = std::move(value); }
  bool Has(const std::string& key) const { return values_.count(key) > 0; }

  // Typed access; throws std::out_of_range naming the key when absent or of another type.
  int64_t Int(const std::string& key) const;
  double Double(const std::string& key) const;  // accepts integer values too
  bool Bool(const std::string& key) const;
  const std::string& String(const std::string& key) const;  // also kPath (already absolute)
  std::vector<int64_t> IntList(const std::string& key) const;
  std::vector<double> DoubleList(const std::string& key) const;
  std::vector<std::string> StringList(const std::string& key) const;

  // Values as JSON, in key order (for records and the cache key).
  nlohmann::json ToJson() const;
  // Only the keys whose spec affects results (the part of the cache key).
  nlohmann::json ResultJson(const std::vector<ParamSpec>& specs) const;

 private:
  const ParamValue& Get(const std::string& key) const;
  std::map<std::string, ParamValue> values_;
};

// A number as a parameter's default YAML text, without trailing zeros ("0.05", "3", "-1").
std::string DefaultNumberText(double value);

}  // namespace ibmr
