// Per-view face visibility and quality from the item buffer (see face_visibility.h; seed 003 §5).
#include "stages/texture/face_visibility.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <opencv2/imgproc.hpp>

#include "pipeline/core/rasterizer.h"

namespace ibmr {

FaceGeometry FaceGeometry::Of(const TriangleMesh& mesh) {
  FaceGeometry geometry;
  geometry.centroids.resize(mesh.faces.size());
  geometry.normals.resize(mesh.faces.size());
  for (size_t f = 0; f < mesh.faces.size(); ++f) {
    const Eigen::Vector3d a = mesh.vertices[mesh.faces[f][0]].cast<double>();
    const Eigen::Vector3d b = mesh.vertices[mesh.faces[f][1]].cast<double>();
    const Eigen::Vector3d c = mesh.vertices[mesh.faces[f][2]].cast<double>();
    geometry.centroids[f] = (a + b + c) / 3.0;
    const Eigen::Vector3d n = (b - a).cross(c - a);
    geometry.normals[f] = n.norm() > 0 ? Eigen::Vector3d(n.normalized()) : Eigen::Vector3d::Zero();
  }
  return geometry;
}

void ObserveView(const TriangleMesh& mesh, const FaceGeometry& geometry, const Camera& camera,
                 const Rigid3d& cam_from_world, const cv::Mat& image, int view, const TextureOptions& options,
                 std::vector<std::pair<int, FaceObservation>>* seen) {
  const RasterResult raster = Rasterize(mesh, camera, cam_from_world);
  const int width = camera.width, height = camera.height;

  // Gradient magnitude of the grey image (Sobel, 0..~1442 for 8-bit) and the item buffer sums.
  cv::Mat gray, gx, gy;
  cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  cv::Sobel(gray, gx, CV_32F, 1, 0, 3);
  cv::Sobel(gray, gy, CV_32F, 0, 1, 3);
  const size_t faces = mesh.faces.size();
  std::vector<float> quality(faces, 0.f);
  std::vector<int> pixels(faces, 0);
  std::vector<Eigen::Vector3f> color_sum(faces, Eigen::Vector3f::Zero());
  for (int y = 0; y < height; ++y) {
    const float* rx = gx.ptr<float>(y);
    const float* ry = gy.ptr<float>(y);
    const cv::Vec3b* rgb = image.ptr<cv::Vec3b>(y);
    for (int x = 0; x < width; ++x) {
      const int f = raster.face_id[static_cast<size_t>(y) * width + x];
      if (f < 0) continue;
      quality[f] += 1.f + std::sqrt(rx[x] * rx[x] + ry[x] * ry[x]) / 32.f;
      ++pixels[f];
      color_sum[f] += Eigen::Vector3f(rgb[x][0], rgb[x][1], rgb[x][2]);
    }
  }

  const Eigen::Vector3d center = cam_from_world.Inverse().translation;
  const auto sample_bgr = [&](const Eigen::Vector2d& p) {
    const int x = std::clamp(static_cast<int>(p.x()), 0, width - 1);
    const int y = std::clamp(static_cast<int>(p.y()), 0, height - 1);
    const cv::Vec3b c = image.at<cv::Vec3b>(y, x);
    return Eigen::Vector3f(c[0], c[1], c[2]);
  };
  for (size_t f = 0; f < faces; ++f) {
    const Eigen::Vector3d& n = geometry.normals[f];
    if (n.isZero()) continue;
    const Eigen::Vector3d to_camera = center - geometry.centroids[f];
    // Either side: a mesh from real data has faces wound the wrong way (OrientFaces turns them).
    const double cos_angle = n.dot(to_camera.normalized());
    if (!(std::abs(cos_angle) >= std::max(options.min_cos_angle, 1e-6))) continue;
    // The vertices (pulled 5% toward the centroid, so that a neighbour sharing the vertex does not
    // decide the test) and the centroid against the z-buffer.
    bool inside = true;
    int hidden = 0;            // samples behind something
    bool centroid_hidden = false;
    Eigen::Vector2d corners[3];
    for (int k = 0; k < 4 && inside; ++k) {
      Eigen::Vector3d point = geometry.centroids[f];
      if (k < 3) {
        const Eigen::Vector3d vertex = mesh.vertices[mesh.faces[f][k]].cast<double>();
        const Eigen::Vector3d in_cam = cam_from_world * vertex;
        if (!(in_cam.z() > 0)) {
          inside = false;
          break;
        }
        corners[k] = camera.ImgFromCam(in_cam);
        if (!(corners[k].x() >= 0 && corners[k].y() >= 0 && corners[k].x() <= width && corners[k].y() <= height)) {
          inside = false;
          break;
        }
        point = vertex + 0.05 * (geometry.centroids[f] - vertex);
      }
      const Eigen::Vector3d in_cam = cam_from_world * point;
      const Eigen::Vector2d pixel = camera.ImgFromCam(in_cam);
      const int x = std::clamp(static_cast<int>(pixel.x()), 0, width - 1);
      const int y = std::clamp(static_cast<int>(pixel.y()), 0, height - 1);
      const float z = raster.depth.At(x, y);
      // Nothing in front of the sample (an uncovered pixel: the face is thinner than the pixel).
      if (z > 0 && z < in_cam.z() * (1.0 - options.visibility_epsilon)) {
        ++hidden;
        centroid_hidden = centroid_hidden || k == 3;
      }
    }
    // Entirely seen; or partly (the centroid seen, some corner hidden), or hidden behind other
    // parts of the mesh: those two for the view maps only, where the renderer's per-pixel depth
    // test decides.
    if (!inside) continue;
    FaceObservation observation;
    observation.view = view;
    observation.back = cos_angle < 0;
    observation.partial = hidden > 0;
    observation.hidden = centroid_hidden;
    if (pixels[f] > 0) {
      observation.quality = quality[f];
      observation.mean_color = color_sum[f] / static_cast<float>(pixels[f]);
    } else {
      const double area = 0.5 * std::abs((corners[1] - corners[0]).x() * (corners[2] - corners[0]).y() -
                                         (corners[1] - corners[0]).y() * (corners[2] - corners[0]).x());
      observation.quality = static_cast<float>(area);
      observation.mean_color = sample_bgr((corners[0] + corners[1] + corners[2]) / 3.0);
    }
    seen->emplace_back(static_cast<int>(f), observation);
  }
}

size_t OrientFaces(FaceObservations* observations, TriangleMesh* mesh, FaceGeometry* geometry) {
  size_t flipped = 0;
  for (size_t f = 0; f < observations->size(); ++f) {
    std::vector<FaceObservation>& list = (*observations)[f];
    size_t back = 0, seen = 0;
    for (const FaceObservation& o : list) {
      if (o.hidden) continue;  // behind other parts of the mesh: says nothing of the face's side
      back += o.back;
      ++seen;
    }
    if (2 * back <= seen) continue;
    std::swap(mesh->faces[f][1], mesh->faces[f][2]);
    geometry->normals[f] = -geometry->normals[f];
    for (FaceObservation& o : list) o.back = !o.back;
    ++flipped;
  }
  return flipped;
}

size_t RemoveInconsistentViews(double tolerance, FaceObservations* observations) {
  const auto luminance = [](const FaceObservation& o) {
    return 0.114f * o.mean_color[0] + 0.587f * o.mean_color[1] + 0.299f * o.mean_color[2];
  };
  size_t removed = 0;
  std::vector<float> values;
  for (std::vector<FaceObservation>& list : *observations) {
    if (list.size() < 3) continue;
    values.clear();
    for (const FaceObservation& o : list) values.push_back(luminance(o));
    std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
    const float median = values[values.size() / 2];
    const float allowed = std::max(20.f, static_cast<float>(tolerance) * median);
    const size_t before = list.size();
    list.erase(std::remove_if(list.begin(), list.end(), [&](const FaceObservation& o) { return std::abs(luminance(o) - median) > allowed; }),
               list.end());
    removed += before - list.size();
  }
  return removed;
}

}  // namespace ibmr
