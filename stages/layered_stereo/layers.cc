// Steps 3-5 of layers.h: pixel assignment, sprites with residual depth, and the layer count chosen
// by held-out prediction (seed 000 lines 5625-5811, 5906-5950).
#include "stages/layered_stereo/layers.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <opencv2/imgproc.hpp>

namespace ibmr {

bool LayeredOptions::Check(std::string* error) const {
  auto fail = [&](const std::string& key, const std::string& range) {
    if (error) *error = key + ": must be in " + range;
    return false;
  };
  if (max_layers < 1 || max_layers > 16) return fail("max_layers", "[1, 16]");
  if (!(plane_tolerance > 0 && plane_tolerance <= 0.2)) return fail("plane_tolerance", "(0, 0.2]");
  if (!(min_layer_fraction > 0 && min_layer_fraction < 1)) return fail("min_layer_fraction", "(0, 1)");
  if (ransac_iterations < 10 || ransac_iterations > 100000) return fail("ransac_iterations", "[10, 100000]");
  if (sample_step < 1 || sample_step > 16) return fail("sample_step", "[1, 16]");
  if (edge_margin_px < 0 || edge_margin_px > 64) return fail("edge_margin_px", "[0, 64]");
  if (residual_steps != 0 && (residual_steps < 3 || residual_steps > 129 || residual_steps % 2 == 0)) {
    return fail("residual_steps", "0 or odd in [3, 129]");
  }
  if (!(max_residual >= 0 && max_residual <= 0.5)) return fail("max_residual", "[0, 0.5]");
  if (!(depth_weight >= 0 && depth_weight <= 1e6)) return fail("depth_weight", "[0, 1e6]");
  if (!(smoothness >= 0 && smoothness <= 1e6)) return fail("smoothness", "[0, 1e6]");
  if (icm_sweeps < 0 || icm_sweeps > 100) return fail("icm_sweeps", "[0, 100]");
  if (!(max_cost > 0 && max_cost <= 1e6)) return fail("max_cost", "(0, 1e6]");
  if (extend_px < 0 || extend_px > 256) return fail("extend_px", "[0, 256]");
  if (!(count_tolerance >= 0 && count_tolerance <= 1)) return fail("count_tolerance", "[0, 1]");
  if (choose_count != 0 && choose_count != 1) return fail("choose_count", "{0, 1}");
  if (!(selection_scale > 0 && selection_scale <= 1)) return fail("selection_scale", "(0, 1]");
  if (photometric_refinement != 0 && photometric_refinement != 1) return fail("photometric_refinement", "{0, 1}");
  return true;
}

namespace {

// The plane in the reference camera's frame: n_c . X_c = d_c.
void PlaneInCamera(const WorldPlane& plane, const Rigid3d& cam_from_world, Eigen::Vector3d* n_c, double* d_c) {
  const Eigen::Matrix3d r = cam_from_world.R();
  const Eigen::Vector3d centre = -(r.transpose() * cam_from_world.translation);
  *n_c = r * plane.normal;
  *d_c = plane.offset - plane.normal.dot(centre);
}

// Reference pixel index (x, y) -> neighbour pixel index through the plane (seed 000 Eq. 7), for
// cv::warpPerspective with WARP_INVERSE_MAP; pixel centres at +0.5 (COLMAP) on both sides.
cv::Matx33d PlaneHomography(const LayerView& reference, const LayerView& neighbour, const WorldPlane& plane) {
  Eigen::Vector3d n_c;
  double d_c;
  PlaneInCamera(plane, reference.cam_from_world, &n_c, &d_c);
  const Eigen::Matrix3d r_rel = neighbour.cam_from_world.R() * reference.cam_from_world.R().transpose();
  const Eigen::Vector3d t_rel = neighbour.cam_from_world.translation - r_rel * reference.cam_from_world.translation;
  Eigen::Matrix3d to_centre = Eigen::Matrix3d::Identity(), from_centre = Eigen::Matrix3d::Identity();
  to_centre(0, 2) = to_centre(1, 2) = 0.5;
  from_centre(0, 2) = from_centre(1, 2) = -0.5;
  const Eigen::Matrix3d h = from_centre * neighbour.camera.K() * (r_rel + t_rel * n_c.transpose() / d_c) *
                            reference.camera.K().inverse() * to_centre;
  cv::Matx33d m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m(i, j) = h(i, j);
  return m;
}

// z of the plane along the reference pixel's ray, 0 when behind or parallel.
cv::Mat PlaneDepthMap(const LayerView& reference, const WorldPlane& plane) {
  Eigen::Vector3d n_c;
  double d_c;
  PlaneInCamera(plane, reference.cam_from_world, &n_c, &d_c);
  cv::Mat z(reference.depth.size(), CV_32F);
  for (int y = 0; y < z.rows; ++y) {
    float* row = z.ptr<float>(y);
    for (int x = 0; x < z.cols; ++x) {
      const double denominator = n_c.dot(reference.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)));
      const double depth = std::abs(denominator) > 1e-12 ? d_c / denominator : 0.0;
      row[x] = depth > 0 && std::isfinite(depth) ? static_cast<float>(depth) : 0.f;
    }
  }
  return z;
}

// The views' colours as floats (CV_32FC3), converted once for all the planes and offsets a
// caller warps them through.
std::vector<cv::Mat> FloatImages(const std::vector<const LayerView*>& views) {
  std::vector<cv::Mat> out(views.size());
  for (size_t i = 0; i < views.size(); ++i) views[i]->image.convertTo(out[i], CV_32FC3);
  return out;
}

// Per pixel, the mean absolute colour difference between the reference and the neighbour warped
// through the plane; NaN where the neighbour does not reach, and where the plane's point lies
// behind either camera (the homography would mirror it into the neighbour's image: the floor
// ahead of a camera that moves forward lies behind the camera in front).
cv::Mat WarpDifference(const LayerView& reference, const LayerView& neighbour, const cv::Mat& neighbour_float,
                       const WorldPlane& plane, const cv::Mat& reference_float) {
  cv::Mat warped;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const cv::Matx33d h = PlaneHomography(reference, neighbour, plane);
  cv::warpPerspective(neighbour_float, warped, h, reference.image.size(), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                      cv::BORDER_CONSTANT, cv::Scalar::all(nan));
  // At pixel (x, y) the homography's third coordinate is z_neighbour / z_reference, and
  // n_c . K^-1 (x + 0.5, y + 0.5, 1) has the sign of d_c where the plane lies in front of the reference.
  Eigen::Vector3d n_c;
  double d_c;
  PlaneInCamera(plane, reference.cam_from_world, &n_c, &d_c);
  const Eigen::Matrix3d k_inv = reference.camera.K().inverse();
  const Eigen::RowVector3d along = n_c.transpose() * k_inv * std::copysign(1.0, d_c);
  cv::Mat difference(reference.image.size(), CV_32F);
  for (int y = 0; y < difference.rows; ++y) {
    const cv::Vec3f* a = reference_float.ptr<cv::Vec3f>(y);
    const cv::Vec3f* b = warped.ptr<cv::Vec3f>(y);
    float* out = difference.ptr<float>(y);
    for (int x = 0; x < difference.cols; ++x) {
      const double w = h(2, 0) * x + h(2, 1) * y + h(2, 2);
      const double in_front = along.x() * (x + 0.5) + along.y() * (y + 0.5) + along.z();
      if (!(w > 0 && in_front > 0)) {
        out[x] = nan;
        continue;
      }
      out[x] = (std::abs(a[x][0] - b[x][0]) + std::abs(a[x][1] - b[x][1]) + std::abs(a[x][2] - b[x][2])) / 3.f;
    }
  }
  return difference;
}

// Per pixel, how well the neighbours warped through a plane agree with the reference: the mean of
// the two best neighbours' colour differences (one neighbour that an occluder hides does not veto),
// max_cost where none reaches, box-filtered 5x5.
cv::Mat PhotoCost(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                  const std::vector<cv::Mat>& neighbours_float, const WorldPlane& plane, const cv::Mat& reference_float,
                  const LayeredOptions& options) {
  std::vector<cv::Mat> differences;
  for (size_t i = 0; i < neighbours.size(); ++i) {
    differences.push_back(WarpDifference(reference, *neighbours[i], neighbours_float[i], plane, reference_float));
  }
  cv::Mat photo(reference.image.size(), CV_32F);
  for (int y = 0; y < photo.rows; ++y) {
    float* out = photo.ptr<float>(y);
    for (int x = 0; x < photo.cols; ++x) {
      float best = std::numeric_limits<float>::infinity(), second = best;
      for (const cv::Mat& d : differences) {
        const float v = d.at<float>(y, x);
        if (!std::isfinite(v)) continue;
        if (v < best) {
          second = best;
          best = v;
        } else if (v < second) {
          second = v;
        }
      }
      out[x] = !std::isfinite(best) ? static_cast<float>(options.max_cost) : !std::isfinite(second) ? best : 0.5f * (best + second);
    }
  }
  cv::blur(photo, photo, cv::Size(5, 5));
  return photo;
}

// Data cost of every plane at every pixel (steps 3's terms before smoothing).
std::vector<cv::Mat> DataCosts(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                               const std::vector<WorldPlane>& planes, const LayeredOptions& options,
                               std::vector<cv::Mat>* plane_depths) {
  cv::Mat reference_float;
  reference.image.convertTo(reference_float, CV_32FC3);
  const std::vector<cv::Mat> neighbours_float = FloatImages(neighbours);
  std::vector<cv::Mat> costs(planes.size());
  plane_depths->assign(planes.size(), cv::Mat());
  tbb::parallel_for(size_t{0}, planes.size(), [&](size_t l) {
    (*plane_depths)[l] = PlaneDepthMap(reference, planes[l]);
    cv::Mat photo = PhotoCost(reference, neighbours, neighbours_float, planes[l], reference_float, options);
    const cv::Mat& plane_z = (*plane_depths)[l];
    for (int y = 0; y < photo.rows; ++y) {
      float* out = photo.ptr<float>(y);
      const float* z = reference.depth.ptr<float>(y);
      const float* zp = plane_z.ptr<float>(y);
      for (int x = 0; x < photo.cols; ++x) {
        if (!(zp[x] > 0)) {
          out[x] = std::numeric_limits<float>::max() / 4;
          continue;
        }
        if (z[x] > 0) {
          const float off = std::abs(z[x] - zp[x]) / static_cast<float>(options.plane_tolerance * z[x]);
          out[x] += static_cast<float>(options.depth_weight) * std::min(off, 3.f);
        }
      }
    }
    costs[l] = photo;
  });
  return costs;
}

// Step 4's residual depth by stereo in the plane-stabilised frame (seed 000 Eq. 8 and the lines
// after it: "almost any stereo algorithm ... preferable to use one favoring small disparities ...
// a simple plane-sweep"). A residual displaces a pixel along its ray by a fraction delta of the
// plane's depth; the points of one delta form the plane scaled about the reference's centre, a
// plane parallel to the layer's, so each hypothesis is again a homography warp (PhotoCost). Per
// pixel of the layer: the cheapest of `residual_steps` deltas spread over [-max_residual,
// max_residual], refined by a parabola through its neighbours; NaN where no neighbour reaches
// or the minimum lies on the range's end (no evidence of a surface inside it).
cv::Mat SweepResidual(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                      const std::vector<cv::Mat>& neighbours_float, const WorldPlane& plane, const cv::Mat& own,
                      const cv::Mat& reference_float, const LayeredOptions& options) {
  const int steps = options.residual_steps;
  const Eigen::Vector3d centre = -(reference.cam_from_world.R().transpose() * reference.cam_from_world.translation);
  const double plane_from_centre = plane.offset - plane.normal.dot(centre);
  auto delta_of = [&](double k) { return options.max_residual * (2.0 * k / (steps - 1) - 1.0); };
  // A running minimum over the offsets: per pixel the cheapest cost, its offset and the costs of
  // the offsets either side of it, so that only one cost map is held at a time.
  const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
  const cv::Size size = reference.image.size();
  cv::Mat best_cost(size, CV_32F, cv::Scalar::all(inf)), below(size, CV_32F, cv::Scalar::all(nan)),
      above(size, CV_32F, cv::Scalar::all(nan)), best(size, CV_32S, cv::Scalar::all(-1)), previous;
  for (int k = 0; k < steps; ++k) {
    WorldPlane scaled = plane;
    scaled.offset = plane.normal.dot(centre) + (1 + delta_of(k)) * plane_from_centre;
    const cv::Mat cost = PhotoCost(reference, neighbours, neighbours_float, scaled, reference_float, options);
    for (int y = 0; y < size.height; ++y) {
      const uint8_t* mine = own.ptr<uint8_t>(y);
      const float* c = cost.ptr<float>(y);
      float *low = best_cost.ptr<float>(y), *before = below.ptr<float>(y), *after = above.ptr<float>(y);
      int* at = best.ptr<int>(y);
      const float* earlier = k > 0 ? previous.ptr<float>(y) : nullptr;
      for (int x = 0; x < size.width; ++x) {
        if (!mine[x]) continue;
        if (c[x] < low[x]) {
          low[x] = c[x];
          at[x] = k;
          before[x] = earlier ? earlier[x] : nan;
          after[x] = nan;
        } else if (at[x] == k - 1) {
          after[x] = c[x];
        }
      }
    }
    previous = cost;
  }
  cv::Mat delta(size, CV_32F, cv::Scalar::all(nan));
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const int k = best.at<int>(y, x);
      const float c0 = best_cost.at<float>(y, x), cm = below.at<float>(y, x), cp = above.at<float>(y, x);
      if (k <= 0 || k >= steps - 1 || !(c0 < options.max_cost)) continue;
      const float curvature = cm + cp - 2 * c0;
      const float shift = curvature > 0 ? std::clamp(0.5f * (cm - cp) / curvature, -0.5f, 0.5f) : 0.f;
      delta.at<float>(y, x) = static_cast<float>(delta_of(k + shift));
    }
  }
  return delta;
}

}  // namespace

namespace {

// At most this many labels (LayeredOptions::max_layers' range).
constexpr int kMaxLabels = 16;

// Labels from the first `count` planes' data costs: the cheapest, then ICM with the Potts term.
cv::Mat AssignFromCosts(const LayerView& reference, const std::vector<cv::Mat>& costs, int count, const LayeredOptions& options) {
  if (count > kMaxLabels) throw std::invalid_argument("AssignFromCosts: " + std::to_string(count) + " planes, at most " + std::to_string(kMaxLabels));
  const int width = reference.image.cols, height = reference.image.rows;
  cv::Mat labels(height, width, CV_32S, cv::Scalar::all(-1));
  if (count == 0) return labels;
  // Initial labels: the cheapest plane; empty where nothing explains the pixel and it has no depth.
  for (int y = 0; y < height; ++y) {
    int* row = labels.ptr<int>(y);
    const float* z = reference.depth.ptr<float>(y);
    for (int x = 0; x < width; ++x) {
      int best = -1;
      float best_cost = std::numeric_limits<float>::infinity();
      for (int l = 0; l < count; ++l) {
        const float c = costs[l].at<float>(y, x);
        if (c < best_cost) best_cost = c, best = l;
      }
      row[x] = (best_cost <= options.max_cost || z[x] > 0) ? best : -1;
    }
  }
  // ICM on data + Potts, red-black so that the result does not depend on the thread schedule.
  const float smoothness = static_cast<float>(options.smoothness);
  for (int sweep = 0; sweep < options.icm_sweeps; ++sweep) {
    for (int parity = 0; parity < 2; ++parity) {
      tbb::parallel_for(0, height, [&](int y) {
        int* row = labels.ptr<int>(y);
        const int* above = y > 0 ? labels.ptr<int>(y - 1) : nullptr;
        const int* below = y + 1 < height ? labels.ptr<int>(y + 1) : nullptr;
        const float* cost_rows[kMaxLabels];
        for (int l = 0; l < count; ++l) cost_rows[l] = costs[l].ptr<float>(y);
        for (int x = (y + parity) % 2; x < width; x += 2) {
          if (row[x] < 0) continue;
          const int around[4] = {x > 0 ? row[x - 1] : -2, x + 1 < width ? row[x + 1] : -2, above ? above[x] : -2,
                                 below ? below[x] : -2};
          // The Potts term of label l: smoothness once for each labelled neighbour with another
          // label, added one at a time as a sum of equal terms (the same float whatever the order).
          int labelled = 0;
          for (const int a : around) labelled += a >= 0;
          int best = row[x];
          float best_cost = std::numeric_limits<float>::infinity();
          for (int l = 0; l < count; ++l) {
            float c = cost_rows[l][x];
            int others = labelled;
            for (const int a : around) others -= a == l;
            for (int k = 0; k < others; ++k) c += smoothness;
            if (c < best_cost) best_cost = c, best = l;
          }
          row[x] = best;
        }
      });
    }
  }
  // Speckle: a pixel whose 5x5 window holds another label 13 times or more (a majority) takes it.
  // ICM's 4-neighbour Potts term leaves isolated pixels and thin streaks; a sprite pixel without
  // same-layer neighbours makes no triangle, so each would draw as a hole in a novel view.
  for (int pass = 0; pass < 2; ++pass) {
    const cv::Mat before = labels.clone();
    tbb::parallel_for(2, height - 2, [&](int y) {
      int votes[kMaxLabels + 1];
      const int* rows[5];
      for (int dy = -2; dy <= 2; ++dy) rows[dy + 2] = before.ptr<int>(y + dy);
      int* out = labels.ptr<int>(y);
      for (int x = 2; x < width - 2; ++x) {
        // A window of one label (most of them) keeps it: nothing to count.
        const int centre = rows[2][x];
        bool uniform = true;
        for (int r = 0; r < 5 && uniform; ++r) {
          for (int dx = -2; dx <= 2; ++dx) uniform &= rows[r][x + dx] == centre;
        }
        if (uniform) continue;
        std::fill(votes, votes + count + 1, 0);
        for (int r = 0; r < 5; ++r) {
          for (int dx = -2; dx <= 2; ++dx) ++votes[rows[r][x + dx] + 1];
        }
        const int winner = static_cast<int>(std::max_element(votes, votes + count + 1) - votes) - 1;
        if (votes[winner + 1] >= 13) out[x] = winner;
      }
    });
  }
  return labels;
}

}  // namespace

cv::Mat AssignPixels(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                     const std::vector<WorldPlane>& planes, const LayeredOptions& options) {
  std::vector<cv::Mat> plane_depths;
  const std::vector<cv::Mat> costs = DataCosts(reference, neighbours, planes, options, &plane_depths);
  return AssignFromCosts(reference, costs, static_cast<int>(planes.size()), options);
}

namespace {

// BuildSprites with each plane's depth map along the reference's rays given (`plane_z[l]`, at
// least as many as planes): the count selection draws many models from the same planes.
// `swept`: per plane, the relative residual of SweepResidual (empty: residuals from the depth map).
LayerSet SpritesFromPlaneDepths(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                                const std::vector<WorldPlane>& planes, const std::vector<cv::Mat>& plane_z,
                                const cv::Mat& labels, const LayeredOptions& options,
                                const std::vector<cv::Mat>& swept = {}) {
  const int width = reference.image.cols, height = reference.image.rows;
  LayerSet set;
  set.image = reference.name;
  set.camera = reference.camera;
  set.cam_from_world = reference.cam_from_world;
  // Order: back to front by the median reference depth of each plane's pixels (every pixel: a
  // plane that holds only a thin strip still makes a layer).
  std::vector<std::pair<double, int>> order;
  for (size_t l = 0; l < planes.size(); ++l) {
    std::vector<float> depths;
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        if (labels.at<int>(y, x) == static_cast<int>(l) && plane_z[l].at<float>(y, x) > 0) depths.push_back(plane_z[l].at<float>(y, x));
      }
    }
    if (depths.empty()) continue;  // a plane no pixel chose makes no layer
    std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
    order.emplace_back(depths[depths.size() / 2], static_cast<int>(l));
  }
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.first > b.first; });

  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * options.extend_px + 1, 2 * options.extend_px + 1));
  const Eigen::Matrix3d world_from_cam = reference.cam_from_world.R().transpose();
  const Eigen::Vector3d centre = -(world_from_cam * reference.cam_from_world.translation);
  for (const auto& [median_depth, l] : order) {
    SpriteLayer layer;
    layer.normal = planes[l].normal;
    layer.offset = planes[l].offset;
    layer.rgba = cv::Mat(height, width, CV_8UC4, cv::Scalar::all(0));
    layer.residual = cv::Mat(height, width, CV_32F, cv::Scalar::all(0));
    // The layer's pixels and a seam of `kSeamPx` around them (coloured from the reference like
    // the layer's own): where two layers meet, both cover the boundary, so that a novel view that
    // pulls them apart shows no crack between them; the nearer one is drawn over the seam.
    constexpr int kSeamPx = 1;
    const cv::Mat own = labels == l;
    cv::Mat support;
    cv::dilate(own, support, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * kSeamPx + 1, 2 * kSeamPx + 1)));
    support &= labels >= 0;
    cv::Mat extended;
    if (options.extend_px > 0) {
      cv::dilate(support, extended, kernel);
    } else {
      extended = support.clone();
    }
    const cv::Mat& zl = plane_z[l];
    const size_t layer_index = static_cast<size_t>(l);  // lambdas may not capture structured bindings (clang)
    tbb::parallel_for(0, height, [&](int y) {
      std::vector<cv::Vec3b> seen;
      seen.reserve(neighbours.size());
      std::vector<uint8_t> values;  // one channel of `seen`, for its median
      values.reserve(neighbours.size());
      for (int x = 0; x < width; ++x) {
        const float zp = zl.at<float>(y, x);
        if (!(zp > 0)) continue;
        if (support.at<uint8_t>(y, x)) {
          const cv::Vec3b c = reference.image.at<cv::Vec3b>(y, x);
          const bool owned = own.at<uint8_t>(y, x) != 0;
          layer.rgba.at<cv::Vec4b>(y, x) = cv::Vec4b(c[0], c[1], c[2], owned ? 255 : kSeamAlpha);
          const float limit = static_cast<float>(options.max_residual) * zp;
          const float z = reference.depth.at<float>(y, x);
          if (!owned) continue;  // seam pixels lie on the plane
          if (z > 0) {
            layer.residual.at<float>(y, x) = std::clamp(z - zp, -limit, limit);
          } else if (!swept.empty()) {
            const float delta = swept[layer_index].at<float>(y, x);
            if (std::isfinite(delta)) layer.residual.at<float>(y, x) = std::clamp(delta * zp, -limit, limit);
          }
          continue;
        }
        if (!extended.at<uint8_t>(y, x)) continue;
        // Under a nearer layer in the reference: the neighbours that see the plane colour it.
        const int other = labels.at<int>(y, x);
        if (other < 0 || !(plane_z[other].at<float>(y, x) > 0) || plane_z[other].at<float>(y, x) >= zp) continue;
        const Eigen::Vector3d point = centre + world_from_cam * (zp * reference.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)));
        seen.clear();
        for (const LayerView* n : neighbours) {
          const Eigen::Vector3d in_cam = n->cam_from_world * point;
          if (in_cam.z() <= 0) continue;
          const Eigen::Vector2d p = n->camera.ImgFromCam(in_cam);
          const int u = static_cast<int>(std::floor(p.x())), v = static_cast<int>(std::floor(p.y()));
          if (u < 0 || v < 0 || u >= n->image.cols || v >= n->image.rows) continue;
          const float zn = n->depth.empty() ? 0.f : n->depth.at<float>(v, u);
          if (zn > 0 && std::abs(zn - in_cam.z()) > 2 * options.plane_tolerance * in_cam.z()) continue;  // hidden there too
          seen.push_back(n->image.at<cv::Vec3b>(v, u));
        }
        if (seen.empty()) continue;
        cv::Vec4b out(0, 0, 0, 255);
        for (int c = 0; c < 3; ++c) {
          values.clear();
          for (const auto& s : seen) values.push_back(s[c]);
          std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
          out[c] = values[values.size() / 2];
        }
        layer.rgba.at<cv::Vec4b>(y, x) = out;
      }
    });
    cv::medianBlur(layer.residual, layer.residual, 5);
    set.layers.push_back(std::move(layer));
  }
  return set;
}

}  // namespace

LayerSet BuildSprites(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                      const std::vector<WorldPlane>& planes, const cv::Mat& labels, const LayeredOptions& options) {
  std::vector<cv::Mat> plane_z;
  for (const WorldPlane& plane : planes) plane_z.push_back(PlaneDepthMap(reference, plane));
  std::vector<cv::Mat> swept;
  if (options.residual_steps > 0 && !neighbours.empty()) {
    cv::Mat reference_float;
    reference.image.convertTo(reference_float, CV_32FC3);
    const std::vector<cv::Mat> neighbours_float = FloatImages(neighbours);
    swept.resize(planes.size());
    tbb::parallel_for(size_t{0}, planes.size(), [&](size_t l) {
      swept[l] = SweepResidual(reference, neighbours, neighbours_float, planes[l], labels == static_cast<int>(l), reference_float,
                               options);
    });
  }
  return SpritesFromPlaneDepths(reference, neighbours, planes, plane_z, labels, options, swept);
}

LayerCountCurve ChooseLayerCount(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                                 const std::vector<WorldPlane>& planes, const LayeredOptions& options) {
  LayerCountCurve curve;
  curve.chosen = static_cast<int>(planes.size());
  if (neighbours.empty() || planes.size() <= 1) return curve;
  const size_t counts = planes.size();
  // renders[c][j]: the model with c + 1 planes predicting neighbour j from the others. A plane's
  // data cost does not depend on the others, so each held-out neighbour's costs serve every count.
  std::vector<std::vector<RgbaImage>> renders(counts, std::vector<RgbaImage>(neighbours.size()));
  std::vector<cv::Mat> plane_z;
  for (const WorldPlane& plane : planes) plane_z.push_back(PlaneDepthMap(reference, plane));
  CompositeScratch scratch;  // one set of drawing buffers for all the renders below
  for (size_t j = 0; j < neighbours.size(); ++j) {
    std::vector<const LayerView*> others;
    for (size_t i = 0; i < neighbours.size(); ++i) {
      if (i != j) others.push_back(neighbours[i]);
    }
    std::vector<cv::Mat> plane_depths;
    const std::vector<cv::Mat> costs = DataCosts(reference, others, planes, options, &plane_depths);
    for (size_t c = 0; c < counts; ++c) {
      const std::vector<WorldPlane> subset(planes.begin(), planes.begin() + static_cast<long>(c) + 1);
      const cv::Mat labels = AssignFromCosts(reference, costs, static_cast<int>(c) + 1, options);
      const LayerSet set = SpritesFromPlaneDepths(reference, others, subset, plane_z, labels, options);
      renders[c][j] = CompositeLayers(set, neighbours[j]->camera, neighbours[j]->cam_from_world, kLayerMaxDepthStep, &scratch);
    }
  }
  // The error of every count over one region per neighbour: the pixels any count covers.
  std::vector<double> squared(counts, 0.0);
  double pixels = 0;
  for (size_t j = 0; j < neighbours.size(); ++j) {
    const cv::Mat& photo = neighbours[j]->image;
    for (int y = 0; y < photo.rows; ++y) {
      for (int x = 0; x < photo.cols; ++x) {
        bool covered = false;
        for (size_t c = 0; c < counts && !covered; ++c) covered = renders[c][j].alpha.at<float>(y, x) > 0.5f;
        if (!covered) continue;
        pixels += 1;
        const cv::Vec3b truth = photo.at<cv::Vec3b>(y, x);
        for (size_t c = 0; c < counts; ++c) {
          const cv::Vec3f predicted = renders[c][j].color.at<cv::Vec3f>(y, x);  // premultiplied: black where empty
          for (int k = 0; k < 3; ++k) squared[c] += (truth[k] - predicted[k]) * (truth[k] - predicted[k]) / 3.0;
        }
      }
    }
  }
  if (pixels == 0) return curve;
  for (size_t c = 0; c < counts; ++c) curve.rms_error.push_back(std::sqrt(squared[c] / pixels));
  const double best = *std::min_element(curve.rms_error.begin(), curve.rms_error.end());
  for (size_t c = 0; c < counts; ++c) {
    if (curve.rms_error[c] <= (1 + options.count_tolerance) * best) {
      curve.chosen = static_cast<int>(c) + 1;
      break;
    }
  }
  return curve;
}

LayeredResult ReconstructLayers(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                                const LayeredOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  LayeredResult result;
  result.planes = FitPlanesRansac(reference, options);
  std::vector<const LayerView*> all = {&reference};
  all.insert(all.end(), neighbours.begin(), neighbours.end());
  RefinePlanes(all, options, &result.planes);
  if (options.photometric_refinement) {
    const cv::Mat labels = AssignPixels(reference, neighbours, result.planes, options);
    RefinePlanesPhotometric(reference, neighbours, labels, options, &result.planes);
  }
  if (options.choose_count) {
    auto scaled = [&](const LayerView& view) {
      if (options.selection_scale >= 1) return view;
      LayerView small;
      small.name = view.name;
      small.cam_from_world = view.cam_from_world;
      small.camera = view.camera.Scaled(options.selection_scale);
      cv::resize(view.image, small.image, cv::Size(small.camera.width, small.camera.height), 0, 0, cv::INTER_AREA);
      cv::resize(view.depth, small.depth, small.image.size(), 0, 0, cv::INTER_NEAREST);
      return small;
    };
    const LayerView small_reference = scaled(reference);
    std::vector<LayerView> small_neighbours;
    for (const LayerView* n : neighbours) small_neighbours.push_back(scaled(*n));
    std::vector<const LayerView*> small_pointers;
    for (const LayerView& n : small_neighbours) small_pointers.push_back(&n);
    result.curve = ChooseLayerCount(small_reference, small_pointers, result.planes, options);
  } else {
    result.curve.chosen = static_cast<int>(result.planes.size());
  }
  const std::vector<WorldPlane> chosen(result.planes.begin(), result.planes.begin() + result.curve.chosen);
  const cv::Mat labels = AssignPixels(reference, neighbours, chosen, options);
  result.layers = BuildSprites(reference, neighbours, chosen, labels, options);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace ibmr
