// Tile rasterizer of oriented elliptical splats, forward and backward (see splat_rasterizer.h).
#include "pipeline/core/splat_rasterizer.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <Eigen/LU>
#include <algorithm>
#include <array>
#include <cmath>

namespace ibmr {

struct SplatBackwardScratch {
  tbb::enumerable_thread_specific<std::vector<float>> buffers;
};

namespace {

constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 1e-4f;
constexpr int kTilePixels = kSplatTile * kSplatTile;
// Per-splat quantities the backward pass accumulates over a view's pixels: d/dM^-1 (9), d/d the
// projected centre (2), d/d colour (3), d/d opacity (1).
constexpr int kScreenGrads = 15;

float Sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

// Squared radius (in sigmas) beyond which exp(-r^2 / 2) < min_alpha: no opacity makes it drawn.
float Cutoff(const SplatRasterOptions& options) {
  return options.min_alpha > 0 ? 2.0f * std::log(1.0f / options.min_alpha) : 1e30f;
}

// The falloff at pixel centre (x, y) of splat `i`: the object-space value g (with u, v and the
// homogeneous w), the screen-space floor gl, and which one is used.
struct Falloff {
  float g = 0, gl = 0, u = 0, v = 0, w2 = 0;
  bool object = false;  // g is the larger (and non-zero)
  float G() const { return object ? g : gl; }
};

// `cutoff`: the squared radius (in sigmas) beyond which the falloff is below the smallest alpha drawn.
inline Falloff Evaluate(const Eigen::Matrix3f& a, const Eigen::Vector2f& centre, float inv_two_sigma2, float cutoff,
                        float x, float y) {
  Falloff f;
  const float w0 = a(0, 0) * x + a(0, 1) * y + a(0, 2);
  const float w1 = a(1, 0) * x + a(1, 1) * y + a(1, 2);
  f.w2 = a(2, 0) * x + a(2, 1) * y + a(2, 2);
  if (f.w2 > 0) {
    f.u = w0 / f.w2;
    f.v = w1 / f.w2;
    const float r2 = f.u * f.u + f.v * f.v;
    if (r2 < cutoff) f.g = std::exp(-0.5f * r2);
  }
  const float dx = x - centre.x(), dy = y - centre.y();
  const float d2 = (dx * dx + dy * dy) * inv_two_sigma2;
  if (d2 < 0.5f * cutoff) f.gl = std::exp(-d2);
  f.object = f.g > 0 && f.g >= f.gl;
  return f;
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
  Eigen::Matrix3f k = Eigen::Matrix3f::Identity();
  k(0, 0) = camera.fx;
  k(1, 1) = camera.fy;
  k(0, 2) = camera.cx;
  k(1, 2) = camera.cy;
  const Eigen::Vector3f eye = camera.Centre();
  const float cutoff = Cutoff(options);
  const float lowpass_reach = options.lowpass_sigma * std::min(std::sqrt(cutoff), options.extent_sigmas);

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
      frame->visible[i] = 1;
    }
  });

  // Binning: each visible splat into the tiles its footprint touches, front to back per tile.
  frame->tile_start.assign(tiles + 1, 0);
  frame->drawn = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!frame->visible[i]) continue;
    ++frame->drawn;
    const Eigen::Vector4i b = frame->box[i] / kSplatTile;
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
  const std::vector<float>& depth_of = frame->view_depth;
  tbb::parallel_for(0, tiles, [&](int t) {
    std::stable_sort(frame->tile_splats.begin() + frame->tile_start[t], frame->tile_splats.begin() + frame->tile_start[t + 1],
                     [&](uint32_t a, uint32_t b) { return depth_of[a] < depth_of[b]; });
  });

  frame->image.create(camera.height, camera.width, CV_32FC3);
  frame->transmittance.create(camera.height, camera.width, CV_32FC1);
  frame->depth.create(camera.height, camera.width, CV_32FC1);
  frame->last.assign(static_cast<size_t>(camera.width) * camera.height, 0);
  const float inv_two_sigma2 = 1.0f / (2.0f * options.lowpass_sigma * options.lowpass_sigma);
  tbb::parallel_for(0, tiles, [&](int t) {
    const int tx = t % frame->tiles_x, ty = t / frame->tiles_x;
    const int px0 = tx * kSplatTile, py0 = ty * kSplatTile;
    const int w = std::min(kSplatTile, camera.width - px0), hgt = std::min(kSplatTile, camera.height - py0);
    float transmit[kTilePixels], colour[kTilePixels][3], depth[kTilePixels];
    uint32_t walked[kTilePixels];
    bool done[kTilePixels];
    int remaining = 0;
    for (int p = 0; p < kTilePixels; ++p) {
      const bool inside = (p % kSplatTile) < w && (p / kSplatTile) < hgt;
      transmit[p] = 1.0f;
      colour[p][0] = colour[p][1] = colour[p][2] = 0.0f;
      depth[p] = 0.0f;
      walked[p] = 0;
      done[p] = !inside;
      remaining += inside;
    }
    const uint32_t start = frame->tile_start[t], end = frame->tile_start[t + 1];
    for (uint32_t j = start; j < end && remaining > 0; ++j) {
      const uint32_t i = frame->tile_splats[j];
      const Eigen::Matrix3f& a = frame->inverse[i];
      const Eigen::Vector2f& c = frame->centre[i];
      const float op = frame->opacity[i];
      const Eigen::Vector3f col = frame->colour[i].cwiseMax(0.0f);
      const Eigen::Vector4i& box = frame->box[i];
      const int bx0 = std::max(box[0] - px0, 0), bx1 = std::min(box[2] - px0, w - 1);
      const int by0 = std::max(box[1] - py0, 0), by1 = std::min(box[3] - py0, hgt - 1);
      for (int ly = by0; ly <= by1; ++ly) {
        for (int lx = bx0; lx <= bx1; ++lx) {
          const int p = ly * kSplatTile + lx;
          if (done[p]) continue;
          const float x = px0 + lx + 0.5f, y = py0 + ly + 0.5f;
          const Falloff f = Evaluate(a, c, inv_two_sigma2, cutoff, x, y);
          const float alpha = std::min(kMaxAlpha, op * f.G());
          if (alpha < options.min_alpha || alpha <= 0.0f) continue;
          const float next = transmit[p] * (1.0f - alpha);
          if (next < kMinTransmittance) {
            done[p] = true;
            --remaining;
            continue;
          }
          const float weight = alpha * transmit[p];
          colour[p][0] += col[0] * weight;
          colour[p][1] += col[1] * weight;
          colour[p][2] += col[2] * weight;
          if (depth[p] == 0.0f && alpha >= 0.5f) depth[p] = f.object ? 1.0f / f.w2 : frame->view_depth[i];
          transmit[p] = next;
          walked[p] = j - start + 1;
        }
      }
    }
    for (int p = 0; p < kTilePixels; ++p) {
      const int x = px0 + p % kSplatTile, y = py0 + p / kSplatTile;
      if (p % kSplatTile >= w || p / kSplatTile >= hgt) continue;
      cv::Vec3f& out = frame->image.at<cv::Vec3f>(y, x);
      for (int ch = 0; ch < 3; ++ch) out[ch] = colour[p][ch] + transmit[p] * options.background[ch];
      frame->transmittance.at<float>(y, x) = transmit[p];
      frame->depth.at<float>(y, x) = depth[p];
      frame->last[static_cast<size_t>(y) * camera.width + x] = walked[p];
    }
  });
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
  const float inv_two_sigma2 = 1.0f / (2.0f * options.lowpass_sigma * options.lowpass_sigma);
  const float inv_sigma2 = 2.0f * inv_two_sigma2;
  const float cutoff = Cutoff(options);
  if (!gradients->scratch) gradients->scratch = std::make_shared<SplatBackwardScratch>();
  auto& buffers = gradients->scratch->buffers;
  for (std::vector<float>& buffer : buffers) buffer.resize(n * kScreenGrads, 0.0f);  // new splats: zero

  tbb::parallel_for(0, tiles, [&](int t) {
    std::vector<float>& acc = buffers.local();
    acc.resize(n * kScreenGrads, 0.0f);
    const int tx = t % frame.tiles_x, ty = t / frame.tiles_x;
    const int px0 = tx * kSplatTile, py0 = ty * kSplatTile;
    const int w = std::min(kSplatTile, frame.width - px0), hgt = std::min(kSplatTile, frame.height - py0);
    float transmit[kTilePixels], behind[kTilePixels][3], d_colour[kTilePixels][3];
    uint32_t walked[kTilePixels];
    uint32_t most = 0;
    for (int p = 0; p < kTilePixels; ++p) {
      const int x = px0 + p % kSplatTile, y = py0 + p / kSplatTile;
      const bool inside = (p % kSplatTile) < w && (p / kSplatTile) < hgt;
      walked[p] = inside ? frame.last[static_cast<size_t>(y) * frame.width + x] : 0;
      most = std::max(most, walked[p]);
      transmit[p] = inside ? frame.transmittance.at<float>(y, x) : 1.0f;
      for (int c = 0; c < 3; ++c) {
        behind[p][c] = options.background[c];
        d_colour[p][c] = inside ? d_image.at<cv::Vec3f>(y, x)[c] : 0.0f;
      }
    }
    const uint32_t start = frame.tile_start[t];
    for (uint32_t jj = most; jj-- > 0;) {
      const uint32_t i = frame.tile_splats[start + jj];
      const Eigen::Matrix3f& a = frame.inverse[i];
      const Eigen::Vector2f& c = frame.centre[i];
      const float op = frame.opacity[i];
      const Eigen::Vector3f col = frame.colour[i].cwiseMax(0.0f);
      float g[kScreenGrads] = {};
      bool touched = false;
      const Eigen::Vector4i& box = frame.box[i];
      const int bx0 = std::max(box[0] - px0, 0), bx1 = std::min(box[2] - px0, w - 1);
      const int by0 = std::max(box[1] - py0, 0), by1 = std::min(box[3] - py0, hgt - 1);
      for (int ly = by0; ly <= by1; ++ly) {
       for (int lx = bx0; lx <= bx1; ++lx) {
        const int p = ly * kSplatTile + lx;
        if (jj >= walked[p]) continue;
        const float x = px0 + lx + 0.5f, y = py0 + ly + 0.5f;
        const Falloff f = Evaluate(a, c, inv_two_sigma2, cutoff, x, y);
        const float raw = op * f.G();
        const float alpha = std::min(kMaxAlpha, raw);
        if (alpha < options.min_alpha || alpha <= 0.0f) continue;
        touched = true;
        transmit[p] /= (1.0f - alpha);
        const float weight = alpha * transmit[p];
        float d_alpha = 0;
        for (int ch = 0; ch < 3; ++ch) {
          g[11 + ch] += weight * d_colour[p][ch];
          d_alpha += (col[ch] - behind[p][ch]) * d_colour[p][ch];
          behind[p][ch] = col[ch] * alpha + behind[p][ch] * (1.0f - alpha);
        }
        d_alpha *= transmit[p];
        if (raw >= kMaxAlpha) continue;  // clamped: no gradient to the opacity or the footprint
        g[14] += d_alpha * f.G();
        const float d_g = d_alpha * op;
        if (f.object) {
          const float du = -f.u * f.g * d_g, dv = -f.v * f.g * d_g;
          const float dw0 = du / f.w2, dw1 = dv / f.w2, dw2 = -(du * f.u + dv * f.v) / f.w2;
          g[0] += dw0 * x, g[1] += dw0 * y, g[2] += dw0;
          g[3] += dw1 * x, g[4] += dw1 * y, g[5] += dw1;
          g[6] += dw2 * x, g[7] += dw2 * y, g[8] += dw2;
        } else {
          const float scale = d_g * f.gl * inv_sigma2;
          g[9] += scale * (x - c.x());
          g[10] += scale * (y - c.y());
        }
       }
      }
      if (!touched) continue;
      float* out = acc.data() + static_cast<size_t>(i) * kScreenGrads;
      for (int q = 0; q < kScreenGrads; ++q) out[q] += g[q];
    }
  });

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
      for (std::vector<float>& buffer : buffers) {
        if (buffer.size() < (i + 1) * kScreenGrads) continue;
        for (int q = 0; q < kScreenGrads; ++q) {
          g[q] += buffer[i * kScreenGrads + q];
          buffer[i * kScreenGrads + q] = 0.0f;  // zero for the next call
        }
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

}  // namespace ibmr
