// Tile rasterizer of oriented elliptical splats, forward and backward (see splat_rasterizer.h).
#include "pipeline/core/splat_rasterizer.h"

#include <tbb/parallel_for.h>

#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "pipeline/core/splat_tiles.h"

namespace ibmr {

// The backward pass's sums, one per splat and tile of its box (SplatFrame::entry_start).
struct SplatBackwardScratch {
  std::vector<splat_tiles::ScreenGradientSums> entries;
};

namespace {

constexpr int kScreenGrads = splat_tiles::kScreenGradients;

float Sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

// The disc is drawn within the cut-off circle u^2 + v^2 < cutoff of its plane, which lies inside
// the extent square. The square's projected corners bound it loosely: a disc
// turned 45 degrees on screen gets a box twice the ellipse's area, and every tile and row of that
// box is walked for nothing. This intersects [x0, x1] x [y0, y1] with the exact box of the circle's
// image, a conic: with M mapping (u, v, 1) to homogeneous pixels, the circle's dual conic is
// D = M diag(R^2, R^2, -1) M^T, and the vertical lines x = t tangent to it solve
// D00 - 2 t D02 + t^2 D22 = 0 (likewise y with D11, D12). The circle lies wholly in front of the
// camera (the image an ellipse) exactly when D22 < 0, given the centre is in front; otherwise the
// box is left as it was. Nothing drawn changes: every pixel dropped lies outside the circle.
void TightenToCutoffCircle(const Eigen::Matrix3f& m_float, float cutoff, float* x0, float* x1, float* y0, float* y1) {
  const Eigen::Matrix3d m = m_float.cast<double>();
  const double r2 = cutoff;
  const Eigen::Matrix3d d = m * Eigen::Vector3d(r2, r2, -1.0).asDiagonal() * m.transpose();
  if (!(d(2, 2) < 0) || !(m(2, 2) > 0)) return;
  const double disc_x = d(0, 2) * d(0, 2) - d(0, 0) * d(2, 2), disc_y = d(1, 2) * d(1, 2) - d(1, 1) * d(2, 2);
  if (!(disc_x >= 0) || !(disc_y >= 0)) return;
  constexpr double kPad = 1e-3;  // pixels: float rounding of the box's ends
  const double sx = std::sqrt(disc_x), sy = std::sqrt(disc_y);
  // D22 < 0: the smaller root takes + sqrt.
  const double ex0 = (d(0, 2) + sx) / d(2, 2) - kPad, ex1 = (d(0, 2) - sx) / d(2, 2) + kPad;
  const double ey0 = (d(1, 2) + sy) / d(2, 2) - kPad, ey1 = (d(1, 2) - sy) / d(2, 2) + kPad;
  *x0 = std::max(*x0, static_cast<float>(ex0));
  *x1 = std::min(*x1, static_cast<float>(ex1));
  *y0 = std::max(*y0, static_cast<float>(ey0));
  *y1 = std::min(*y1, static_cast<float>(ey1));
}

}  // namespace

SplatCamera ToSplatCamera(const Camera& camera, const Rigid3d& cam_from_world) {
  SplatCamera out;
  out.width = camera.width;
  out.height = camera.height;
  out.fx = static_cast<float>(camera.FocalX());
  out.fy = static_cast<float>(camera.FocalY());
  out.cx = static_cast<float>(camera.PrincipalX());
  out.cy = static_cast<float>(camera.PrincipalY());
  out.rotation = cam_from_world.R().cast<float>();
  out.translation = cam_from_world.translation.cast<float>();
  return out;
}

void RenderSplats(const GaussianSplats& splats, const SplatCamera& camera, const SplatRasterOptions& options,
                  SplatFrame* frame) {
  const size_t n = splats.size();
  const int degree = options.sh_degree < 0 ? splats.sh_degree : std::min(options.sh_degree, splats.sh_degree);
  frame->options = options;
  frame->width = camera.width;
  frame->height = camera.height;
  frame->tiles_x = (camera.width + kSplatTile - 1) / kSplatTile;
  frame->tiles_y = (camera.height + kSplatTile - 1) / kSplatTile;
  const int tiles = frame->tiles_x * frame->tiles_y;
  frame->visible.assign(n, 0);
  frame->inverse.resize(n);
  frame->m.resize(n);
  frame->centre.resize(n);
  frame->colour.resize(n);
  frame->opacity.resize(n);
  frame->view_depth.resize(n);
  frame->box.resize(n);
  frame->tile_record.resize(n);
  Eigen::Matrix3f k = Eigen::Matrix3f::Identity();
  k(0, 0) = camera.fx;
  k(1, 1) = camera.fy;
  k(0, 2) = camera.cx;
  k(1, 2) = camera.cy;
  const Eigen::Vector3f eye = camera.Centre();
  const float cutoff = SplatCutoffSquared(options);
  const float lowpass_reach = options.lowpass_sigma * std::sqrt(cutoff);  // the floor's reach (splat_rasterizer.h)

  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
    float basis[16];
    for (size_t i = range.begin(); i != range.end(); ++i) {
      const Eigen::Vector3f mu = camera.rotation * splats.position[i] + camera.translation;
      if (!(mu.z() > options.near)) continue;
      const Eigen::Matrix3f r = camera.rotation * RotationMatrix(splats.rotation[i]);
      Eigen::Matrix3f h;
      h.col(0) = std::exp(splats.log_scale[i][0]) * r.col(0);
      h.col(1) = std::exp(splats.log_scale[i][1]) * r.col(1);
      h.col(2) = mu;
      const Eigen::Matrix3f m = k * h;
      const float det = m.determinant();
      const float size = m.col(0).norm() * m.col(1).norm() * m.col(2).norm();
      if (!(std::abs(det) > 1e-7f * size)) continue;  // seen exactly edge-on, or degenerate
      // The footprint: the 3-sigma square's corners (the projected ellipse lies inside their
      // projection while every corner is in front of the camera) and the screen-space floor.
      float x0 = 1e30f, y0 = 1e30f, x1 = -1e30f, y1 = -1e30f;
      bool behind = false;
      for (const float a : {-options.extent_sigmas, options.extent_sigmas}) {
        for (const float b : {-options.extent_sigmas, options.extent_sigmas}) {
          const Eigen::Vector3f p = m * Eigen::Vector3f(a, b, 1.0f);
          if (!(p.z() > options.near)) {
            behind = true;
            break;
          }
          x0 = std::min(x0, p.x() / p.z());
          x1 = std::max(x1, p.x() / p.z());
          y0 = std::min(y0, p.y() / p.z());
          y1 = std::max(y1, p.y() / p.z());
        }
      }
      if (behind) continue;
      TightenToCutoffCircle(m, cutoff, &x0, &x1, &y0, &y1);
      const Eigen::Vector2f centre(m(0, 2) / m(2, 2), m(1, 2) / m(2, 2));
      x0 = std::min(x0, centre.x() - lowpass_reach);
      x1 = std::max(x1, centre.x() + lowpass_reach);
      y0 = std::min(y0, centre.y() - lowpass_reach);
      y1 = std::max(y1, centre.y() + lowpass_reach);
      if (x1 < 0 || y1 < 0 || x0 >= camera.width || y0 >= camera.height) continue;
      // Pixels (c, r) whose centres (c + 0.5, r + 0.5) lie within [x0, x1] x [y0, y1].
      const float w = static_cast<float>(camera.width), hgt = static_cast<float>(camera.height);
      frame->box[i] = Eigen::Vector4i(static_cast<int>(std::floor(std::clamp(x0 - 0.5f, 0.0f, w - 1))),
                                      static_cast<int>(std::floor(std::clamp(y0 - 0.5f, 0.0f, hgt - 1))),
                                      static_cast<int>(std::ceil(std::clamp(x1 - 0.5f, 0.0f, w - 1))),
                                      static_cast<int>(std::ceil(std::clamp(y1 - 0.5f, 0.0f, hgt - 1))));
      frame->m[i] = m;
      frame->inverse[i] = m.cast<double>().inverse().cast<float>();  // double: near edge-on, M is ill-conditioned
      frame->centre[i] = centre;
      frame->view_depth[i] = mu.z();
      frame->opacity[i] = Sigmoid(splats.opacity_logit[i]);
      const Eigen::Vector3f direction = (splats.position[i] - eye).normalized();
      ShBasis(degree, direction, basis);
      const float* sh = splats.Sh(i);
      Eigen::Vector3f colour = Eigen::Vector3f::Constant(0.5f);
      for (int j = 0; j < (degree + 1) * (degree + 1); ++j) {
        for (int c = 0; c < 3; ++c) colour[c] += basis[j] * sh[j * 3 + c];
      }
      frame->colour[i] = colour;
      SplatTileRecord& record = frame->tile_record[i];
      const Eigen::Matrix3f& inverse = frame->inverse[i];
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) record.inverse[r * 3 + c] = inverse(r, c);
      }
      record.centre_x = centre.x(), record.centre_y = centre.y();
      record.opacity = frame->opacity[i];
      for (int c = 0; c < 3; ++c) record.colour[c] = std::max(colour[c], 0.0f);
      record.view_depth = mu.z();
      frame->visible[i] = 1;
    }
  });

  // Binning: each visible splat into the tiles its footprint touches, front to back per tile.
  // entry_start: each splat's run of entries, one per tile of its box (the backward pass's sums).
  frame->tile_start.assign(tiles + 1, 0);
  frame->entry_start.assign(n + 1, 0);
  frame->drawn = 0;
  for (size_t i = 0; i < n; ++i) {
    frame->entry_start[i + 1] = frame->entry_start[i];
    if (!frame->visible[i]) continue;
    ++frame->drawn;
    const Eigen::Vector4i b = frame->box[i] / kSplatTile;
    frame->entry_start[i + 1] += (b[2] - b[0] + 1) * (b[3] - b[1] + 1);
    for (int ty = b[1]; ty <= b[3]; ++ty) {
      for (int tx = b[0]; tx <= b[2]; ++tx) ++frame->tile_start[ty * frame->tiles_x + tx + 1];
    }
  }
  for (int t = 0; t < tiles; ++t) frame->tile_start[t + 1] += frame->tile_start[t];
  frame->tile_splats.resize(frame->tile_start[tiles]);
  {
    std::vector<uint32_t> fill(frame->tile_start.begin(), frame->tile_start.end() - 1);
    for (size_t i = 0; i < n; ++i) {
      if (!frame->visible[i]) continue;
      const Eigen::Vector4i b = frame->box[i] / kSplatTile;
      for (int ty = b[1]; ty <= b[3]; ++ty) {
        for (int tx = b[0]; tx <= b[2]; ++tx) frame->tile_splats[fill[ty * frame->tiles_x + tx]++] = static_cast<uint32_t>(i);
      }
    }
  }
  // Sorted by (depth, index): the depth's bits, flipped to order as the floats do, above the index
  // in one 64-bit key: the order a stable sort by depth of the index-ordered lists gives, without
  // looking the depth up at every comparison.
  const std::vector<float>& depth_of = frame->view_depth;
  tbb::parallel_for(0, tiles, [&](int t) {
    thread_local std::vector<uint64_t> keys;
    const auto begin = frame->tile_splats.begin() + frame->tile_start[t], end = frame->tile_splats.begin() + frame->tile_start[t + 1];
    keys.clear();
    for (auto it = begin; it != end; ++it) {
      uint32_t depth_bits;
      std::memcpy(&depth_bits, &depth_of[*it], sizeof depth_bits);
      depth_bits ^= (depth_bits >> 31) != 0 ? 0xffffffffu : 0x80000000u;
      keys.push_back(static_cast<uint64_t>(depth_bits) << 32 | *it);
    }
    std::sort(keys.begin(), keys.end());
    for (size_t k = 0; k < keys.size(); ++k) begin[k] = static_cast<uint32_t>(keys[k]);
  });

  frame->image.create(camera.height, camera.width, CV_32FC3);
  frame->transmittance.create(camera.height, camera.width, CV_32FC1);
  frame->depth.create(camera.height, camera.width, CV_32FC1);
  frame->last.assign(static_cast<size_t>(camera.width) * camera.height, 0);
  tbb::parallel_for(0, tiles, [&](int t) { splat_tiles::ForwardTile(*frame, t); });
}

void SplatGradients::Reset(const GaussianSplats& splats) {
  const size_t n = splats.size();
  position.assign(n, Eigen::Vector3f::Zero());
  rotation.assign(n, Eigen::Vector4f::Zero());
  log_scale.assign(n, Eigen::Vector2f::Zero());
  opacity_logit.assign(n, 0.0f);
  sh.assign(splats.sh.size(), 0.0f);
  screen.assign(n, 0.0f);
}

void BackwardSplats(const GaussianSplats& splats, const SplatCamera& camera, const SplatFrame& frame,
                    const cv::Mat& d_image, SplatGradients* gradients) {
  const size_t n = splats.size();
  const SplatRasterOptions& options = frame.options;
  const int tiles = frame.tiles_x * frame.tiles_y;
  if (!gradients->scratch) gradients->scratch = std::make_shared<SplatBackwardScratch>();
  SplatBackwardScratch& scratch = *gradients->scratch;
  // Every entry written by its tile, at the splat's own place (frame.entry_start): the sums below
  // add a splat's entries in tile order whatever thread drew each tile.
  scratch.entries.resize(frame.entry_start[n]);
  tbb::parallel_for(0, tiles, [&](int t) { splat_tiles::BackwardTile(frame, d_image, t, scratch.entries.data()); });

  // The per-splat screen quantities carried to the parameters.
  Eigen::Matrix3f k_transposed = Eigen::Matrix3f::Zero();
  k_transposed(0, 0) = camera.fx;
  k_transposed(1, 1) = camera.fy;
  k_transposed(2, 0) = camera.cx;
  k_transposed(2, 1) = camera.cy;
  k_transposed(2, 2) = 1.0f;
  const Eigen::Vector3f eye = camera.Centre();
  const int degree = options.sh_degree < 0 ? splats.sh_degree : std::min(options.sh_degree, splats.sh_degree);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1024), [&](const tbb::blocked_range<size_t>& range) {
    float basis[16];
    for (size_t i = range.begin(); i != range.end(); ++i) {
      if (!frame.visible[i]) continue;
      float g[kScreenGrads] = {};
      for (uint32_t e = frame.entry_start[i]; e < frame.entry_start[i + 1]; ++e) {
        for (int q = 0; q < kScreenGrads; ++q) g[q] += scratch.entries[e].value[q];
      }
      bool any = false;
      for (int q = 0; q < kScreenGrads; ++q) any = any || g[q] != 0.0f;
      if (!any) continue;
      // Colour -> SH coefficients (no gradient through the clamp at 0).
      ShBasis(degree, (splats.position[i] - eye).normalized(), basis);
      float* d_sh = gradients->sh.data() + i * splats.ShCount() * 3;
      for (int ch = 0; ch < 3; ++ch) {
        if (frame.colour[i][ch] < 0.0f) continue;
        for (int j = 0; j < (degree + 1) * (degree + 1); ++j) d_sh[j * 3 + ch] += basis[j] * g[11 + ch];
      }
      const float op = frame.opacity[i];
      gradients->opacity_logit[i] += g[14] * op * (1.0f - op);
      // d M^-1 -> d M; the projected centre (M02 / M22, M12 / M22) -> d M's last column.
      Eigen::Matrix3f d_inverse;
      d_inverse << g[0], g[1], g[2], g[3], g[4], g[5], g[6], g[7], g[8];
      const Eigen::Matrix3f& a = frame.inverse[i];
      const Eigen::Matrix3f& m = frame.m[i];
      Eigen::Matrix3f d_m = -a.transpose() * d_inverse * a.transpose();
      const float m22 = m(2, 2);
      d_m(0, 2) += g[9] / m22;
      d_m(1, 2) += g[10] / m22;
      d_m(2, 2) -= (g[9] * m(0, 2) + g[10] * m(1, 2)) / (m22 * m22);
      const Eigen::Matrix3f d_h = k_transposed * d_m;  // M = K H
      // H = [s_u R t_u, s_v R t_v, R mu + t] (R: cam_from_world).
      const Eigen::Vector3f d_mu_camera = d_h.col(2);
      gradients->position[i] += camera.rotation.transpose() * d_mu_camera;
      const float z = frame.view_depth[i];
      // As 3DGS measures it: the gradient of the projected centre in normalised device
      // coordinates (x in [-1, 1] across the width), which does not change with the resolution.
      gradients->screen[i] += std::hypot(d_mu_camera.x() * z / camera.fx * 0.5f * camera.width,
                                         d_mu_camera.y() * z / camera.fy * 0.5f * camera.height);
      const Eigen::Vector4f q_raw = splats.rotation[i];
      const float q_norm = q_raw.norm();
      const Eigen::Vector4f q = q_raw / q_norm;
      const Eigen::Matrix3f r_world = RotationMatrix(q_raw);
      const Eigen::Vector2f s(std::exp(splats.log_scale[i][0]), std::exp(splats.log_scale[i][1]));
      Eigen::Vector3f d_axis[2];
      for (int axis = 0; axis < 2; ++axis) {
        const Eigen::Vector3f axis_camera = camera.rotation * r_world.col(axis);
        gradients->log_scale[i][axis] += axis_camera.dot(d_h.col(axis)) * s[axis];
        d_axis[axis] = s[axis] * (camera.rotation.transpose() * d_h.col(axis));  // d loss / d world axis
      }
      // The rotation matrix's first two columns as functions of the unit quaternion (w, x, y, z).
      const float qw = q[0], qx = q[1], qy = q[2], qz = q[3];
      const Eigen::Vector3f& a0 = d_axis[0];
      const Eigen::Vector3f& a1 = d_axis[1];
      Eigen::Vector4f d_q;
      d_q[0] = a0.dot(Eigen::Vector3f(0, 2 * qz, -2 * qy)) + a1.dot(Eigen::Vector3f(-2 * qz, 0, 2 * qx));
      d_q[1] = a0.dot(Eigen::Vector3f(0, 2 * qy, 2 * qz)) + a1.dot(Eigen::Vector3f(2 * qy, -4 * qx, 2 * qw));
      d_q[2] = a0.dot(Eigen::Vector3f(-4 * qy, 2 * qx, -2 * qw)) + a1.dot(Eigen::Vector3f(2 * qx, 0, 2 * qz));
      d_q[3] = a0.dot(Eigen::Vector3f(-4 * qz, 2 * qw, 2 * qx)) + a1.dot(Eigen::Vector3f(-2 * qw, -4 * qz, 2 * qy));
      gradients->rotation[i] += (d_q - q * q.dot(d_q)) / q_norm;  // through the normalisation
    }
  });
}

namespace splat_tiles {
namespace {

// IBMR_ISA=portable (or avx2) in the environment starts the process on that build where the CPU
// runs it (the variable plane_sweep's kernels read too).
std::atomic<Isa>& Active() {
  static std::atomic<Isa> active{InitialIsa(IsaSupported)};
  return active;
}

}  // namespace

bool IsaSupported(Isa isa) {
  switch (isa) {
    case Isa::kPortable:
      return true;
#if IBMR_SPLAT_HAVE_AVX
    case Isa::kAvx2: {
      // Every feature the build's `#pragma GCC target` enables (splat_tiles.cc).
      static const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
      return avx2;
    }
    case Isa::kAvx512: {
      static const bool avx512 = IsaSupported(Isa::kAvx2) && __builtin_cpu_supports("avx512f") &&
                                 __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw") &&
                                 __builtin_cpu_supports("avx512vl");
      return avx512;
    }
#endif
    default:
      return false;
  }
}

Isa ActiveIsa() { return Active().load(); }

bool SetIsa(Isa isa) {
  if (!IsaSupported(isa)) return false;
  Active().store(isa);
  return true;
}

#if IBMR_SPLAT_HAVE_AVX
#define IBMR_SPLAT_DISPATCH(call) \
  switch (ActiveIsa()) {          \
    case Isa::kAvx512:            \
      return avx512::call;        \
    case Isa::kAvx2:              \
      return avx2::call;          \
    default:                      \
      return portable::call;      \
  }
#else
#define IBMR_SPLAT_DISPATCH(call) return portable::call
#endif

void ForwardTile(SplatFrame& frame, int tile) { IBMR_SPLAT_DISPATCH(ForwardTile(frame, tile)); }

void BackwardTile(const SplatFrame& frame, const cv::Mat& d_image, int tile, ScreenGradientSums* sums) {
  IBMR_SPLAT_DISPATCH(BackwardTile(frame, d_image, tile, sums));
}

#undef IBMR_SPLAT_DISPATCH

}  // namespace splat_tiles
}  // namespace ibmr
