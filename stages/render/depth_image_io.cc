// Loads depth images (photo, depth, confidence, normals) from dense/stereo/. See depth_image_io.h.
#include "stages/render/depth_image_io.h"

#include <tbb/parallel_for.h>

#include <cstdlib>
#include <filesystem>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/colmap_array_io.h"
#include "pipeline/core/depth_normals.h"
#include "pipeline/core/errors.h"
#include "pipeline/core/image_io.h"
#include "pipeline/core/undistorted_cameras.h"

namespace fs = std::filesystem;

namespace ibmr {

std::vector<DepthImage> LoadDepthImages(const Workspace& workspace, const SparseModel& model,
                                        const std::vector<std::string>& names, const std::string& kind) {
  std::vector<DepthImage> images(names.size());
  tbb::parallel_for(size_t{0}, names.size(), [&](size_t i) {
    const Image& image = *model.FindImage(names[i]);
    DepthImage& out = images[i];
    out.name = image.name;
    const Camera& camera = model.CameraOf(image);
    RequireUndistorted(camera, image.name, workspace.SparseDir() + "/cameras.txt", "render (splatting depth maps)");
    const bool truth = kind == "truth";
    const std::string depth_path = truth ? workspace.GroundTruthDepthPath(image.name) : workspace.DepthMapPath(image.name, kind);
    if (!fs::exists(depth_path)) {
      throw InputError(depth_path + ": no " + kind + " depth map for training view '" + image.name + "'; run " +
                       (truth ? "synth (only synthetic scenes have true depth)"
                              : kind == "geometric" ? "multi_depth" : "plane_sweep") +
                       " first, or drop the splat_depth model from render.proxies");
    }
    out.depth = ReadColmapArray(depth_path);
    if (out.depth.channels != 1 || out.depth.width <= 0) throw InputError(depth_path + ": not a 1-channel depth map");
    if (!truth) {
      out.confidence = ReadColmapArrayMatching(workspace.ConfidenceMapPath(image.name, kind), out.depth, 1);
      out.normals = ReadColmapArrayMatching(workspace.NormalMapPath(image.name, kind), out.depth, 3);
    }
    out.camera = out.depth.width == camera.width ? camera : camera.Scaled(static_cast<double>(out.depth.width) / camera.width);
    // The camera is scaled by the width ratio: a map of another aspect ratio (another image's, or
    // a crop) would put every sample at the wrong height, so its height must match too (within the
    // rounding of a downscaled size).
    if (std::abs(out.camera.height - out.depth.height) > 1) {
      throw InputError(depth_path + ": depth map is " + std::to_string(out.depth.width) + "x" +
                       std::to_string(out.depth.height) + " but the image '" + image.name + "' is " +
                       std::to_string(camera.width) + "x" + std::to_string(camera.height) + " (expected height " +
                       std::to_string(out.camera.height) + " at that width): not this image's aspect ratio; re-run " +
                       (truth ? "synth" : "plane_sweep / multi_depth") + " for the current sparse model");
    }
    out.cam_from_world = image.cam_from_world;
    if (out.normals.Empty()) out.normals = NormalsFromDepth(out.camera, out.depth);
    const std::string photo_path = workspace.ImagesDir() + "/" + image.name;
    cv::Mat photo = ReadImageColor(photo_path);
    if (photo.cols != camera.width || photo.rows != camera.height) {
      throw InputError(photo_path + ": image is " + std::to_string(photo.cols) + "x" + std::to_string(photo.rows) +
                       " but its camera says " + std::to_string(camera.width) + "x" + std::to_string(camera.height));
    }
    if (photo.cols != out.depth.width || photo.rows != out.depth.height) {
      cv::resize(photo, photo, cv::Size(out.depth.width, out.depth.height), 0, 0, cv::INTER_AREA);
    }
    out.image = photo;
  });
  return images;
}

}  // namespace ibmr
