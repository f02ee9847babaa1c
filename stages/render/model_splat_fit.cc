// The `splat_fit` render model: the splats the splat_fit stage fitted to the training photos
// (splat_fit/splats.ply; oriented elliptical discs, seed 000 §5 and seed 004 §5.4), drawn with the
// rasterizer the fit used (pipeline/core/splat_rasterizer.h): each disc evaluated where the pixel's
// ray meets its plane, composited front to back. Drawn at the output size (the footprints carry
// their own screen-space floor: no supersampling), over black with the transmittance left as the
// coverage, so that the stage's fill composites the capture's background where the splats leave it
// visible; or, where the fit fitted the background colour too (splat_fit/background.json "fitted"),
// over that colour, which is then part of the model: every pixel covered. The splats were fitted to every training view: a training view rendered leave-one-out
// still saw its own photo (MadeFromEveryPhoto).
#include <filesystem>

#include "pipeline/core/errors.h"
#include "pipeline/core/gaussian_splats.h"
#include "pipeline/core/json_file.h"
#include "pipeline/core/splat_rasterizer.h"
#include "stages/render/render_model.h"

namespace fs = std::filesystem;

namespace ibmr {

namespace {

class SplatFitModel : public RenderModel {
 public:
  SplatFitModel(ModelEntry entry, const Workspace& workspace)
      : RenderModel(std::move(entry)),
        path_(workspace.Path("splat_fit/splats.ply")),
        background_path_(workspace.Path("splat_fit/background.json")) {}

  std::vector<std::string> Inputs(const StageContext&) const override {
    return {"splat_fit/splats.ply", "splat_fit/background.json"};
  }
  std::string SourcePath(const Workspace& workspace) const override { return workspace.Relative(path_); }
  // At the output size: the frame's image, transmittance, depth and per-pixel counts (24 bytes), and
  // the per-splat projection (about 100 bytes a splat, counted against the pixels of a 1 Mpx view).
  double ViewBytes(const StageContext&, double pixels) const override {
    std::error_code ec;
    const double splats = static_cast<double>(fs::file_size(path_, ec)) / 248.0;  // degree 3: 62 floats a splat
    return pixels * 28.0 + (ec ? 0.0 : splats * 110.0);
  }
  bool DrawsAtOutputSize() const override { return true; }
  bool MadeFromEveryPhoto() const override { return true; }

  std::optional<std::string> Prepare(const RenderScene&, nlohmann::json* facts) override {
    if (!fs::exists(path_)) return path_ + " does not exist (run the splat_fit stage)";
    try {
      splats_ = ReadGaussianSplatsPly(path_);
    } catch (const IoError& e) {
      return std::string(e.what());
    }
    if (splats_.size() == 0) return path_ + " holds no splat";
    const nlohmann::json background = ReadJsonOr(background_path_, nlohmann::json::object());
    fitted_background_ = background.value("fitted", false);
    if (fitted_background_) {
      const nlohmann::json& rgb = background["rgb"];
      if (!rgb.is_array() || rgb.size() != 3 || !rgb[0].is_number() || !rgb[1].is_number() || !rgb[2].is_number()) {
        return background_path_ + ": \"rgb\" must be three numbers (re-run the splat_fit stage)";
      }
      for (int c = 0; c < 3; ++c) background_[c] = rgb[c].get<float>();
      (*facts)["fitted_background"] = {background_[0], background_[1], background_[2]};
    }
    (*facts)["splats"] = splats_.size();
    (*facts)["sh_degree"] = splats_.sh_degree;
    return std::nullopt;
  }

  ModelView Render(const RenderScene&, const DesiredView& view) const override {
    const SplatCamera camera = ToSplatCamera(view.camera, view.cam_from_world);
    SplatFrame frame;
    SplatRasterOptions options;
    if (fitted_background_) options.background = background_;  // else over black
    RenderSplats(splats_, camera, options, &frame);
    ModelView drawn;
    drawn.fine.image.create(camera.height, camera.width, CV_8UC3);
    drawn.fine.coverage.create(camera.height, camera.width, CV_8UC1);
    size_t covered = 0;
    for (int y = 0; y < camera.height; ++y) {
      const cv::Vec3f* rgb = frame.image.ptr<cv::Vec3f>(y);
      const float* transmittance = frame.transmittance.ptr<float>(y);
      cv::Vec3b* out = drawn.fine.image.ptr<cv::Vec3b>(y);
      uint8_t* cover = drawn.fine.coverage.ptr<uint8_t>(y);
      for (int x = 0; x < camera.width; ++x) {
        for (int c = 0; c < 3; ++c) out[x][2 - c] = cv::saturate_cast<uint8_t>(255.0f * rgb[x][c]);
        cover[x] = fitted_background_ ? uint8_t{255} : cv::saturate_cast<uint8_t>(255.0f * (1.0f - transmittance[x]));
        covered += cover[x] > 0;
      }
    }
    drawn.fine.covered_pixels = covered;
    drawn.sources = 0;
    return drawn;
  }

  nlohmann::json Size() const override {
    std::error_code ec;
    return {{"kind", "splat_fit"}, {"elements", splats_.size()}, {"bytes", fs::file_size(path_, ec)}};
  }

 private:
  std::string path_, background_path_;
  GaussianSplats splats_;
  bool fitted_background_ = false;
  Eigen::Vector3f background_ = Eigen::Vector3f::Zero();
};

}  // namespace

RenderModelKind SplatFitKind() {
  return NewRenderModelKind<SplatFitModel>("splat_fit", "the splats fitted to the photos (splat_fit/splats.ply)");
}

}  // namespace ibmr
