// Held-out-view cross-validation: Szeliski's prediction error (seed 000, BMVC'99 section 6,
// lines 5906-5920): views held back from every reconstruction stage are rendered from the model
// and compared with the real photographs. Metrics per view (RENDERERS.md "Scoring held-out views"):
//  * PSNR over covered pixels (MSE over the three 8-bit channels, peak 255; capped at 100 dB when
//    the render is exact);
//  * SSIM (Wang et al. 2004: Gaussian window sigma 1.5, C1 = (0.01*255)^2, C2 = (0.03*255)^2, per
//    channel, averaged) over covered pixels whose whole window is covered (the coverage eroded by
//    the window radius; all covered pixels when that leaves none);
//  * coverage: covered fraction of the image, and of the mask where a mask exists;
//  * the same PSNR / SSIM inside the mask (covered and foreground);
//  * "photo" PSNR / SSIM over the pixels where the real photo is lit (its largest channel above
//    `photo_threshold`), uncovered pixels counted as black: a model that leaves holes on the
//    object pays for them, where the covered-pixel PSNR would not see them;
//  * optional per-image, per-channel gain correction (lighting can differ between photos): the
//    least-squares gain g_c = sum(real*render) / sum(render^2) over covered pixels is applied to the
//    render before the metrics.
// The angle to the nearest training camera (seen from the scene centre) is computed here too: a
// near-zero angle makes a held-out view trivially easy (epipole consistency), reported apart.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace ibmr {

struct ScoreOptions {
  bool gain_correction = false;   // per-image, per-channel least-squares gain on the render
  double near_angle_deg = 1.0;    // views closer than this to a training camera are "near", in [0, 180)
  int error_gain = 4;             // error panel of side-by-side images shows |real - render| * this, in [1, 64]
  int photo_threshold = 20;       // "photo" pixels: the real photo's largest channel above this, in [-1, 255]
                                  // (-1: every pixel)

  bool Check(std::string* error) const;  // error starts with the YAML key
};

struct MaskedScore {
  double psnr = 0;          // dB over the pixels counted (covered [and in mask]); 0 when pixels == 0,
                            // which is no score: the stage omits psnr and ssim then
  double ssim = 0;
  double coverage = 0;      // covered fraction of the image (or of the mask)
  size_t pixels = 0;        // pixels counted
};

struct ImageScore {
  MaskedScore all;          // over covered pixels
  bool has_mask = false;
  MaskedScore mask;         // covered and foreground
  MaskedScore photo;        // lit pixels of the real photo, uncovered ones rendered black; coverage:
                            // covered fraction of the lit pixels
  double gains[3] = {1, 1, 1};  // B, G, R gains applied (1 without gain correction)
};

// Working images of the SSIM computation (up to ten floats a pixel), reused from one ScoreImage call to
// the next when the caller keeps them: a fresh full-size image costs its page faults at first
// touch, most of the scoring time on photo-sized renders.
struct SsimBuffers {
  cv::Mat a, b, aa, bb, ab, mu_a, mu_b, blur_aa, blur_bb, blur_ab;  // blur_*: the products' Gaussian means
};

// The real photo's share of the SSIM statistics: per channel, the Gaussian means of its values and
// of their squares. Every model's render of a held-out view is scored against the same photo, so
// two of the five blurs of each channel are the same each time: computed once per photo and
// passed to ScoreImage they are reused as they are (the scores are identical to the bit).
struct SsimReference {
  cv::Mat mean[3], mean_square[3];  // CV_32F per channel of the photo, of its values less 128
  int channels = 0;
  bool Matches(const cv::Mat& real) const { return channels == real.channels() && mean[0].size() == real.size(); }
};
// `real`: CV_8UC3 (ScoreImage's photo); throws std::invalid_argument for another type.
SsimReference PrepareSsimReference(const cv::Mat& real);

// `real`, `rendered`: CV_8UC3 of one size; `coverage`: CV_8UC1, nonzero where covered; `mask`:
// CV_8UC1 (nonzero = foreground) or empty. Throws std::invalid_argument on size mismatch.
// `buffers`: optional, see SsimBuffers (one set per thread). `reference`: optional,
// PrepareSsimReference(real) (std::invalid_argument when it was made from another size).
ImageScore ScoreImage(const cv::Mat& real, const cv::Mat& rendered, const cv::Mat& coverage, const cv::Mat& mask,
                      const ScoreOptions& options, SsimBuffers* buffers = nullptr,
                      const SsimReference* reference = nullptr);

// real | rendered | |real - rendered| * error_gain (uncovered pixels of the error panel dark blue).
cv::Mat SideBySide(const cv::Mat& real, const cv::Mat& rendered, const cv::Mat& coverage, int error_gain);

// Mean of the finite points (one NaN or infinite coordinate would make the mean NaN; such points
// are skipped). False, `mean` unchanged, when there is none.
bool MeanOfFinitePoints(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d* mean);

// Angle in degrees at `scene_center` between `center` and the nearest of `others`; sets `nearest`
// (index into others, -1 when empty; angle 180 then).
double NearestCameraAngleDeg(const Eigen::Vector3d& center, const std::vector<Eigen::Vector3d>& others,
                             const Eigen::Vector3d& scene_center, int* nearest);

}  // namespace ibmr
