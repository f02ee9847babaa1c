// A set of oriented elliptical splats: the seed's oriented particles (seed 000 §5, lines 4454-4586:
// a position, an orientation and a size per particle) drawn as elliptical splats (seed 004, §5.4),
// each with an opacity and a view-dependent colour, as the splat fit (stages/splat_fit) adjusts
// them to re-synthesise the photos and the splat_fit render model draws them. The parametrisation
// and the file layout are those the Gaussian-splatting field uses (Kerbl et al., "3D Gaussian
// Splatting", SIGGRAPH 2023, §4 and its reference code's PLY; Huang et al., "2D Gaussian Splatting",
// SIGGRAPH 2024, §4.1 for flat discs):
//   position      the disc's centre (world)
//   rotation      unit quaternion (w, x, y, z) of the disc's frame: its x and y axes span the disc,
//                 its z axis is the normal
//   log_scale     natural logs of the two radii (standard deviations of the Gaussian falloff) along
//                 the frame's x and y axes, world units
//   opacity_logit opacity = 1 / (1 + exp(-opacity_logit))
//   sh            spherical-harmonic colour coefficients per channel, degree 0..3 (K = (d+1)^2 per
//                 channel): colour = 0.5 + sum_k Y_k(direction) sh_k, clamped at 0, direction from the
//                 camera centre to the splat; stored [splat][k][channel]
// PLY (binary little-endian, every property float; what common splat viewers read): x y z, nx ny nz
// (the normal), f_dc_0..2, f_rest_0..(3(K-1)-1) channel-major (all of red's higher coefficients,
// then green's, then blue's), opacity (the logit), scale_0 scale_1 scale_2 (logs; scale_2 the thin
// normal axis, kLogThinScale), rot_0..3 (w x y z).
#pragma once

#include <Eigen/Core>
#include <string>
#include <vector>

namespace ibmr {

inline constexpr float kShC0 = 0.28209479177387814f;  // Y_0^0
// The normal axis's log scale written to PLY: a disc, not a ball (viewers draw 3D Gaussians).
inline constexpr float kLogThinScale = -13.8155f;     // log(1e-6)

struct GaussianSplats {
  int sh_degree = 0;  // 0..3
  std::vector<Eigen::Vector3f> position;
  std::vector<Eigen::Vector4f> rotation;  // (w, x, y, z), not necessarily normalised
  std::vector<Eigen::Vector2f> log_scale;
  std::vector<float> opacity_logit;
  std::vector<float> sh;  // size() * ShCount() * 3

  size_t size() const { return position.size(); }
  int ShCount() const { return (sh_degree + 1) * (sh_degree + 1); }
  float* Sh(size_t i) { return sh.data() + i * ShCount() * 3; }
  const float* Sh(size_t i) const { return sh.data() + i * ShCount() * 3; }
  // Appends one splat (its SH coefficients zero except the DC term from `rgb`, in [0, 1]).
  void Add(const Eigen::Vector3f& centre, const Eigen::Vector4f& rotation_wxyz, const Eigen::Vector2f& log_radii,
           float opacity, const Eigen::Vector3f& rgb);
  // Empty when consistent; otherwise what is wrong (sizes, a non-finite value).
  std::string Validate() const;
};

// The rotation (w, x, y, z) of a frame whose z axis is `normal` (unit), x and y any orthonormal pair.
Eigen::Vector4f RotationWithNormal(const Eigen::Vector3f& normal);
// The unit quaternion's rotation matrix (columns: the disc's x axis, y axis, normal).
Eigen::Matrix3f RotationMatrix(const Eigen::Vector4f& wxyz);

// The K = (degree+1)^2 real SH basis values at unit `d` (the 3D Gaussian splatting code's order
// and constants).
void ShBasis(int degree, const Eigen::Vector3f& d, float* out);

// Writes / reads the PLY layout above. Writes are atomic. Reading accepts any f_rest count of a
// whole degree (0, 9, 24 or 45) and ignores unknown float properties; throws IoError naming the file
// and the property that is missing or malformed.
void WriteGaussianSplatsPly(const std::string& path, const GaussianSplats& splats, const std::string& comment = "");
GaussianSplats ReadGaussianSplatsPly(const std::string& path);

}  // namespace ibmr
