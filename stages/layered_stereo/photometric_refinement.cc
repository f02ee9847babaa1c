// Step 2b of layers.h: each plane refined by the photo-consistency of its pixels across the views,
// the plane optimised directly as seed 000 line 5716 suggests ("a better approach might be to
// directly optimize over the plane normal n_l used in (7)"): the reference's pixels of the layer,
// mapped into each neighbour through the plane's homography (Eq. 7), should have the neighbour's
// grey level there. Ceres, with bicubic interpolation of the neighbours' images and a Huber loss;
// the plane is parametrised as u = n_c / d_c in the reference camera (n_c . X = d_c), so that a
// pixel's point is r / (u . r) for its ray r, without a gauge freedom. A pixel counts where the
// depth maps show the plane alone 2 pixels around it, in the reference and where it lands in the
// neighbour: an outline mixes the colours of both sides, which pulled small planes off.
#include <ceres/ceres.h>
#include <ceres/cubic_interpolation.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <memory>
#include <opencv2/imgproc.hpp>

#include "stages/layered_stereo/layers.h"

namespace ibmr {

namespace {

using Interpolator = ceres::BiCubicInterpolator<ceres::Grid2D<double, 1>>;

struct PhotoResidual {
  PhotoResidual(const Eigen::Vector3d& ray, double grey, const Eigen::Matrix3d& r_rel, const Eigen::Vector3d& t_rel,
                const Eigen::Matrix3d& k, const Interpolator* image)
      : ray(ray), grey(grey), r_rel(r_rel), t_rel(t_rel), k(k), image(image) {}

  template <typename T>
  bool operator()(const T* const u, T* residual) const {
    const T denominator = u[0] * T(ray.x()) + u[1] * T(ray.y()) + u[2] * T(ray.z());
    if (!(denominator > T(1e-12))) return false;  // the plane behind the camera along this ray
    const T x_c[3] = {T(ray.x()) / denominator, T(ray.y()) / denominator, T(ray.z()) / denominator};
    T x_j[3];
    for (int i = 0; i < 3; ++i) x_j[i] = T(r_rel(i, 0)) * x_c[0] + T(r_rel(i, 1)) * x_c[1] + T(r_rel(i, 2)) * x_c[2] + T(t_rel(i));
    if (!(x_j[2] > T(1e-9))) return false;
    // Pixel coordinates (centre of the top-left pixel at 0.5), then the grid index (-0.5).
    const T col = (T(k(0, 0)) * x_j[0] + T(k(0, 1)) * x_j[1]) / x_j[2] + T(k(0, 2)) - T(0.5);
    const T row = T(k(1, 1)) * x_j[1] / x_j[2] + T(k(1, 2)) - T(0.5);
    T value;
    image->Evaluate(row, col, &value);
    residual[0] = value - T(grey);
    return true;
  }

  Eigen::Vector3d ray;
  double grey;
  Eigen::Matrix3d r_rel;
  Eigen::Vector3d t_rel;
  Eigen::Matrix3d k;
  const Interpolator* image;
};

// Whether every depth in the (2r+1)^2 window around (x, y) lies within `tolerance` of `z` (relative):
// the pixel and its surroundings show one surface at that depth, with no hole and no other surface
// near enough to bleed into its colour (a rendered or photographed edge mixes both sides over a
// pixel or two, and the interpolation reaches two more).
bool OneSurfaceAround(const cv::Mat& depth, int x, int y, int r, double z, double tolerance) {
  if (x - r < 0 || y - r < 0 || x + r >= depth.cols || y + r >= depth.rows) return false;
  for (int yy = y - r; yy <= y + r; ++yy) {
    const float* row = depth.ptr<float>(yy);
    for (int xx = x - r; xx <= x + r; ++xx) {
      if (!(row[xx] > 0) || std::abs(row[xx] - z) > tolerance * z) return false;
    }
  }
  return true;
}

std::vector<double> Grey(const cv::Mat& bgr) {
  cv::Mat grey;
  cv::cvtColor(bgr, grey, cv::COLOR_BGR2GRAY);
  std::vector<double> values(static_cast<size_t>(grey.rows) * grey.cols);
  for (int y = 0; y < grey.rows; ++y)
    for (int x = 0; x < grey.cols; ++x) values[static_cast<size_t>(y) * grey.cols + x] = grey.at<uint8_t>(y, x);
  return values;
}

// The window around a pixel, in both views, that must show the plane alone (OneSurfaceAround).
constexpr int kMargin = 2;

}  // namespace

void RefinePlanesPhotometric(const LayerView& reference, const std::vector<const LayerView*>& neighbours,
                             const cv::Mat& labels, const LayeredOptions& options, std::vector<WorldPlane>* planes) {
  if (neighbours.empty() || planes->empty()) return;
  const int width = reference.image.cols, height = reference.image.rows;
  cv::Mat grey, gx, gy;
  cv::cvtColor(reference.image, grey, cv::COLOR_BGR2GRAY);
  cv::Sobel(grey, gx, CV_32F, 1, 0, 3);
  cv::Sobel(grey, gy, CV_32F, 0, 1, 3);
  std::vector<std::vector<double>> images;
  std::vector<std::unique_ptr<ceres::Grid2D<double, 1>>> grids;
  std::vector<std::unique_ptr<Interpolator>> interpolators;
  for (const LayerView* n : neighbours) {
    images.push_back(Grey(n->image));
    grids.push_back(std::make_unique<ceres::Grid2D<double, 1>>(images.back().data(), 0, n->image.rows, 0, n->image.cols));
    interpolators.push_back(std::make_unique<Interpolator>(*grids.back()));
  }
  const Eigen::Matrix3d r_ref = reference.cam_from_world.R();
  const Eigen::Vector3d centre = -(r_ref.transpose() * reference.cam_from_world.translation);
  for (size_t l = 0; l < planes->size(); ++l) {
    WorldPlane& plane = (*planes)[l];
    const Eigen::Vector3d n_c = r_ref * plane.normal;
    const double d_c = plane.offset - plane.normal.dot(centre);
    if (std::abs(d_c) < 1e-12) continue;
    double u[3] = {n_c.x() / d_c, n_c.y() / d_c, n_c.z() / d_c};
    // The layer's textured pixels (gradient above 8 grey levels a pixel), on a grid of sample_step,
    // with their rays and u . ray (1 / the plane's depth there), which every neighbour uses.
    struct Pixel {
      int x, y;
      Eigen::Vector3d ray;
      double along;
    };
    const Eigen::Vector3d u_start(u[0], u[1], u[2]);
    std::vector<Pixel> pixels;
    for (int y = 2; y < height - 2; y += options.sample_step) {
      for (int x = 2; x < width - 2; x += options.sample_step) {
        if (labels.at<int>(y, x) != static_cast<int>(l)) continue;
        const float g = std::hypot(gx.at<float>(y, x), gy.at<float>(y, x)) / 8.0f;  // Sobel's scale: 8
        if (g < 8.0f) continue;
        const Eigen::Vector3d ray = reference.camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5));
        const double along = u_start.dot(ray);
        if (!(along > 0)) continue;
        if (!OneSurfaceAround(reference.depth, x, y, kMargin, 1.0 / along, 2 * options.plane_tolerance)) continue;
        pixels.push_back({x, y, ray, along});
      }
    }
    if (pixels.size() < 50) continue;
    const size_t stride = std::max<size_t>(1, pixels.size() / 4000);
    ceres::Problem problem;
    size_t residuals = 0;
    for (size_t j = 0; j < neighbours.size(); ++j) {
      const LayerView& n = *neighbours[j];
      const Eigen::Matrix3d r_rel = n.cam_from_world.R() * r_ref.transpose();
      const Eigen::Vector3d t_rel = n.cam_from_world.translation - r_rel * reference.cam_from_world.translation;
      const Eigen::Matrix3d k = n.camera.K();
      for (size_t s = 0; s < pixels.size(); s += stride) {
        const Pixel& pixel = pixels[s];
        // Kept only where the neighbour sees the plane's point: inside its image, with the plane
        // alone around it in the neighbour's depth map.
        const Eigen::Vector3d in_neighbour = r_rel * (pixel.ray / pixel.along) + t_rel;
        if (in_neighbour.z() <= 0) continue;
        const Eigen::Vector2d p = n.camera.ImgFromCam(in_neighbour);
        if (p.x() < 3 || p.y() < 3 || p.x() > n.image.cols - 3 || p.y() > n.image.rows - 3) continue;
        if (!OneSurfaceAround(n.depth, static_cast<int>(p.x()), static_cast<int>(p.y()), kMargin, in_neighbour.z(),
                              2 * options.plane_tolerance)) continue;
        auto* residual = new PhotoResidual(pixel.ray, grey.at<uint8_t>(pixel.y, pixel.x), r_rel, t_rel, k,
                                           interpolators[j].get());
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<PhotoResidual, 1, 3>(residual),
                                 new ceres::HuberLoss(10.0), u);
        ++residuals;
      }
    }
    if (residuals < 50) continue;
    ceres::Solver::Options solver;
    solver.max_num_iterations = 30;
    solver.linear_solver_type = ceres::DENSE_QR;
    solver.num_threads = 2;
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    const Eigen::Vector3d refined(u[0], u[1], u[2]);
    if (!refined.allFinite() || !(refined.norm() > 0) || summary.termination_type == ceres::FAILURE) continue;
    // Back to the world: n_c = u / |u|, d_c = 1 / |u|; n = R^T n_c, offset = d_c + n . C.
    plane.normal = (r_ref.transpose() * refined).normalized();
    plane.offset = 1.0 / refined.norm() + plane.normal.dot(centre);
  }
}

}  // namespace ibmr
