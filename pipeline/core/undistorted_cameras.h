// The check every stage that reads pixels through a pinhole camera makes of its cameras (plane
// sweep, texture, the renderers): the dense stages, their depth maps and everything drawn from
// them assume undistorted images, as COLMAP's dense steps do. A distorted camera there would put
// the depth maps on a grid the later stages read as the photo's own. One message for all of them,
// naming the file, the camera, the image, the stage and the fix.
#pragma once

#include <string>

#include "pipeline/core/camera.h"

namespace ibmr {

// Throws InputError when `camera` (of image `image_name`, read from `cameras_file`) has lens
// distortion: "<cameras_file>: camera <id> of image <name> (<MODEL>) has lens distortion; <stage>
// needs undistorted images: add the undistort stage before it ..., or import PINHOLE cameras".
void RequireUndistorted(const Camera& camera, const std::string& image_name, const std::string& cameras_file,
                        const std::string& stage);

}  // namespace ibmr
