// View-dependent texture mapping with polygon view maps (see vdtm.h; seed 003 §7-8).
#include "stages/render/vdtm.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "pipeline/core/errors.h"
#include "pipeline/core/rasterizer.h"
#include "stages/render/textured.h"

namespace ibmr {

namespace {

// The face's corners in double precision.
struct Corners {
  Eigen::Vector3d a, b, c;
};

Corners CornersOf(const TriangleMesh& mesh, int face) {
  const Eigen::Vector3i& f = mesh.faces[face];
  return {mesh.vertices[f[0]].cast<double>(), mesh.vertices[f[1]].cast<double>(), mesh.vertices[f[2]].cast<double>()};
}

// The geometric unit normal of a counter-clockwise face (+z for a degenerate one, which the
// rasterizer never draws anyway).
Eigen::Vector3d FaceNormal(const Corners& corners) {
  const Eigen::Vector3d n = (corners.b - corners.a).cross(corners.c - corners.a);
  const double length = n.norm();
  return length > 0 && std::isfinite(length) ? Eigen::Vector3d(n / length) : Eigen::Vector3d::UnitZ();
}

}  // namespace

VdtmRenderer::VdtmRenderer(const TexturedMesh* mesh, const ViewMaps* maps, const std::vector<SourceView>* sources,
                           double visibility_epsilon)
    : mesh_(mesh), maps_(maps), sources_(sources), visibility_epsilon_(visibility_epsilon) {
  if (maps->faces.size() != mesh->mesh.faces.size()) {
    throw InputError("vdtm: the view maps hold " + std::to_string(maps->faces.size()) + " faces but the mesh has " +
                     std::to_string(mesh->mesh.faces.size()) + " (files of different texture runs? run texture again)");
  }
  std::unordered_map<std::string, int> source_by_name;
  for (size_t i = 0; i < sources->size(); ++i) source_by_name.emplace((*sources)[i].name, static_cast<int>(i));
  source_of_view_.assign(maps->view_names.size(), -1);
  for (size_t v = 0; v < maps->view_names.size(); ++v) {
    const auto found = source_by_name.find(maps->view_names[v]);
    if (found == source_by_name.end()) continue;
    source_of_view_[v] = found->second;
    ++matched_views_;
  }
  for (const SourceView& source : *sources) {
    Prepared p;
    p.rotation = source.cam_from_world.R();
    p.translation = source.cam_from_world.translation;
    p.fx = source.camera.FocalX();
    p.fy = source.camera.FocalY();
    p.cx = source.camera.PrincipalX();
    p.cy = source.camera.PrincipalY();
    p.width = source.image.cols;
    p.height = source.image.rows;
    prepared_.push_back(p);
  }
}

Eigen::Vector2d VdtmRenderer::MapToFace(int face, const Eigen::Vector3d& desired_center) const {
  const Corners corners = CornersOf(mesh_->mesh, face);
  const Eigen::Vector3d centroid = (corners.a + corners.b + corners.c) / 3.0;
  const Eigen::Matrix3d frame = FaceFrame(FaceNormal(corners));
  Eigen::Vector3d direction = desired_center - centroid;
  direction = direction.norm() > 0 ? Eigen::Vector3d(direction.normalized()) : Eigen::Vector3d(frame.col(2));
  return MapDirection(frame, direction);
}

FaceBlend VdtmRenderer::BlendViews(int face, const Eigen::Vector2d& mapped, int exclude_source,
                                   bool* may_fall_back) const {
  FaceBlend blend;
  *may_fall_back = false;
  const FaceViewMap& map = maps_->faces[face];
  if (map.views.empty()) return blend;  // seen by no view: the atlas (hole filling, §6)
  const Eigen::Vector2f mapped_direction = mapped.cast<float>();
  const ViewBlend views = BlendAt(*maps_, face, mapped);
  float sum = 0.f;
  for (int i = 0; i < views.count; ++i) {
    const int source = source_of_view_[views.views[i]];
    if (source < 0 || source == exclude_source || !(views.weights[i] > 0.f)) continue;
    blend.sources[blend.count] = source;
    blend.weights[blend.count] = views.weights[i];
    sum += views.weights[i];
    ++blend.count;
  }
  if (blend.count > 0) {
    for (int i = 0; i < blend.count; ++i) blend.weights[i] /= sum;
    *may_fall_back = true;
    return blend;
  }
  // Every view of the map's triangle is gone (the desired view's own photo, or a photo that is
  // not a source): the nearest remaining view of the face in the map plane, what the grid would
  // have held without them (§7: each grid sample takes the nearest view).
  float best = std::numeric_limits<float>::max();
  for (size_t k = 0; k < map.views.size(); ++k) {
    const int source = source_of_view_[map.views[k]];
    if (source < 0 || source == exclude_source) continue;
    const float d = (map.directions[k] - mapped_direction).squaredNorm();
    if (d < best) {
      best = d;
      blend.count = 1;
      blend.sources[0] = source;
      blend.weights[0] = 1.f;
    }
  }
  return blend;
}

void VdtmRenderer::AddFallbacks(int face, const Eigen::Vector2f& mapped, int exclude_source, FaceBlend* blend) const {
  const FaceViewMap& map = maps_->faces[face];
  const auto blended = [&](int source) {
    return std::find(blend->sources.begin(), blend->sources.begin() + blend->count, source) !=
           blend->sources.begin() + blend->count;
  };
  std::array<std::pair<float, int>, 4> nearest;
  int found = 0;
  for (size_t k = 0; k < map.views.size(); ++k) {
    const int source = source_of_view_[map.views[k]];
    if (source < 0 || source == exclude_source || blended(source)) continue;
    const std::pair<float, int> candidate((map.directions[k] - mapped).squaredNorm(), source);
    if (found < 4) {
      nearest[found++] = candidate;
    } else if (candidate < nearest[3]) {
      nearest[3] = candidate;
    } else {
      continue;
    }
    std::sort(nearest.begin(), nearest.begin() + found);
  }
  blend->fallback_count = found;
  for (int i = 0; i < found; ++i) blend->fallback[i] = nearest[i].second;
}

FaceBlend VdtmRenderer::Blend(int face, const Eigen::Vector3d& desired_center, int exclude_source) const {
  const Eigen::Vector2d mapped = MapToFace(face, desired_center);
  bool may_fall_back;
  FaceBlend blend = BlendViews(face, mapped, exclude_source, &may_fall_back);
  if (may_fall_back) AddFallbacks(face, mapped.cast<float>(), exclude_source, &blend);
  return blend;
}

namespace {

// One covered face's drawing in a frame: its blend and, per blended source, the face's corners
// projected into that source as homogeneous pixel coordinates (column j: K (R v_j + t), whose
// third entry is v_j's depth there). Projection is linear in homogeneous coordinates, so a pixel
// of the face lies at corners * barycentrics in each source: three multiply-adds a coordinate
// instead of a world point built and transformed per pixel. The fallbacks are found only for the
// pixels that need them (few: where every blended view is hidden or outside).
struct FaceDraw {
  FaceBlend blend;
  Eigen::Vector2f mapped = Eigen::Vector2f::Zero();  // desired direction in the view map's plane
  bool may_fall_back = false;  // the blend is the map triangle's views (not the nearest remaining one)
  std::array<Eigen::Matrix3f, 3> corners;
};

}  // namespace

RenderResult VdtmRenderer::Render(const Camera& camera, const Rigid3d& cam_from_world, int exclude_source,
                                  VdtmStats* stats, int extend_px) const {
  // Back faces are not drawn: the inside of the surface, which no photo shows, seen through a
  // hole of the mesh (a surfel mesh has some). Their pixels are holes, which the extension below
  // closes near the surface. On templeRing (bar protocol) culling moved vdtm's held-out photo
  // PSNR by -0.015 dB and took a third of the rasterization's time.
  RasterizeOptions raster_options;
  raster_options.cull_backfaces = true;
  RasterResult raster = Rasterize(mesh_->mesh, camera, cam_from_world, raster_options);
  const std::vector<uint8_t> extended = ExtendIntoHoles(&raster, extend_px);
  const Rigid3d world_from_cam = cam_from_world.Inverse();
  const Eigen::Vector3d desired_center = world_from_cam.translation;
  // The faces this frame covers, then each one's blend once (§8: per polygon, before drawing).
  const size_t num_faces = mesh_->mesh.faces.size();
  // Slots in the order the image's rows first meet the faces, so that the per-pixel pass below
  // reads its faces' draws nearly in sequence (in face order they were a cache miss a pixel).
  std::vector<int> slot_of_face(num_faces, -1);
  int slots = 0;
  for (const int face : raster.face_id) {
    if (face >= 0 && slot_of_face[face] < 0) slot_of_face[face] = slots++;
  }
  std::vector<int> faces;  // covered faces in the mesh's order (their view maps lie in that order)
  faces.reserve(slots);
  for (size_t f = 0; f < num_faces; ++f) {
    if (slot_of_face[f] >= 0) faces.push_back(static_cast<int>(f));
  }
  const std::vector<Eigen::Vector3f>& vertices = mesh_->mesh.vertices;
  std::vector<FaceDraw> draws(slots);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, faces.size(), 256), [&](const tbb::blocked_range<size_t>& range) {
    // Each face's direction is mapped kAhead faces before its blend, and what the blend will read
    // of the view maps is fetched meanwhile (a miss to memory a face otherwise).
    constexpr size_t kAhead = 8;
    std::array<Eigen::Vector2d, kAhead> ahead;
    const auto map_ahead = [&](size_t i) {
      ahead[i % kAhead] = MapToFace(faces[i], desired_center);
      PrefetchBlendAt(*maps_, faces[i], ahead[i % kAhead]);
    };
    for (size_t i = range.begin(); i < std::min(range.end(), range.begin() + kAhead); ++i) map_ahead(i);
    for (size_t i = range.begin(); i < range.end(); ++i) {
      const Eigen::Vector2d mapped = ahead[i % kAhead];
      if (i + kAhead < range.end()) map_ahead(i + kAhead);
      FaceDraw& draw = draws[slot_of_face[faces[i]]];
      draw.mapped = mapped.cast<float>();
      draw.blend = BlendViews(faces[i], mapped, exclude_source, &draw.may_fall_back);
      const Eigen::Vector3i& f = mesh_->mesh.faces[faces[i]];
      for (int k = 0; k < draw.blend.count; ++k) {
        const Prepared& s = prepared_[draw.blend.sources[k]];
        for (int j = 0; j < 3; ++j) {
          const Eigen::Vector3d q = s.rotation * vertices[f[j]].cast<double>() + s.translation;
          draw.corners[k].col(j) = Eigen::Vector3d(s.fx * q.x() + s.cx * q.z(), s.fy * q.y() + s.cy * q.z(), q.z()).cast<float>();
        }
      }
    }
  });

  RenderResult result;
  result.image = cv::Mat(camera.height, camera.width, CV_8UC3, cv::Scalar::all(0));
  result.coverage = cv::Mat(camera.height, camera.width, CV_8UC1, cv::Scalar::all(0));
  std::vector<size_t> row_blended(camera.height, 0), row_atlas(camera.height, 0);
  // Colour of source `source` at pixel (u, v) of its image where the point has depth z there, or
  // false when that is outside its image or hidden behind another part of the mesh.
  const auto sample = [&](int source, float u, float v, float z, Eigen::Vector3f* color) {
    const Prepared& s = prepared_[source];
    if (!(z > 0.f) || !(u >= 0.f && u < s.width && v >= 0.f && v < s.height)) return false;  // outside: dropped
    // Hidden in that view behind another part of the mesh: dropped. (ULR's stricter test,
    // every pixel of the bilinear footprint within the tolerance, lost 0.2 dB here on
    // templeRing: it drops the nearest views at every depth edge.)
    const DepthMap& depth = (*sources_)[source].proxy_depth;
    if (!depth.Empty()) {
      const float d = depth.At(std::min(static_cast<int>(u), depth.width - 1), std::min(static_cast<int>(v), depth.height - 1));
      if (IsValidDepth(d) && z > d * (1.0 + visibility_epsilon_)) return false;
    }
    *color = SampleBilinear((*sources_)[source].image, u, v);
    return true;
  };
  // The same from a world point (hole pixels the extension reached, and fallback views).
  const auto sample_point = [&](int source, const Eigen::Vector3d& p, Eigen::Vector3f* color) {
    const Prepared& s = prepared_[source];
    const Eigen::Vector3d q = s.rotation * p + s.translation;
    if (!(q.z() > 0)) return false;
    return sample(source, static_cast<float>(s.fx * q.x() / q.z() + s.cx), static_cast<float>(s.fy * q.y() / q.z() + s.cy),
                  static_cast<float>(q.z()), color);
  };
  tbb::parallel_for(tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      uint8_t* out = result.image.ptr<uint8_t>(y);
      uint8_t* covered = result.coverage.ptr<uint8_t>(y);
      for (int x = 0; x < camera.width; ++x) {
        const int face = raster.face_id[static_cast<size_t>(y) * camera.width + x];
        if (face < 0) continue;
        const Eigen::Vector3f bary(raster.barycentric.At(x, y, 0), raster.barycentric.At(x, y, 1),
                                   raster.barycentric.At(x, y, 2));
        const FaceDraw& draw = draws[slot_of_face[face]];
        Eigen::Vector3f bgr = Eigen::Vector3f::Zero();
        float sum = 0.f;
        if (draw.blend.count > 0) {
          // A hole the extension reached: the pixel's own ray at the depth it took (as ULR's
          // proxy), coloured by the blend of the face it took it from.
          const bool on_ray = !extended.empty() && extended[static_cast<size_t>(y) * camera.width + x];
          const auto point = [&]() -> Eigen::Vector3d {
            if (on_ray) {
              return world_from_cam * (camera.CamFromImg(Eigen::Vector2d(x + 0.5, y + 0.5)) * static_cast<double>(raster.depth.At(x, y)));
            }
            const Eigen::Vector3i& f = mesh_->mesh.faces[face];
            return (bary[0] * vertices[f[0]] + bary[1] * vertices[f[1]] + bary[2] * vertices[f[2]]).cast<double>();
          };
          const Eigen::Vector3d ray_point = on_ray ? point() : Eigen::Vector3d::Zero();
          Eigen::Vector3f color;
          for (int i = 0; i < draw.blend.count; ++i) {
            const int source = draw.blend.sources[i];
            bool seen;
            if (on_ray) {
              seen = sample_point(source, ray_point, &color);
            } else {
              const Eigen::Vector3f q = draw.corners[i] * bary;
              seen = q.z() > 0.f && sample(source, q.x() / q.z(), q.y() / q.z(), q.z(), &color);
            }
            if (!seen) continue;
            bgr += draw.blend.weights[i] * color;
            sum += draw.blend.weights[i];
          }
          if (!(sum > 0.f) && draw.may_fall_back) {
            // Every blended view hidden or outside here: the face's next views by map distance.
            FaceBlend others = draw.blend;
            AddFallbacks(face, draw.mapped, exclude_source, &others);
            const Eigen::Vector3d p = on_ray ? ray_point : point();
            for (int i = 0; i < others.fallback_count && !(sum > 0.f); ++i) {
              if (sample_point(others.fallback[i], p, &color)) bgr = color, sum = 1.f;
            }
          }
        }
        if (sum > 0.f) {
          bgr /= sum;  // renormalised over the views that reached the pixel
          ++row_blended[y];
        } else {
          bgr = SampleAtlas(*mesh_, face, bary);
          ++row_atlas[y];
        }
        for (int c = 0; c < 3; ++c) out[3 * x + c] = cv::saturate_cast<uint8_t>(bgr[c]);
        covered[x] = 255;
      }
    }
  });
  VdtmStats counts;
  for (int y = 0; y < camera.height; ++y) {
    counts.blended_pixels += row_blended[y];
    counts.atlas_pixels += row_atlas[y];
  }
  result.covered_pixels = counts.blended_pixels + counts.atlas_pixels;
  if (stats) *stats = counts;
  return result;
}

}  // namespace ibmr
