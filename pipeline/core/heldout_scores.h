// Reading scores/heldout.json (written by the score stage) for the stages and tools that rank
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

}  // namespace ibmr
