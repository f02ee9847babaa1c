// Reads the depth images of seed 004's model (depth_images.h) from the workspace: per training
// view its photo, its depth map of `kind` (photometric or geometric, COLMAP's .bin arrays under
// dense/stereo/; "truth": ground_truth/depth/<view>.bin of synthetic scenes), and the confidence
// and normal maps beside it when they exist. The photo is
// resampled to the depth map's resolution (area averaging) and the camera scaled with it.
#pragma once

#include <string>
#include <vector>

#include "pipeline/core/sparse_model.h"
#include "pipeline/core/workspace.h"
#include "stages/render/depth_images.h"

namespace ibmr {

// Throws InputError naming the missing depth map (and the stage to run), a depth map whose aspect
// ratio is not its image's (height off by more than 1 at the map's width), or a photo whose size
// disagrees with its camera. Views load in parallel.
std::vector<DepthImage> LoadDepthImages(const Workspace& workspace, const SparseModel& model,
                                        const std::vector<std::string>& names, const std::string& kind);

}  // namespace ibmr
