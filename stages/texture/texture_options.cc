// TextureOptions::Check (see texture_options.h).
#include "stages/texture/texture_options.h"

#include <cmath>

namespace ibmr {

bool TextureOptions::Check(std::string* error) const {
  const auto fail = [&](const std::string& message) {
    *error = message;
    return false;
  };
  if (!(smoothness >= 0) || !std::isfinite(smoothness)) return fail("smoothness: must be a finite number >= 0, got " + std::to_string(smoothness));
  if (max_iterations < 1 || max_iterations > 1000) return fail("max_iterations: must be in [1, 1000], got " + std::to_string(max_iterations));
  if (!(visibility_epsilon > 0 && visibility_epsilon < 0.5)) return fail("visibility_epsilon: must be in (0, 0.5), got " + std::to_string(visibility_epsilon));
  if (!(min_cos_angle >= 0 && min_cos_angle < 1)) return fail("min_cos_angle: must be in [0, 1), got " + std::to_string(min_cos_angle));
  if (!(consistency_tolerance >= 0 && consistency_tolerance <= 10)) {
    return fail("consistency_tolerance: must be in [0, 10], got " + std::to_string(consistency_tolerance));
  }
  if (!(gain_sigma > 0) || !std::isfinite(gain_sigma)) return fail("gain_sigma: must be a finite number > 0, got " + std::to_string(gain_sigma));
  if (!(leveling_smoothness > 0) || !std::isfinite(leveling_smoothness)) {
    return fail("leveling_smoothness: must be a finite number > 0, got " + std::to_string(leveling_smoothness));
  }
  if (max_texture_size < 64 || max_texture_size > 32768) return fail("max_texture_size: must be in [64, 32768], got " + std::to_string(max_texture_size));
  if (padding < 0 || padding > 64) return fail("padding: must be in [0, 64], got " + std::to_string(padding));
  if (hole_cell < 3 || hole_cell > 64) return fail("hole_cell: must be in [3, 64], got " + std::to_string(hole_cell));
  if (view_map_grid < 2 || view_map_grid > 256) return fail("view_map_grid: must be in [2, 256], got " + std::to_string(view_map_grid));
  if (!(view_map_partial_penalty >= 0 && view_map_partial_penalty <= 10)) {
    return fail("view_map_partial_penalty: must be in [0, 10] (radians), got " + std::to_string(view_map_partial_penalty));
  }
  return true;
}

}  // namespace ibmr
