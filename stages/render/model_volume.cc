// The `volume` render model: the volume stage's RGBA plane volumes (volume/<reference>/; a
// multiplane image; seed 000 lines 5526-5610, pipeline/core/plane_volume.h). Each plane is
// re-projected into the desired view by its homography and the planes are composited with the
// over operator (plane by plane with OpenCV's warps where every ray meets every plane ahead, as in
// a forward-facing capture; else ray by ray, plane_volume.h); the farthest plane is opaque, so a pixel whose
// ray reaches it inside the volume's image is covered. Several local volumes (the volume stage's
// `references`): the render.volume_blend nearest to the desired camera's centre are blended by
// the inverse square of that distance, where each covers the pixel. The volumes are fitted to every training photo:
// a training view cannot be left out of them (exclude_self warns).
#include <algorithm>
#include <filesystem>
#include <opencv2/core.hpp>

#include "pipeline/core/errors.h"
#include "pipeline/core/plane_volume.h"
#include "stages/render/render_model.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

class VolumeModel : public RenderModel {
 public:
  VolumeModel(ModelEntry entry, const Workspace& workspace)
      : RenderModel(std::move(entry)), folder_(workspace.Path("volume")) {}

  std::vector<std::string> Inputs(const StageContext&) const override { return {"volume"}; }
  std::string SourcePath(const Workspace& workspace) const override { return workspace.Relative(folder_); }
  bool MadeFromEveryPhoto() const override { return true; }

  // At the output size: a float colour, a coverage byte and a warped plane (17 bytes), the blend's
  // sums (16) when several volumes are blended, and the drawn image (4); the volumes are loaded once
  // (Prepare). Asked before Prepare: the volume folders are counted on disk.
  double ViewBytes(const StageContext& context, double pixels) const override {
    const size_t blended = std::min<size_t>(VolumeFolders().size(), static_cast<size_t>(context.params.Int("volume_blend")));
    return pixels * (17.0 + 4.0 + (blended > 1 ? 16.0 : 0.0));
  }

  std::optional<std::string> Prepare(const RenderScene& scene, nlohmann::json* facts) override {
    blend_ = static_cast<size_t>(scene.context->params.Int("volume_blend"));
    const std::vector<std::string> folders = VolumeFolders();
    if (folders.empty()) return folder_ + " holds no volume (run the volume stage)";
    try {
      for (const std::string& folder : folders) {
        volumes_.push_back(ReadPlaneVolume(folder));
        plane_images_.push_back(PlaneImages(volumes_.back()));
      }
    } catch (const InputError& e) {
      return std::string(e.what());
    } catch (const IoError& e) {
      return std::string(e.what());
    }
    nlohmann::json names = nlohmann::json::array();
    for (const std::string& folder : folders) names.push_back(fs::path(folder).filename().string());
    (*facts)["volumes"] = names;
    return std::nullopt;
  }

  // The planes are read bilinearly: a sample per output pixel is already a filtered one, and
  // render.supersample's sub-samples would cost their square in time for no gain (the
  // forward-facing scene at 1008x756: 37.85 dB held out drawn at supersample 2 and 1023 ms a frame,
  // 37.86 dB and 250 ms at the output size).
  bool DrawsAtOutputSize() const override { return true; }

  ModelView Render(const RenderScene&, const DesiredView& view) const override {
    const Camera& camera = view.camera;
    const Eigen::Vector3d centre = view.cam_from_world.Inverse().translation;
    // The volume_blend volumes nearest the desired camera.
    std::vector<std::pair<double, size_t>> nearest;
    for (size_t i = 0; i < volumes_.size(); ++i) {
      nearest.emplace_back((volumes_[i].cam_from_world.Inverse().translation - centre).norm(), i);
    }
    std::sort(nearest.begin(), nearest.end());
    nearest.resize(std::min<size_t>(nearest.size(), blend_));
    ModelView drawn;
    drawn.fine.image = cv::Mat(camera.height, camera.width, CV_8UC3, cv::Scalar::all(0));
    drawn.fine.coverage = cv::Mat(camera.height, camera.width, CV_8UC1, cv::Scalar(0));
    drawn.sources = nearest.size();
    cv::Mat colour, coverage;
    if (nearest.size() == 1) {  // one volume: its render as it is
      Composite(nearest[0].second, view, &colour, &coverage);
      for (int y = 0; y < camera.height; ++y) {
        const cv::Vec3f* c = colour.ptr<cv::Vec3f>(y);
        const uint8_t* cover = coverage.ptr<uint8_t>(y);
        cv::Vec3b* out = drawn.fine.image.ptr<cv::Vec3b>(y);
        for (int x = 0; x < camera.width; ++x) {
          if (!cover[x]) continue;
          for (int ch = 0; ch < 3; ++ch) out[x][ch] = cv::saturate_cast<uint8_t>(255.f * c[x][ch]);
          ++drawn.fine.covered_pixels;
        }
      }
      drawn.fine.coverage = coverage;
      return drawn;
    }
    cv::Mat sum(camera.height, camera.width, CV_32FC3, cv::Scalar::all(0));
    cv::Mat weight(camera.height, camera.width, CV_32F, cv::Scalar(0));
    for (const auto& [distance_to_volume, i] : nearest) {
      Composite(i, view, &colour, &coverage);
      const float w = static_cast<float>(1.0 / std::max(distance_to_volume * distance_to_volume, 1e-12));
      for (int y = 0; y < camera.height; ++y) {
        const uint8_t* cover = coverage.ptr<uint8_t>(y);
        const cv::Vec3f* c = colour.ptr<cv::Vec3f>(y);
        cv::Vec3f* s = sum.ptr<cv::Vec3f>(y);
        float* ws = weight.ptr<float>(y);
        for (int x = 0; x < camera.width; ++x) {
          if (!cover[x]) continue;
          s[x] += w * c[x];
          ws[x] += w;
        }
      }
    }
    for (int y = 0; y < camera.height; ++y) {
      const cv::Vec3f* s = sum.ptr<cv::Vec3f>(y);
      const float* ws = weight.ptr<float>(y);
      cv::Vec3b* out = drawn.fine.image.ptr<cv::Vec3b>(y);
      uint8_t* cover = drawn.fine.coverage.ptr<uint8_t>(y);
      for (int x = 0; x < camera.width; ++x) {
        if (!(ws[x] > 0)) continue;
        for (int ch = 0; ch < 3; ++ch) out[x][ch] = cv::saturate_cast<uint8_t>(255.f * s[x][ch] / ws[x]);
        cover[x] = 255;
        ++drawn.fine.covered_pixels;
      }
    }
    return drawn;
  }

  // The cells (planes x pixels) and the bytes of the plane files.
  nlohmann::json Size() const override {
    uintmax_t bytes = 0;
    double cells = 0;
    std::error_code ec;
    for (const auto& entry : fs::recursive_directory_iterator(folder_, ec)) {
      if (entry.is_regular_file() && entry.path().filename().string().rfind("plane_", 0) == 0) bytes += entry.file_size();
    }
    int planes = 0;
    for (const PlaneVolume& volume : volumes_) {
      cells += static_cast<double>(volume.Width()) * volume.Height() * volume.Planes();
      planes += volume.Planes();
    }
    return {{"kind", "volume"}, {"elements", cells}, {"planes", planes}, {"volumes", volumes_.size()}, {"bytes", bytes}};
  }

 private:
  // The volume stage's folders under folder_ (each with a volume.json), sorted.
  std::vector<std::string> VolumeFolders() const {
    std::vector<std::string> folders;
    std::error_code ec;
    for (fs::directory_iterator it(folder_, ec), end; !ec && it != end; it.increment(ec)) {
      if (fs::exists(it->path() / "volume.json")) folders.push_back(it->path().string());
    }
    std::sort(folders.begin(), folders.end());
    return folders;
  }
  // Volume i drawn into the view: plane by plane (warps) where every ray meets every plane ahead,
  // else ray by ray.
  void Composite(size_t i, const DesiredView& view, cv::Mat* colour, cv::Mat* coverage) const {
    if (!CompositePlaneVolumeByWarps(volumes_[i], plane_images_[i], view.camera, view.cam_from_world, colour, coverage)) {
      CompositePlaneVolume(volumes_[i], view.camera, view.cam_from_world, colour, coverage);
    }
  }

  std::string folder_;
  std::vector<PlaneVolume> volumes_;
  std::vector<std::vector<cv::Mat>> plane_images_;  // each volume's planes, 8-bit, for the warps
  size_t blend_ = 2;
};

std::optional<ParamError> CheckVolumeParams(const Params& params) {
  if (params.Int("volume_blend") < 1 || params.Int("volume_blend") > 64) {
    return ParamError{"volume_blend", "must be in [1, 64], got " + std::to_string(params.Int("volume_blend"))};
  }
  return std::nullopt;
}

}  // namespace

RenderModelKind VolumeKind() {
  RenderModelKind kind = NewRenderModelKind<VolumeModel>(
      "volume", "the volume stage's RGBA plane volumes (volume/<reference>/, multiplane images): each plane warped "
                "into the view and composited over the ones behind; the volume_blend nearest local volumes blended by "
                "1/distance^2");
  kind.params = {{"volume_blend", ParamType::kInt, "2",
                  "volume: local volumes blended per desired view (the nearest camera centres), in [1, 64]", {}}};
  kind.check_params = CheckVolumeParams;
  return kind;
}

}  // namespace ibmr
