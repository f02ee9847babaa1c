// The import stage: brings a capture into the workspace as a COLMAP text model (sparse/) and
// an image folder (images/). Sources:
//   folder      plain images; one camera per image size, focal length from EXIF when present
//               (35 mm equivalent, or focal length and focal-plane resolution), else
//               focal_prior * max(width, height) (COLMAP's default prior is 1.2). No poses: images.txt
//               is empty and image_list.txt names the images for structure from motion.
//   middlebury  a Middlebury multi-view folder with <name>_par.txt ("name k11..k33 r11..r33 t1..t3",
//               projection K [R t], pixel centre at (0,0)).
//   strecha     a Strecha folder: images/ and gt_dense_cameras/<image>.camera (K, distortion, R
//               camera-to-world, centre C, "w h"; projection K [R^T | -R^T C], pixel centre (0,0)).
//   colmap      a COLMAP text model folder (cameras.txt, images.txt, points3D.txt) and an image folder.
//   transforms  NeRF's Blender layout (transforms_{train,val,test}.json) or nerfstudio's
//               transforms.json, with their splits (transforms_splits.h).
//   llff        poses_bounds.npy beside images/ (nerf_formats.h).
// Photos with an alpha channel are composited over a background colour, their alpha kept in
// alpha/<name>.png (import.alpha; alpha_composite.h).
// Pixel convention: COLMAP puts the top-left pixel centre at (0.5, 0.5), Middlebury and Strecha
// at (0, 0); their principal points get +0.5 here (BRIEF.md, "Conventions that bite").
#pragma once

#include <functional>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "pipeline/core/sparse_model.h"

namespace ibmr {

enum class ImportFormat { kAuto, kFolder, kMiddlebury, kStrecha, kColmap, kTransforms, kLlff };

// What becomes of a photo's alpha channel (alpha_composite.h): composited over `background` with
// the alpha kept in alpha/ (the silhouettes' source), kept in alpha/ only (colour as stored), or
// dropped.
enum class AlphaMode { kComposite, kMask, kIgnore };

struct ImportOptions {
  ImportFormat format = ImportFormat::kAuto;
  AlphaMode alpha = AlphaMode::kComposite;
  cv::Vec3b background{255, 255, 255};  // BGR; white as NeRF composites its Blender captures
  bool alpha_premultiplied = false;     // PNG's alpha is straight (not premultiplied)
  // Focal length prior for images without EXIF, as a multiple of max(width, height); > 0.
  double focal_prior = 1.2;
  // Camera model for a plain folder (COLMAP name); SIMPLE_RADIAL as COLMAP's default.
  std::string folder_camera_model = "SIMPLE_RADIAL";
  bool Check(std::string* error) const;  // error starts with the offending key
};

// Parses a Middlebury _par.txt. `images` gives each image's size (by name) for cameras.txt;
// `path` is only used in error messages ("file:line: ...").
SparseModel ParseMiddleburyPar(const std::string& text, const std::string& path,
                               const std::function<std::pair<int, int>(const std::string&)>& image_size);

// Parses one Strecha .camera file into a camera (PINHOLE, +0.5 principal point) and pose.
void ParseStrechaCamera(const std::string& text, const std::string& path, Camera* camera, Rigid3d* cam_from_world);

// A camera for an image without pose: focal from `exif_focal_pixels` when > 0, else the prior.
Camera FolderCamera(int width, int height, double exif_focal_pixels, const ImportOptions& options);

// Focal length in pixels from the image's EXIF (0 when absent or unusable).
double ExifFocalPixels(const std::string& image_path, int width, int height);
// The EXIF orientation tag (1-8; 1, "as stored", when absent or unreadable).
int ExifOrientation(const std::string& image_path);

// Detects the source format of a folder ("middlebury" when a *_par.txt is present, ...).
ImportFormat DetectFormat(const std::string& folder);

}  // namespace ibmr
