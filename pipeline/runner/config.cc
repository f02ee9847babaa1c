// Loading and validating the YAML run configuration (see config.h).
#include "pipeline/runner/config.h"

#include "pipeline/core/capture_shape.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <regex>
#include <sstream>

namespace fs = std::filesystem;

namespace ibmr {

namespace {

// Formats "FILE:LINE: key 'K': MESSAGE".
std::string Where(const std::string& file, int line, const std::string& key, const std::string& message) {
  std::ostringstream out;
  out << file;
  if (line > 0) out << ":" << line;
  out << ": ";
  if (!key.empty()) out << "key '" << key << "': ";
  out << message;
  return out.str();
}

int LineOf(const YAML::Node& node) { return node.Mark().line >= 0 ? node.Mark().line + 1 : 0; }

// What a node holds, for "expected X, got Y".
std::string Describe(const YAML::Node& node) {
  if (node.IsScalar()) return "'" + node.Scalar() + "'";
  if (node.IsSequence()) return "a list";
  if (node.IsMap()) return "a map";
  return "nothing";
}

std::string Suggest(const std::string& key, const std::vector<std::string>& valid) {
  int best_distance = 0;
  const std::string best = Nearest(key, valid, &best_distance);
  std::string out;
  if (!best.empty() && best_distance <= std::max<int>(2, static_cast<int>(key.size()) / 3)) {
    out = "did you mean '" + best + "'? ";
  }
  std::string list;
  for (const std::string& v : valid) list += (list.empty() ? "" : ", ") + v;
  return out + "Valid keys: " + list + ".";
}

std::string ResolvePath(const std::string& dir, const std::string& value) {
  if (value.empty()) return value;
  fs::path p(value);
  if (p.is_relative()) p = fs::path(dir) / p;
  return p.lexically_normal().string();
}

// Converts one YAML node to the declared type; on failure returns false with `error` set.
bool ToValue(const YAML::Node& node, const ParamSpec& spec, const std::string& dir, ParamValue* value,
             std::string* error) {
  const std::string expected = "expected " + ParamTypeName(spec.type);
  auto scalar_text = [&]() { return Describe(node); };
  try {
    switch (spec.type) {
      case ParamType::kInt: {
        if (!node.IsScalar()) throw YAML::Exception(YAML::Mark(), "");
        const std::string s = node.Scalar();
        size_t pos = 0;
        const long long v = std::stoll(s, &pos);
        if (pos != s.size()) throw std::invalid_argument(s);
        // Stages keep their counts in int: a larger value would wrap past their range checks.
        if (v < std::numeric_limits<int32_t>::min() || v > std::numeric_limits<int32_t>::max()) {
          *error = "expected an integer within 32 bits (no parameter needs more), got " + scalar_text();
          return false;
        }
        *value = static_cast<int64_t>(v);
        return true;
      }
      case ParamType::kDouble: {
        if (!node.IsScalar()) throw YAML::Exception(YAML::Mark(), "");
        const std::string s = node.Scalar();
        size_t pos = 0;
        const double v = std::stod(s, &pos);
        if (pos != s.size()) throw std::invalid_argument(s);
        if (!std::isfinite(v)) {  // stod reads "inf" and "nan"; no parameter means either
          *error = "expected a finite number, got " + scalar_text();
          return false;
        }
        *value = v;
        return true;
      }
      case ParamType::kBool:
        *value = node.as<bool>();
        return true;
      case ParamType::kString:
      case ParamType::kPath: {
        std::string s;
        if (spec.type == ParamType::kString && spec.list_as_text && node.IsSequence()) {
          // A free-form string given as a flow list of scalars (import.background: [255, 255, 255])
          // reads as its text, "[255, 255, 255]", for the stage to parse.
          for (const auto& item : node) {
            if (!item.IsScalar()) throw YAML::Exception(YAML::Mark(), "");
            s += (s.empty() ? "[" : ", ") + item.Scalar();
          }
          s += s.empty() ? "[]" : "]";
        } else {
          if (!node.IsScalar()) throw YAML::Exception(YAML::Mark(), "");
          s = node.Scalar();
        }
        if (!spec.choices.empty() && std::find(spec.choices.begin(), spec.choices.end(), s) == spec.choices.end()) {
          std::string list;
          for (const auto& c : spec.choices) list += (list.empty() ? "" : ", ") + c;
          *error = "'" + s + "' is not one of: " + list;
          return false;
        }
        *value = spec.type == ParamType::kPath ? ResolvePath(dir, s) : s;
        return true;
      }
      case ParamType::kIntList:
      case ParamType::kDoubleList:
      case ParamType::kStringList: {
        if (!node.IsSequence() && !node.IsNull()) throw YAML::Exception(YAML::Mark(), "");
        if (spec.type == ParamType::kIntList) {
          std::vector<int64_t> v;
          for (const auto& item : node) {
            v.push_back(item.as<int64_t>());
            if (v.back() < std::numeric_limits<int32_t>::min() || v.back() > std::numeric_limits<int32_t>::max()) {
              *error = "expected integers within 32 bits, got '" + item.Scalar() + "'";
              return false;
            }
          }
          *value = v;
        } else if (spec.type == ParamType::kDoubleList) {
          std::vector<double> v;
          for (const auto& item : node) {
            v.push_back(item.as<double>());
            if (!std::isfinite(v.back())) {
              *error = "expected finite numbers, got '" + item.Scalar() + "'";
              return false;
            }
          }
          *value = v;
        } else {
          std::vector<std::string> v;
          for (const auto& item : node) {
            if (!item.IsScalar()) throw YAML::Exception(YAML::Mark(), "");  // as<std::string>() reads null as "null"
            v.push_back(item.Scalar());
          }
          *value = v;
        }
        return true;
      }
    }
  } catch (const std::exception&) {
    *error = expected + ", got " + scalar_text();
    return false;
  }
  return false;
}

void FillDefaults(const Stage& stage, const std::string& dir, StageConfig* config) {
  config->params = DefaultParams(stage, dir);
}

void CheckStage(const Stage& stage, const std::string& file, const StageConfig& config) {
  if (auto problem = stage.CheckParams(config.params)) {
    auto it = config.key_lines.find(problem->key);
    const int line = it != config.key_lines.end() ? it->second : config.line;
    throw ConfigError(Where(file, line, config.name + "." + problem->key, problem->message));
  }
}

StageConfig ParseStage(const YAML::Node& entry, const StageRegistry& registry, const Config& config) {
  StageConfig stage_config;
  stage_config.line = LineOf(entry);
  YAML::Node params_node;
  if (entry.IsScalar()) {
    stage_config.name = entry.Scalar();
  } else if (entry.IsMap() && entry.size() == 1) {
    stage_config.name = entry.begin()->first.Scalar();  // keys are plain names (ExpandAndCheckTree)
    params_node = entry.begin()->second;
  } else {
    throw ConfigError(Where(config.path, stage_config.line, "stages",
                            "each entry is a stage name with its parameters, e.g. '- carve: {levels: 7}'"));
  }
  const Stage* stage = registry.Find(stage_config.name);
  if (!stage) {
    throw ConfigError(Where(config.path, stage_config.line, "stages",
                            "unknown stage '" + stage_config.name + "'; " + Suggest(stage_config.name, registry.Names())));
  }
  FillDefaults(*stage, config.dir, &stage_config);
  if (params_node && !params_node.IsNull()) {
    if (!params_node.IsMap()) {
      throw ConfigError(Where(config.path, LineOf(params_node), stage_config.name, "expected a map of parameters"));
    }
    const std::vector<ParamSpec> specs = stage->Parameters();
    std::vector<std::string> valid;
    for (const auto& s : specs) valid.push_back(s.key);
    for (const auto& kv : params_node) {
      const std::string key = kv.first.Scalar();
      const int line = LineOf(kv.first);
      auto spec = std::find_if(specs.begin(), specs.end(), [&](const ParamSpec& s) { return s.key == key; });
      if (spec == specs.end()) {
        throw ConfigError(Where(config.path, line, stage_config.name + "." + key,
                                "unknown parameter of stage '" + stage_config.name + "'; " + Suggest(key, valid)));
      }
      ParamValue value;
      std::string error;
      if (!ToValue(kv.second, *spec, config.dir, &value, &error)) {
        throw ConfigError(Where(config.path, LineOf(kv.second), stage_config.name + "." + key, error));
      }
      stage_config.params.Set(key, value);
      stage_config.key_lines[key] = line;
    }
  }
  CheckStage(*stage, config.path, stage_config);
  return stage_config;
}

void ParseRace(const YAML::Node& node, const std::string& path, RacePlan* race) {
  if (node.IsScalar() && (node.Scalar() == "off" || node.Scalar() == "false")) {
    race->enabled = false;
    return;
  }
  if (node.IsScalar() && (node.Scalar() == "on" || node.Scalar() == "true")) {
    race->enabled = true;
    return;
  }
  if (!node.IsMap()) {
    throw ConfigError(Where(path, LineOf(node), "plan.race",
                            "expected on, off or a map (scale, validation_every, margin_db, metric)"));
  }
  race->enabled = true;
  const std::vector<std::string> valid = {"scale", "validation_every", "margin_db", "metric"};
  for (const auto& kv : node) {
    const std::string key = kv.first.Scalar();
    const int line = LineOf(kv.first);
    try {
      if (key == "scale") {
        race->scale = kv.second.as<double>();
        if (!(race->scale > 0 && race->scale < 1)) {
          throw ConfigError(Where(path, line, "plan.race.scale", "must be in (0, 1), got " + kv.second.Scalar()));
        }
      } else if (key == "validation_every") {
        race->validation_every = kv.second.as<int>();
        if (race->validation_every < 2) {
          throw ConfigError(Where(path, line, "plan.race.validation_every", "must be >= 2, got " + kv.second.Scalar()));
        }
      } else if (key == "margin_db") {
        race->margin_db = kv.second.as<double>();
        if (!(race->margin_db >= 0)) {
          throw ConfigError(Where(path, line, "plan.race.margin_db", "must be >= 0, got " + kv.second.Scalar()));
        }
      } else if (key == "metric") {
        // PSNRs of scores/heldout.json: higher is better and margin_db is in their unit.
        const std::vector<std::string> metrics = {"photo_psnr", "filled_photo_psnr", "psnr", "filled_psnr", "mask_psnr"};
        race->metric = kv.second.IsScalar() ? kv.second.Scalar() : "";
        if (std::find(metrics.begin(), metrics.end(), race->metric) == metrics.end()) {
          throw ConfigError(Where(path, LineOf(kv.second), "plan.race.metric",
                                  "expected a held-out PSNR: photo_psnr, filled_photo_psnr, psnr, filled_psnr or mask_psnr; " +
                                      Suggest(race->metric, metrics)));
        }
      } else {
        throw ConfigError(Where(path, line, "plan.race." + key, "unknown key; " + Suggest(key, valid)));
      }
    } catch (const YAML::Exception&) {
      throw ConfigError(Where(path, LineOf(kv.second), "plan.race." + key, "expected a number"));
    }
  }
}

void ParsePlan(const YAML::Node& node, Config* config) {
  const std::string& path = config->path;
  if (!node.IsMap()) throw ConfigError(Where(path, LineOf(node), "plan", "expected a map (kind, with)"));
  config->plan.line = LineOf(node);
  const std::vector<std::string> valid = {"kind", "with", "race"};
  std::vector<std::string> stages = {"all"};
  for (const StageConfig& s : config->stages) stages.push_back(s.name);
  for (const auto& kv : node) {
    const std::string key = kv.first.Scalar();
    const int line = LineOf(kv.first);
    if (key == "kind") {
      const std::string kind = kv.second.IsScalar() ? kv.second.Scalar() : "";
      if (kind != "auto" && !IsCaptureKind(kind)) {
        throw ConfigError(Where(path, line, "plan.kind",
                                "expected auto, forward_facing, object or general, got '" + kind + "'"));
      }
      config->plan.kind = kind;
    } else if (key == "with") {
      if (!kv.second.IsSequence()) {
        throw ConfigError(Where(path, line, "plan.with", "expected a list of stage names, e.g. [volume], or [all]"));
      }
      for (const auto& item : kv.second) {
        const std::string name = item.IsScalar() ? item.Scalar() : "";
        if (std::find(stages.begin(), stages.end(), name) == stages.end()) {
          throw ConfigError(Where(path, LineOf(item), "plan.with",
                                  "'" + name + "' is not a stage of this config; " + Suggest(name, stages)));
        }
        config->plan.with.push_back(name);
      }
    } else if (key == "race") {
      ParseRace(kv.second, path, &config->plan.race);
    } else {
      throw ConfigError(Where(path, line, "plan." + key, "unknown key; " + Suggest(key, valid)));
    }
  }
}

void ParseHoldout(const YAML::Node& node, Config* config) {
  if (!node.IsMap()) throw ConfigError(Where(config->path, LineOf(node), "holdout", "expected a map (every, offset, images)"));
  const std::vector<std::string> valid = {"every", "offset", "images", "split"};
  int offset_line = LineOf(node);
  for (const auto& kv : node) {
    const std::string key = kv.first.Scalar();
    const int line = LineOf(kv.first);
    try {
      if (key == "every") {
        config->holdout.every = kv.second.as<int>();
        if (config->holdout.every < 0 || config->holdout.every == 1) {
          throw ConfigError(Where(config->path, line, "holdout.every", "must be 0 (off) or >= 2, got " + kv.second.Scalar()));
        }
      } else if (key == "offset") {
        config->holdout.offset = kv.second.as<int>();
        offset_line = line;
      } else if (key == "split") {
        if (!kv.second.IsScalar()) throw YAML::Exception(YAML::Mark(), "");
        config->holdout.split = kv.second.Scalar();
        config->holdout.split_line = line;
        if (config->holdout.split != "train" && config->holdout.split != "val" && config->holdout.split != "test") {
          throw ConfigError(Where(config->path, line, "holdout.split",
                                  "must be test or val (a split import read), got '" + config->holdout.split + "'"));
        }
      } else if (key == "images") {
        // Item by item: as<std::vector<std::string>>() reads a null item as the name "null".
        if (!kv.second.IsSequence()) throw YAML::Exception(YAML::Mark(), "");
        for (const auto& item : kv.second) {
          if (!item.IsScalar() || item.Scalar().empty()) throw YAML::Exception(YAML::Mark(), "");
          config->holdout.images.push_back(item.Scalar());
          config->holdout.image_lines.push_back(LineOf(item));
        }
      } else {
        throw ConfigError(Where(config->path, line, "holdout." + key, "unknown key; " + Suggest(key, valid)));
      }
    } catch (const YAML::Exception&) {
      throw ConfigError(Where(config->path, LineOf(kv.second), "holdout." + key,
                              key == "images"  ? "expected a list of image names"
                              : key == "split" ? "expected a split name (test or val)"
                                               : "expected integer"));
    }
  }
  if (config->holdout.every > 0 && (config->holdout.offset < 0 || config->holdout.offset >= config->holdout.every)) {
    throw ConfigError(Where(config->path, offset_line, "holdout.offset",
                            "must be in [0, every) = [0, " + std::to_string(config->holdout.every) + "), got " +
                                std::to_string(config->holdout.offset)));
  }
}

// ${VAR} or ${VAR:-default}; a default does not span lines.
const std::regex& VariablePattern() {
  static const std::regex pattern(R"(\$\{([A-Za-z_][A-Za-z0-9_]*)(:-([^}\n]*))?\})");
  return pattern;
}

// The value of ${name} (or ${name:-fallback} when `has_default`): the variable when set and not
// empty, else the default. Throws for neither: the value would read as null, and a stage fail late
// on a path ".../null".
std::string VariableValue(const std::string& name, bool has_default, const std::string& fallback,
                          const std::string& file, int line) {
  const char* env = std::getenv(name.c_str());
  if (env && *env) return env;
  if (has_default) return fallback;
  throw ConfigError(Where(file, line, "", "${" + name + "} is " + (env ? "empty" : "not set") + ": set it (" + name +
                                              "=...) or give a default as ${" + name + ":-...}"));
}

// A config's text with every ${...} replaced by a placeholder that YAML reads as plain text in
// any position (block or flow, quoted or not, key or value), and what each placeholder stands
// for. The values go in after parsing (ExpandScalar): spliced into the text, a value holding
// " #" cut a path short ('/x/photos #1' read as '/x/photos'), and one holding ": " was a syntax
// error blamed on the config. Placeholders in comments vanish with them, unchecked.
struct MaskedConfig {
  struct Reference {
    std::string name;
    bool has_default = false;
    std::string fallback;
    int line = 0;  // 1-based
  };
  std::string text;
  std::string marker;  // a placeholder is marker + index + "__"; the marker is not in the file
  std::vector<Reference> references;
};

MaskedConfig MaskVariables(const std::string& text) {
  MaskedConfig masked;
  masked.marker = "__ibmr_variable_";
  while (text.find(masked.marker) != std::string::npos) masked.marker += "_";
  size_t last = 0;
  const auto end = std::sregex_iterator();
  for (auto it = std::sregex_iterator(text.begin(), text.end(), VariablePattern()); it != end; ++it) {
    const std::smatch& m = *it;
    const size_t at = static_cast<size_t>(m.position(0));
    const int line = 1 + static_cast<int>(std::count(text.begin(), text.begin() + at, '\n'));
    masked.text += text.substr(last, at - last);
    masked.text += masked.marker + std::to_string(masked.references.size()) + "__";
    masked.references.push_back({m[1].str(), m[2].matched, m[3].str(), line});
    last = at + m.length(0);
  }
  masked.text += text.substr(last);
  return masked;
}

// `scalar` with its placeholders replaced by their values. Throws as VariableValue, with the line
// of the ${...} itself.
std::string ExpandScalar(const std::string& scalar, const MaskedConfig& masked, const std::string& file) {
  std::string out;
  size_t last = 0;
  for (size_t at = scalar.find(masked.marker); at != std::string::npos; at = scalar.find(masked.marker, last)) {
    size_t end = at + masked.marker.size();
    size_t index = 0;
    const size_t digits = end;
    while (end < scalar.size() && std::isdigit(static_cast<unsigned char>(scalar[end]))) {
      index = index * 10 + (scalar[end++] - '0');
    }
    if (end == digits || scalar.compare(end, 2, "__") != 0 || index >= masked.references.size()) {
      out += scalar.substr(last, digits - last);  // not one of ours (cannot happen: the marker is unique)
      last = digits;
      continue;
    }
    const MaskedConfig::Reference& ref = masked.references[index];
    out += scalar.substr(last, at - last) + VariableValue(ref.name, ref.has_default, ref.fallback, file, ref.line);
    last = end + 2;
  }
  return out + scalar.substr(last);
}

// Expands the variables of every scalar under `node` in place (keys too), and refuses in every map
// what the parser below cannot read: a key that is not a plain name ("? [a, b]"; as<std::string>()
// aborted on it) and a key given twice (yaml-cpp keeps both: node["k"] saw the first, a loop over
// the map kept the last). `prefix` is the dotted key of `node` with a trailing '.', as errors name
// keys; a stage's parameters are "stage.key", without "stages.". `owner` names the key holding
// `node` ("stages" for a stage entry).
void ExpandAndCheckTree(YAML::Node node, const MaskedConfig& masked, const std::string& file,
                        const std::string& prefix, const std::string& owner) {
  if (node.IsScalar()) {
    if (node.Scalar().find(masked.marker) != std::string::npos) node = ExpandScalar(node.Scalar(), masked, file);
    return;
  }
  if (node.IsSequence()) {
    for (YAML::Node item : node) ExpandAndCheckTree(item, masked, file, prefix == "stages." ? "" : prefix, owner);
    return;
  }
  if (!node.IsMap()) return;
  std::map<std::string, int> first_lines;
  for (auto kv : node) {
    YAML::Node key = kv.first;
    if (!key.IsScalar()) {
      throw ConfigError(Where(file, LineOf(key), owner,
                              "expected a plain name as key, got " + Describe(key) + " (a '? ' key is not supported)"));
    }
    ExpandAndCheckTree(key, masked, file, prefix, owner);
    const std::string name = prefix + key.Scalar();
    const auto [first, inserted] = first_lines.emplace(key.Scalar(), LineOf(key));
    if (!inserted) {
      throw ConfigError(file + ":" + std::to_string(LineOf(key)) + ": key '" + name +
                        "' appears twice (first on line " + std::to_string(first->second) + "); keep one");
    }
    ExpandAndCheckTree(kv.second, masked, file, name + ".", name);
  }
}

// Whether `value` parses as YAML to the plain value `value` (see ParseSweep).
bool RereadsAsItself(const std::string& value) {
  try {
    const YAML::Node node = YAML::Load(value);
    return node.IsScalar() && node.Scalar() == value;
  } catch (const YAML::Exception&) {
    return false;
  }
}

}  // namespace

Params DefaultParams(const Stage& stage, const std::string& dir) {
  Params params;
  for (const ParamSpec& spec : stage.Parameters()) {
    ParamValue value;
    std::string error;
    const YAML::Node node = YAML::Load(spec.default_yaml.empty() ? "\"\"" : spec.default_yaml);
    if (!ToValue(node, spec, dir, &value, &error)) {
      throw std::logic_error("stage '" + stage.Name() + "' declares a bad default for '" + spec.key + "': " + error);
    }
    params.Set(spec.key, value);
  }
  return params;
}

int EditDistance(const std::string& a, const std::string& b) {
  std::vector<int> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = static_cast<int>(j);
  for (size_t i = 1; i <= a.size(); ++i) {
    int diagonal = row[0];
    row[0] = static_cast<int>(i);
    for (size_t j = 1; j <= b.size(); ++j) {
      const int up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = up;
    }
  }
  return row[b.size()];
}

std::string Nearest(const std::string& name, const std::vector<std::string>& candidates, int* distance) {
  std::string best;
  int best_distance = 1 << 30;
  for (const std::string& candidate : candidates) {
    const int d = EditDistance(name, candidate);
    if (d < best_distance) {
      best_distance = d;
      best = candidate;
    }
  }
  if (distance != nullptr) *distance = best_distance;
  return best;
}

// The same expansion LoadConfig gives each parsed value, over a whole text.
std::string ExpandVariables(const std::string& text, const std::string& file) {
  const MaskedConfig masked = MaskVariables(text);
  return ExpandScalar(masked.text, masked, file);
}

std::set<std::string> HoldoutPolicy::Select(const std::vector<std::string>& sorted_names,
                                            const std::map<std::string, std::string>& splits) const {
  std::set<std::string> out(images.begin(), images.end());
  if (!split.empty()) {
    for (const std::string& name : sorted_names) {
      const auto it = splits.find(name);
      if (it != splits.end() && it->second == split) out.insert(name);
    }
  } else if (every > 0) {
    for (size_t i = 0; i < sorted_names.size(); ++i) {
      if (static_cast<int>(i % every) == offset) out.insert(sorted_names[i]);
    }
  }
  return out;
}

std::set<std::string> HoldoutPolicy::Scored(const std::vector<std::string>& sorted_names,
                                            const std::map<std::string, std::string>& splits) const {
  std::set<std::string> out;
  if (split.empty() || every == 0) return out;
  out.insert(images.begin(), images.end());
  int index = 0;  // within the split, in sorted name order
  for (const std::string& name : sorted_names) {
    const auto it = splits.find(name);
    if (it == splits.end() || it->second != split) continue;
    if (index++ % every == offset) out.insert(name);
  }
  return out;
}

std::string HoldoutPolicy::Describe() const {
  if (!Active()) return "none";
  std::string s;
  if (!split.empty()) {
    s = "the " + split + " split";
    if (every > 0) s += " (every " + std::to_string(every) + " of it from index " + std::to_string(offset) + " scored)";
  } else if (every > 0) {
    s = "every " + std::to_string(every) + " from index " + std::to_string(offset);
  }
  if (!images.empty()) s += (s.empty() ? "" : " and ") + std::to_string(images.size()) + " named";
  return s;
}

const StageConfig* Config::FindStage(const std::string& name) const {
  for (const auto& s : stages) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

// Throws for the first key of `map` not in `valid`, naming it (after `prefix`) with a suggestion.
static void RejectUnknownKeys(const std::string& path, const YAML::Node& map, const std::vector<std::string>& valid,
                              const std::string& prefix) {
  for (const auto& kv : map) {
    const std::string key = kv.first.Scalar();
    if (std::find(valid.begin(), valid.end(), key) == valid.end()) {
      throw ConfigError(Where(path, LineOf(kv.first), prefix + key, "unknown key; " + Suggest(key, valid)));
    }
  }
}

// The optional sweep: block (see SweepPlan). Every malformed entry names its line and key.
static void ParseSweep(const YAML::Node& node, Config* config) {
  const std::string& path = config->path;
  // A value of the wrong type names its key.
  const auto text = [&](const YAML::Node& value, const std::string& key) {
    if (!value.IsScalar()) throw ConfigError(Where(path, LineOf(value), key, "expected a plain value"));
    return value.Scalar();
  };
  if (!node.IsMap()) throw ConfigError(Where(path, LineOf(node), "sweep", "expected a map (vary, variants, metric, stability)"));
  RejectUnknownKeys(path, node, {"vary", "variants", "metric", "stability"}, "sweep.");
  if (const YAML::Node vary = node["vary"]) {
    if (!vary.IsMap()) throw ConfigError(Where(path, LineOf(vary), "sweep.vary", "expected a map of stage.key: [values]"));
    for (const auto& kv : vary) {
      const std::string key = "sweep.vary." + kv.first.Scalar();
      if (!kv.second.IsSequence() || kv.second.size() == 0) {
        throw ConfigError(Where(path, LineOf(kv.second), key, "expected a non-empty list of values"));
      }
      std::string joined;
      for (const auto& value : kv.second) {
        const std::string v = text(value, key);
        if (v.find(',') != std::string::npos) {
          throw ConfigError(Where(path, LineOf(value), key, "a value with a comma cannot be varied; list it in sweep.variants"));
        }
        // Each value reaches the variant as text parsed again (ApplyOverride), where '#' or ': '
        // would cut it short or fail: refuse here, where the line is known.
        if (!RereadsAsItself(v)) {
          throw ConfigError(Where(path, LineOf(value), key, "'" + v + "' would not read back as itself in a variant "
                                                            "(it holds YAML syntax such as ' #' or ': '); rename it"));
        }
        joined += (joined.empty() ? "" : ",") + v;
      }
      config->sweep.vary.push_back(kv.first.Scalar() + "=" + joined);
    }
  }
  if (const YAML::Node variants = node["variants"]) {
    if (!variants.IsSequence()) throw ConfigError(Where(path, LineOf(variants), "sweep.variants", "expected a list of \"stage.key=value ...\""));
    for (const auto& v : variants) config->sweep.variants.push_back(text(v, "sweep.variants"));
  }
  if (const YAML::Node metric = node["metric"]) config->sweep.metric = text(metric, "sweep.metric");
  const YAML::Node stability = node["stability"];
  if (!stability) return;
  if (!stability.IsMap()) throw ConfigError(Where(path, LineOf(stability), "sweep.stability", "expected a map (degradation, strength, methods)"));
  RejectUnknownKeys(path, stability, {"degradation", "strength", "methods", "detectors"}, "sweep.stability.");
  const auto keys = [&](const char* key) {
    const YAML::Node list = stability[key];
    const std::string where = std::string("sweep.stability.") + key;
    std::vector<std::string> out;
    if (list && list.IsScalar()) out.push_back(list.Scalar());
    if (list && list.IsSequence()) {
      for (const auto& k : list) out.push_back(text(k, where));
    }
    if (out.empty()) throw ConfigError(Where(path, LineOf(stability), where, "missing: give a stage.key (or a list)"));
    return out;
  };
  config->sweep.degradation_keys = keys("degradation");
  config->sweep.strength_keys = keys("strength");
  if (config->sweep.degradation_keys.size() != config->sweep.strength_keys.size()) {
    throw ConfigError(Where(path, LineOf(stability), "sweep.stability.strength", "give one strength key per degradation key"));
  }
  const YAML::Node methods = stability["methods"];
  if (!methods || !methods.IsSequence() || methods.size() == 0) {
    throw ConfigError(Where(path, LineOf(stability), "sweep.stability.methods", "expected a non-empty list of {name, metric, ...}"));
  }
  for (const auto& m : methods) {
    const std::string where = "sweep.stability.methods";
    if (!m.IsMap()) throw ConfigError(Where(path, LineOf(m), where, "expected {name, metric, confidence, sparsification, higher_is_better}"));
    RejectUnknownKeys(path, m, {"name", "metric", "confidence", "sparsification", "higher_is_better"}, where + ".");
    StabilityMethod method;
    for (const char* required : {"name", "metric"}) {
      if (!m[required]) throw ConfigError(Where(path, LineOf(m), where + "." + required, "missing: give a value"));
    }
    method.name = text(m["name"], where + ".name");
    method.metric = text(m["metric"], where + ".metric");
    if (m["confidence"]) method.confidence = text(m["confidence"], where + ".confidence");
    if (m["sparsification"]) method.sparsification = text(m["sparsification"], where + ".sparsification");
    if (m["higher_is_better"]) {
      const std::string b = text(m["higher_is_better"], where + ".higher_is_better");
      if (b != "true" && b != "false") {
        throw ConfigError(Where(path, LineOf(m["higher_is_better"]), where + ".higher_is_better", "expected true or false"));
      }
      method.higher_is_better = b == "true";
    }
    config->sweep.methods.push_back(method);
  }
  if (const YAML::Node detectors = stability["detectors"]) {
    const std::string where = "sweep.stability.detectors";
    if (!detectors.IsSequence()) throw ConfigError(Where(path, LineOf(detectors), where, "expected a list of {name, precision, recall, false_calls}"));
    for (const auto& d : detectors) {
      if (!d.IsMap()) throw ConfigError(Where(path, LineOf(d), where, "expected {name, precision, recall, false_calls}"));
      RejectUnknownKeys(path, d, {"name", "precision", "recall", "false_calls"}, where + ".");
      for (const char* required : {"name", "precision", "recall"}) {
        if (!d[required]) throw ConfigError(Where(path, LineOf(d), where + "." + required, "missing: give a value"));
      }
      StabilityDetector detector;
      detector.name = text(d["name"], where + ".name");
      detector.precision = text(d["precision"], where + ".precision");
      detector.recall = text(d["recall"], where + ".recall");
      if (d["false_calls"]) detector.false_calls = text(d["false_calls"], where + ".false_calls");
      config->sweep.detectors.push_back(detector);
    }
  }
}

Config LoadConfig(const std::string& path, const StageRegistry& registry) {
  Config config;
  config.path = path;
  std::ifstream in(path);
  if (!in) throw ConfigError(path + ": cannot read the config file (does it exist?)");
  std::stringstream text;
  text << in.rdbuf();
  config.dir = fs::absolute(fs::path(path)).parent_path().lexically_normal().string();

  // Variables expand in the parsed values, not in the text (see MaskVariables).
  const MaskedConfig masked = MaskVariables(text.str());
  YAML::Node root;
  try {
    root = YAML::Load(masked.text);
  } catch (const YAML::ParserException& e) {
    throw ConfigError(Where(path, e.mark.line + 1, "", "YAML syntax error: " + e.msg));
  }
  if (!root.IsMap()) throw ConfigError(Where(path, 1, "", "expected a map with keys workspace, inputs, holdout, stages"));
  ExpandAndCheckTree(root, masked, path, "", "");
  RejectUnknownKeys(path, root, {"workspace", "inputs", "holdout", "stages", "sweep", "plan"}, "");
  const std::string example = "e.g. 'workspace: ../workspaces/demo'";
  const YAML::Node workspace = root["workspace"];
  if (!workspace || workspace.IsNull()) {
    throw ConfigError(Where(path, workspace ? LineOf(workspace) : 0, "workspace",
                            "missing: give the folder where results go, " + example));
  }
  if (!workspace.IsScalar()) {
    throw ConfigError(Where(path, LineOf(workspace), "workspace", "expected a folder, got " + Describe(workspace)));
  }
  // Empty (say ${IBMR_WORKSPACE:-}), the workspace was the filesystem root: records/, images/, ...
  // would have been made at /.
  if (workspace.Scalar().empty()) {
    throw ConfigError(
        Where(path, LineOf(workspace), "workspace", "is empty: give the folder where results go, " + example));
  }
  config.workspace = ResolvePath(config.dir, workspace.Scalar());
  if (fs::path(config.workspace).relative_path().empty()) {
    throw ConfigError(Where(path, LineOf(workspace), "workspace",
                            "'" + workspace.Scalar() + "' is the filesystem root " + config.workspace +
                                ": give a folder of its own for the results, " + example));
  }
  if (const YAML::Node inputs = root["inputs"]) {
    if (!inputs.IsMap()) throw ConfigError(Where(path, LineOf(inputs), "inputs", "expected a map of name: path"));
    for (const auto& kv : inputs) {
      const std::string name = kv.first.Scalar();
      if (!kv.second.IsScalar() || kv.second.Scalar().empty()) {
        // A null value used to read as a folder named "null".
        const std::string got = kv.second.IsScalar() ? "an empty one" : Describe(kv.second);
        throw ConfigError(Where(path, LineOf(kv.first), "inputs." + name, "expected a path, got " + got));
      }
      config.inputs[name] = ResolvePath(config.dir, kv.second.Scalar());
    }
  }
  if (const YAML::Node holdout = root["holdout"]) ParseHoldout(holdout, &config);
  if (const YAML::Node sweep = root["sweep"]) ParseSweep(sweep, &config);
  const YAML::Node stages = root["stages"];
  if (!stages || !stages.IsSequence() || stages.size() == 0) {
    throw ConfigError(Where(path, stages ? LineOf(stages) : 0, "stages", "expected a non-empty list of stages"));
  }
  for (const auto& entry : stages) {
    StageConfig stage = ParseStage(entry, registry, config);
    if (config.FindStage(stage.name)) {
      throw ConfigError(Where(path, stage.line, "stages", "stage '" + stage.name + "' appears twice"));
    }
    config.stages.push_back(std::move(stage));
  }
  if (const YAML::Node plan = root["plan"]) ParsePlan(plan, &config);
  return config;
}

void ApplyWith(const std::vector<std::string>& names, Config* config) {
  std::vector<std::string> stages = {"all"};
  for (const StageConfig& s : config->stages) stages.push_back(s.name);
  for (const std::string& name : names) {
    if (std::find(stages.begin(), stages.end(), name) == stages.end()) {
      throw ConfigError("--with " + name + ": not a stage of " + config->path + "; " + Suggest(name, stages));
    }
    config->plan.with.push_back(name);
  }
}

void ApplyOverride(const std::string& assignment, const StageRegistry& registry, Config* config) {
  const size_t eq = assignment.find('=');
  const size_t dot = assignment.find('.');
  if (eq == std::string::npos || dot == std::string::npos || dot > eq) {
    throw ConfigError("--set " + assignment + ": expected stage.key=value, e.g. --set plane_sweep.num_planes=128");
  }
  const std::string stage_name = assignment.substr(0, dot);
  const std::string key = assignment.substr(dot + 1, eq - dot - 1);
  const std::string value_text = assignment.substr(eq + 1);
  StageConfig* target = nullptr;
  for (auto& s : config->stages) {
    if (s.name == stage_name) target = &s;
  }
  std::vector<std::string> names;
  for (const auto& s : config->stages) names.push_back(s.name);
  if (!target) throw ConfigError("--set " + assignment + ": stage '" + stage_name + "' is not in " + config->path + "; " + Suggest(stage_name, names));
  const Stage* stage = registry.Find(stage_name);
  const std::vector<ParamSpec> specs = stage->Parameters();
  std::vector<std::string> valid;
  for (const auto& s : specs) valid.push_back(s.key);
  auto spec = std::find_if(specs.begin(), specs.end(), [&](const ParamSpec& s) { return s.key == key; });
  if (spec == specs.end()) throw ConfigError("--set " + assignment + ": unknown parameter; " + Suggest(key, valid));
  ParamValue value;
  std::string error;
  YAML::Node node;
  try {
    node = YAML::Load(value_text);
  } catch (const YAML::Exception& e) {
    throw ConfigError("--set " + assignment + ": cannot parse the value: " + e.msg);
  }
  // Paths given on the command line are relative to the current folder.
  if (!ToValue(node, *spec, fs::current_path().string(), &value, &error)) {
    throw ConfigError("--set " + assignment + ": " + error);
  }
  target->params.Set(key, value);
  target->key_lines.erase(key);
  if (auto problem = stage->CheckParams(target->params)) {
    throw ConfigError("--set " + assignment + ": " + stage_name + "." + problem->key + ": " + problem->message);
  }
}

}  // namespace ibmr
