// Workspace layout: the files on disk are the interface between stages. COLMAP's names where
// COLMAP has one, so COLMAP, OpenMVS and nerfstudio tools read what the pipeline writes:
//   images/                       input images (copied or rendered), names as in images.txt
//   sparse/                       COLMAP text model (cameras.txt, images.txt, points3D.txt) of import
//   sfm/sparse/                   the model sfm estimates (its input sparse/ stays as it was)
//   masks/<image name>.png        foreground masks of training views, 0 background, 255 foreground
//   heldout/masks/<image name>.png  masks of held-out views (for scoring only)
//   dense/images/, dense/sparse/  undistorted images and model
//   dense/stereo/depth_maps/<image name>.{photometric,geometric}.bin   COLMAP arrays
//   dense/stereo/normal_maps/...  idem, 3 channels
//   dense/stereo/confidence_maps/...  idem, 1 channel in [0, 1]
//   dense/stereo/view_agreement.json  multi_depth's per-view agreement with the other views and the
//                                 flag of views that stand out (pipeline/core/view_agreement.h)
//   dense/fused.ply               fused points
//   repose/sparse/, repose/repose.json  the model with the flagged views' poses refined, and how (stages/repose)
//   ground_truth/                 synthetic truth: depth/<image name>.bin, masks/<image name>.png, mesh.ply
//   hull/, layers/, surfels/, texture/, renders/, scores/, report/   per-representation folders
//   records/<stage>.json          one record per stage run; logs/ the run logs
#pragma once

#include <filesystem>
#include <string>

namespace ibmr {

class Workspace {
 public:
  Workspace() = default;
  explicit Workspace(std::string root) : root_(std::move(root)) {}

  const std::string& root() const { return root_; }
  // Absolute path of a workspace-relative path ("sparse/cameras.txt").
  std::string Path(const std::string& relative) const { return root_ + "/" + relative; }
  // `path` relative to the root when it lies inside the workspace, else unchanged: what output
  // files record, so that a workspace's outputs do not depend on where it sits.
  // A declared input or output (workspace-relative, or absolute) as an absolute, normalised path
  // without a trailing slash: how the runner compares what stages read and write.
  std::string Resolve(const std::string& path) const {
    std::filesystem::path p(path);
    if (p.is_relative()) p = std::filesystem::path(root_) / p;
    std::string s = p.lexically_normal().string();
    while (s.size() > 1 && s.back() == '/') s.pop_back();
    return s;
  }
  std::string Relative(const std::string& path) const {
    const std::string prefix = root_ + "/";
    return path.compare(0, prefix.size(), prefix) == 0 ? path.substr(prefix.size()) : path;
  }

  // The model and images a stage reads: the last ones written before it in the config
  // (Stage::WritesModel: import's sparse/ and images/, sfm's sfm/sparse/, undistort's dense/sparse/
  // and dense/images/), set by the runner; sparse/ and images/ by default.
  std::string ImagesDir() const { return Path(images_); }
  std::string SparseDir() const { return Path(sparse_); }
  const std::string& ImagesRelative() const { return images_; }
  const std::string& SparseRelative() const { return sparse_; }
  void SetModelFolders(std::string sparse, std::string images) {
    sparse_ = std::move(sparse);
    images_ = std::move(images);
  }
  std::string MasksDir() const { return Path("masks"); }
  std::string MaskPath(const std::string& image_name) const { return Path("masks/" + image_name + ".png"); }
  std::string DepthMapPath(const std::string& image_name, const std::string& kind) const {
    return Path("dense/stereo/depth_maps/" + image_name + "." + kind + ".bin");
  }
  std::string NormalMapPath(const std::string& image_name, const std::string& kind) const {
    return Path("dense/stereo/normal_maps/" + image_name + "." + kind + ".bin");
  }
  std::string ConfidenceMapPath(const std::string& image_name, const std::string& kind) const {
    return Path(ConfidenceMapRelative(image_name, kind));
  }
  // Workspace-relative form, for stages' declared inputs and outputs.
  static std::string ConfidenceMapRelative(const std::string& image_name, const std::string& kind) {
    return "dense/stereo/confidence_maps/" + image_name + "." + kind + ".bin";
  }
  // multi_depth's per-view agreement figures and flags (pipeline/core/view_agreement.h).
  static std::string ViewAgreementRelative() { return "dense/stereo/view_agreement.json"; }
  std::string ViewAgreementPath() const { return Path(ViewAgreementRelative()); }
  std::string GroundTruthDepthPath(const std::string& image_name) const {
    return Path("ground_truth/depth/" + image_name + ".bin");
  }
  std::string GroundTruthMeshPath() const { return Path("ground_truth/mesh.ply"); }
  // Per view, how far the written camera is off the one that rendered the photo (synthetic
  // scenes): {"views": {"<name>": {"displacement_px": d}, ...}}.
  std::string GroundTruthPoseErrorPath() const { return Path("ground_truth/pose_error.json"); }
  std::string GroundTruthMaskPath(const std::string& image_name) const {
    return Path("ground_truth/masks/" + image_name + ".png");
  }
  std::string RecordsDir() const { return Path("records"); }
  std::string LogsDir() const { return Path("logs"); }

 private:
  std::string root_;
  std::string sparse_ = "sparse", images_ = "images";
};

// True when `child` is `parent` or lies inside it (both as Workspace::Resolve gives them).
inline bool PathWithin(const std::string& child, const std::string& parent) {
  return child == parent ||
         (child.size() > parent.size() && child.compare(0, parent.size(), parent) == 0 && child[parent.size()] == '/');
}

}  // namespace ibmr
