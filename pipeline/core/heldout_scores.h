// Reading scores/heldout.json (written by the score stage) and renders/renders.json (render) for the stages and tools that rank
// models by it (select, ibmr sweep, ibmr report).
#pragma once

#include <nlohmann/json.hpp>

namespace ibmr {

// A model's held-out means as they should be compared: over the views that are not near a
// training camera ("mean_excluding_near": a view that coincides with a training view is
// reproduced by any model that is epipole-consistent, and says nothing about prediction), or
// over every view when all of them are near one. An empty object when the model has no means.
inline nlohmann::json HeldoutMeans(const nlohmann::json& proxy) {
  if (proxy.contains("mean_excluding_near") && proxy["mean_excluding_near"].value("views", 0) > 0) {
    return proxy["mean_excluding_near"];
  }
  return proxy.value("mean", nlohmann::json::object());
}

// Each rendered model's size as renders/renders.json reports it ({"<name>": {"kind", "elements",
// "bytes", ...}}); models without one are left out.
inline nlohmann::json ModelSizes(const nlohmann::json& renders) {
  nlohmann::json sizes = nlohmann::json::object();
  if (!renders.is_object() || !renders.contains("proxies") || !renders["proxies"].is_array()) return sizes;
  for (const auto& proxy : renders["proxies"]) {
    if (proxy.is_object() && proxy.contains("name") && proxy["name"].is_string() && proxy.contains("model")) {
      sizes[proxy["name"].get<std::string>()] = proxy["model"];
    }
  }
  return sizes;
}

}  // namespace ibmr
