// The registry of two-view stereo methods (two_view_methods.h).
#include "pipeline/core/two_view_methods.h"

#include <mutex>

namespace ibmr {

namespace {

struct Registry {
  std::mutex mutex;
  std::map<std::string, TwoViewMethod> methods;
};

Registry& TheRegistry() {
  static Registry registry;
  return registry;
}

}  // namespace

void RegisterTwoViewMethod(const std::string& name, TwoViewMethod method) {
  Registry& registry = TheRegistry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  registry.methods[name] = std::move(method);
}

TwoViewMethod FindTwoViewMethod(const std::string& name) {
  Registry& registry = TheRegistry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  const auto it = registry.methods.find(name);
  return it == registry.methods.end() ? TwoViewMethod() : it->second;
}

std::vector<std::string> TwoViewMethodNames() {
  Registry& registry = TheRegistry();
  std::lock_guard<std::mutex> lock(registry.mutex);
  std::vector<std::string> names;
  for (const auto& [name, method] : registry.methods) names.push_back(name);
  return names;
}

}  // namespace ibmr
