// Typed access to stage parameters and their JSON form for records and cache keys.
#include "pipeline/core/params.h"

#include <stdexcept>

namespace ibmr {

std::string ParamTypeName(ParamType type) {
  switch (type) {
    case ParamType::kInt: return "integer";
    case ParamType::kDouble: return "number";
    case ParamType::kBool: return "boolean";
    case ParamType::kString: return "string";
    case ParamType::kPath: return "path";
    case ParamType::kIntList: return "list of integers";
    case ParamType::kDoubleList: return "list of numbers";
    case ParamType::kStringList: return "list of strings";
  }
  return "unknown";
}

const ParamValue& Params::Get(const std::string& key) const {
  auto it = values_.find(key);
  if (it == values_.end()) throw std::out_of_range("parameter '" + key + "' is not set");
  return it->second;
}

namespace {
template <typename T>
const T& As(const ParamValue& value, const std::string& key, const char* wanted) {
  if (const T* v = std::get_if<T>(&value)) return *v;
  throw std::out_of_range("parameter '" + key + "' is not a " + wanted);
}
}  // namespace

int64_t Params::Int(const std::string& key) const { return As<int64_t>(Get(key), key, "integer"); }

double Params::Double(const std::string& key) const {
  const ParamValue& v = Get(key);
  if (const int64_t* i = std::get_if<int64_t>(&v)) return static_cast<double>(*i);
  return As<double>(v, key, "number");
}

bool Params::Bool(const std::string& key) const { return As<bool>(Get(key), key, "boolean"); }

const std::string& Params::String(const std::string& key) const {
  return As<std::string>(Get(key), key, "string");
}

std::vector<int64_t> Params::IntList(const std::string& key) const {
  return As<std::vector<int64_t>>(Get(key), key, "list of integers");
}

std::vector<double> Params::DoubleList(const std::string& key) const {
  const ParamValue& v = Get(key);
  if (const auto* ints = std::get_if<std::vector<int64_t>>(&v)) return std::vector<double>(ints->begin(), ints->end());
  return As<std::vector<double>>(v, key, "list of numbers");
}

std::vector<std::string> Params::StringList(const std::string& key) const {
  return As<std::vector<std::string>>(Get(key), key, "list of strings");
}

nlohmann::json Params::ToJson() const {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& entry : values_) {  // not a structured binding: lambdas cannot capture those in C++17
    const std::string& key = entry.first;
    std::visit([&](const auto& v) { out[key] = v; }, entry.second);
  }
  return out;
}

nlohmann::json Params::ResultJson(const std::vector<ParamSpec>& specs) const {
  nlohmann::json all = ToJson();
  nlohmann::json out = nlohmann::json::object();
  for (const ParamSpec& spec : specs) {
    if (spec.affects_result && all.contains(spec.key)) out[spec.key] = all[spec.key];
  }
  return out;
}

ParamError ParamError::FromCheck(const std::string& check_message) {
  const size_t colon = check_message.find(':');
  if (colon == std::string::npos) return ParamError{"", check_message};
  const size_t start = check_message.find_first_not_of(' ', colon + 1);
  return ParamError{check_message.substr(0, colon), start == std::string::npos ? "" : check_message.substr(start)};
}

std::string DefaultNumberText(double value) {
  std::string s = std::to_string(value);
  s.erase(s.find_last_not_of('0') + 1);
  if (!s.empty() && s.back() == '.') s.pop_back();
  return s;
}

}  // namespace ibmr
