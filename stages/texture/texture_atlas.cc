// Patches, packing, copying, leveling and hole cells of the texture atlas (see texture_atlas.h).
#include "stages/texture/texture_atlas.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <opencv2/imgproc.hpp>

namespace ibmr {

namespace {

Eigen::Vector2d Project(const TextureView& view, const Eigen::Vector3f& point) {
  return view.camera.ImgFromCam(view.cam_from_world * point.cast<double>());
}

// Bilinear sample (continuous pixel coordinates, centres at +0.5), borders clamped.
Eigen::Vector3f Bilinear(const cv::Mat& image, double px, double py) {
  const double x = std::clamp(px - 0.5, 0.0, image.cols - 1.0), y = std::clamp(py - 0.5, 0.0, image.rows - 1.0);
  const int x0 = std::min(static_cast<int>(x), image.cols - 2 < 0 ? 0 : image.cols - 2);
  const int y0 = std::min(static_cast<int>(y), image.rows - 2 < 0 ? 0 : image.rows - 2);
  const int x1 = std::min(x0 + 1, image.cols - 1), y1 = std::min(y0 + 1, image.rows - 1);
  const float fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  const auto at = [&](int yy, int xx) {
    const cv::Vec3b c = image.at<cv::Vec3b>(yy, xx);
    return Eigen::Vector3f(c[0], c[1], c[2]);
  };
  return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x1)) + fy * ((1 - fx) * at(y1, x0) + fx * at(y1, x1));
}

// Shelf packing of rectangles (tallest first) into pages at most `max_size` on a side; returns
// the page sizes (heights trimmed to what is used).
std::vector<cv::Size> Pack(std::vector<AtlasPatch>* patches, int max_size) {
  double area = 0;
  int widest = 1;
  for (const AtlasPatch& p : *patches) {
    area += static_cast<double>(p.width) * p.height;
    widest = std::max(widest, p.width);
  }
  int page_width = 64;
  while (page_width < max_size && (page_width < widest || static_cast<double>(page_width) * page_width < 1.3 * area)) {
    page_width *= 2;
  }
  page_width = std::min(page_width, max_size);
  std::vector<size_t> order(patches->size());
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return (*patches)[a].height > (*patches)[b].height; });
  std::vector<cv::Size> pages;
  int page = -1, shelf_y = 0, shelf_h = 0, cursor_x = 0;
  for (size_t i : order) {
    AtlasPatch& p = (*patches)[i];
    if (page < 0 || cursor_x + p.width > page_width) {  // next shelf
      shelf_y += shelf_h;
      shelf_h = 0;
      cursor_x = 0;
    }
    if (page < 0 || shelf_y + p.height > max_size) {  // next page
      pages.emplace_back(page_width, 0);
      ++page;
      shelf_y = 0;
      shelf_h = 0;
      cursor_x = 0;
    }
    p.page = page;
    p.x = cursor_x;
    p.y = shelf_y;
    cursor_x += p.width;
    shelf_h = std::max(shelf_h, p.height);
    pages[page].height = std::max(pages[page].height, shelf_y + p.height);
  }
  for (cv::Size& size : pages) size.height = (size.height + 3) / 4 * 4;
  return pages;
}

}  // namespace

AtlasLayout LayoutAtlas(const TriangleMesh& mesh, const std::vector<int>& labels,
                        const std::vector<std::array<int, 3>>& adjacency, const std::vector<TextureView>& views,
                        const TextureOptions& options, TexturedMesh* out) {
  AtlasLayout layout;
  const size_t faces = mesh.faces.size();
  out->mesh = mesh;
  out->face_uv.assign(faces, Eigen::Matrix<float, 3, 2>::Zero());
  out->face_page.assign(faces, 0);
  out->pages.clear();

  // Connected components of equally labelled faces.
  std::vector<int> patch_of(faces, -1);
  std::vector<int> holes;
  for (size_t seed = 0; seed < faces; ++seed) {
    if (patch_of[seed] >= 0) continue;
    if (labels[seed] < 0) {
      holes.push_back(static_cast<int>(seed));
      continue;
    }
    AtlasPatch patch;
    patch.label = labels[seed];
    const int id = static_cast<int>(layout.patches.size());
    std::vector<int> stack = {static_cast<int>(seed)};
    patch_of[seed] = id;
    while (!stack.empty()) {
      const int f = stack.back();
      stack.pop_back();
      patch.faces.push_back(f);
      for (int g : adjacency[f]) {
        if (g >= 0 && patch_of[g] < 0 && labels[g] == patch.label) {
          patch_of[g] = id;
          stack.push_back(g);
        }
      }
    }
    layout.patches.push_back(std::move(patch));
  }

  // Rectangles: projections' bounds plus padding; scaled down when larger than a page.
  const int usable = options.max_texture_size;
  for (AtlasPatch& patch : layout.patches) {
    const TextureView& view = views[patch.label];
    Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::max());
    Eigen::Vector2d hi = -lo;
    for (int f : patch.faces) {
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector2d q = Project(view, mesh.vertices[mesh.faces[f][k]]);
        lo = lo.cwiseMin(q);
        hi = hi.cwiseMax(q);
      }
    }
    patch.image_min = Eigen::Vector2d(std::floor(lo.x()) - options.padding, std::floor(lo.y()) - options.padding);
    const Eigen::Vector2d extent = Eigen::Vector2d(std::ceil(hi.x()) + options.padding, std::ceil(hi.y()) + options.padding) - patch.image_min;
    patch.scale = std::min(1.0, usable / std::max(extent.x(), extent.y()));
    patch.width = std::max(1, std::min(usable, static_cast<int>(std::ceil(extent.x() * patch.scale))));
    patch.height = std::max(1, std::min(usable, static_cast<int>(std::ceil(extent.y() * patch.scale))));
  }
  // Hole cells in square blocks (at most a page each).
  const int cell = options.hole_cell;
  const size_t per_block = static_cast<size_t>(usable / cell) * static_cast<size_t>(usable / cell);
  layout.hole_faces = holes.size();
  for (size_t start = 0; start < holes.size(); start += per_block) {
    AtlasPatch block;
    block.faces.assign(holes.begin() + start, holes.begin() + std::min(holes.size(), start + per_block));
    const int columns = static_cast<int>(std::ceil(std::sqrt(static_cast<double>(block.faces.size()))));
    const int rows = static_cast<int>((block.faces.size() + columns - 1) / columns);
    block.width = columns * cell;
    block.height = rows * cell;
    layout.patches.push_back(std::move(block));
  }
  layout.page_sizes = Pack(&layout.patches, usable);
  for (const cv::Size& size : layout.page_sizes) out->pages.emplace_back(size, CV_8UC3, cv::Scalar::all(0));

  // Corner UVs.
  for (const AtlasPatch& patch : layout.patches) {
    const cv::Size page = layout.page_sizes[patch.page];
    if (patch.label >= 0) {
      const TextureView& view = views[patch.label];
      for (int f : patch.faces) {
        out->face_page[f] = patch.page;
        for (int k = 0; k < 3; ++k) {
          const Eigen::Vector2d q = Project(view, mesh.vertices[mesh.faces[f][k]]);
          const Eigen::Vector2d texel = Eigen::Vector2d(patch.x, patch.y) + (q - patch.image_min) * patch.scale;
          const Eigen::Vector2f uv = UvFromTexel(texel.cast<float>(), page.width, page.height);
          out->face_uv[f].row(k) = uv.cwiseMax(0.f).cwiseMin(1.f).transpose();
        }
      }
    } else {
      const int columns = patch.width / cell;
      for (size_t i = 0; i < patch.faces.size(); ++i) {
        const int f = patch.faces[i];
        const float x0 = static_cast<float>(patch.x + static_cast<int>(i % columns) * cell);
        const float y0 = static_cast<float>(patch.y + static_cast<int>(i / columns) * cell);
        out->face_page[f] = patch.page;
        const Eigen::Vector2f corners[3] = {{x0 + 1, y0 + 1}, {x0 + cell - 1, y0 + 1}, {x0 + 1, y0 + cell - 1}};
        for (int k = 0; k < 3; ++k) out->face_uv[f].row(k) = UvFromTexel(corners[k], page.width, page.height).transpose();
      }
    }
  }
  return layout;
}

void CopyPatches(const AtlasLayout& layout, int view, const cv::Mat& image, double gain, TexturedMesh* out) {
  for (const AtlasPatch& patch : layout.patches) {
    if (patch.label != view) continue;
    cv::Mat& page = out->pages[patch.page];
    for (int j = 0; j < patch.height; ++j) {
      cv::Vec3b* row = page.ptr<cv::Vec3b>(patch.y + j) + patch.x;
      for (int i = 0; i < patch.width; ++i) {
        const double px = patch.image_min.x() + (i + 0.5) / patch.scale;
        const double py = patch.image_min.y() + (j + 0.5) / patch.scale;
        if (px < 0 || py < 0 || px > image.cols || py > image.rows) continue;  // outside the photo: black
        const Eigen::Vector3f c = Bilinear(image, px, py) * static_cast<float>(gain);
        row[i] = cv::Vec3b(cv::saturate_cast<uint8_t>(c[0]), cv::saturate_cast<uint8_t>(c[1]), cv::saturate_cast<uint8_t>(c[2]));
      }
    }
  }
}

void ApplyLeveling(const AtlasLayout& layout, const SeamLeveling& leveling, int padding, TexturedMesh* out) {
  // Per page, the offset of each texel from the nearest labelled face (inside first).
  for (size_t page = 0; page < out->pages.size(); ++page) {
    cv::Mat& image = out->pages[page];
    cv::Mat offset(image.size(), CV_32FC3, cv::Scalar::all(0));
    cv::Mat distance(image.size(), CV_32F, cv::Scalar::all(std::numeric_limits<float>::max()));
    for (const AtlasPatch& patch : layout.patches) {
      if (patch.label < 0 || patch.page != static_cast<int>(page)) continue;
      for (int f : patch.faces) {
        Eigen::Vector2f t[3];
        for (int k = 0; k < 3; ++k) t[k] = TexelFromUv(out->face_uv[f].row(k).transpose(), image.cols, image.rows);
        const float det = (t[1] - t[0]).x() * (t[2] - t[0]).y() - (t[1] - t[0]).y() * (t[2] - t[0]).x();
        if (std::abs(det) < 1e-12f) continue;
        const Eigen::Vector3f g[3] = {leveling.Offset(leveling.Variable(f, 0)), leveling.Offset(leveling.Variable(f, 1)),
                                      leveling.Offset(leveling.Variable(f, 2))};
        const Eigen::Vector2f lo = t[0].cwiseMin(t[1]).cwiseMin(t[2]).array() - (padding + 1.f);
        const Eigen::Vector2f hi = t[0].cwiseMax(t[1]).cwiseMax(t[2]).array() + (padding + 1.f);
        const int x0 = std::max(patch.x, static_cast<int>(lo.x())), x1 = std::min(patch.x + patch.width - 1, static_cast<int>(hi.x()));
        const int y0 = std::max(patch.y, static_cast<int>(lo.y())), y1 = std::min(patch.y + patch.height - 1, static_cast<int>(hi.y()));
        for (int y = y0; y <= y1; ++y) {
          for (int x = x0; x <= x1; ++x) {
            const Eigen::Vector2f p(x + 0.5f, y + 0.5f);
            const Eigen::Vector2f d = p - t[0];
            float b1 = (d.x() * (t[2] - t[0]).y() - d.y() * (t[2] - t[0]).x()) / det;
            float b2 = ((t[1] - t[0]).x() * d.y() - (t[1] - t[0]).y() * d.x()) / det;
            float b0 = 1.f - b1 - b2;
            // Outside the face: the weights clamped to it, and the distance to that point.
            float dist = 0;
            if (b0 < 0 || b1 < 0 || b2 < 0) {
              b0 = std::max(b0, 0.f), b1 = std::max(b1, 0.f), b2 = std::max(b2, 0.f);
              const float sum = b0 + b1 + b2;
              b0 /= sum, b1 /= sum, b2 /= sum;
              dist = (b0 * t[0] + b1 * t[1] + b2 * t[2] - p).norm();
            }
            float& best = distance.at<float>(y, x);
            if (dist >= best) continue;
            best = dist;
            const Eigen::Vector3f value = b0 * g[0] + b1 * g[1] + b2 * g[2];
            offset.at<cv::Vec3f>(y, x) = cv::Vec3f(value[0], value[1], value[2]);
          }
        }
      }
    }
    for (int y = 0; y < image.rows; ++y) {
      cv::Vec3b* row = image.ptr<cv::Vec3b>(y);
      const cv::Vec3f* add = offset.ptr<cv::Vec3f>(y);
      for (int x = 0; x < image.cols; ++x) {
        for (int c = 0; c < 3; ++c) row[x][c] = cv::saturate_cast<uint8_t>(row[x][c] + add[x][c]);
      }
    }
  }
}

size_t FillHoles(const AtlasLayout& layout, const std::vector<int>& labels, const FaceObservations& observations,
                 const std::vector<double>& gains, const std::vector<std::array<int, 3>>& adjacency, TexturedMesh* out) {
  const size_t faces = labels.size();
  std::vector<Eigen::Vector3f> color(faces, Eigen::Vector3f::Zero());
  std::vector<char> known(faces, 0);
  for (size_t f = 0; f < faces; ++f) {
    for (const FaceObservation& o : observations[f]) {
      if (o.view == labels[f]) {
        color[f] = o.mean_color * static_cast<float>(gains[o.view]);
        known[f] = 1;
      }
    }
  }
  // Iteratively from coloured neighbours (seed 003 §6 step 3), in waves so the order of faces
  // does not matter.
  std::vector<int> frontier;
  for (size_t f = 0; f < faces; ++f) {
    if (!known[f]) frontier.push_back(static_cast<int>(f));
  }
  while (!frontier.empty()) {
    std::vector<std::pair<int, Eigen::Vector3f>> wave;
    std::vector<int> rest;
    for (int f : frontier) {
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      int count = 0;
      for (int g : adjacency[f]) {
        if (g >= 0 && known[g]) sum += color[g], ++count;
      }
      if (count > 0) wave.emplace_back(f, sum / static_cast<float>(count));
      else rest.push_back(f);
    }
    if (wave.empty()) break;
    for (const auto& [f, c] : wave) color[f] = c, known[f] = 1;
    frontier.swap(rest);
  }
  for (int f : frontier) color[f] = Eigen::Vector3f::Constant(128.f);
  for (const AtlasPatch& patch : layout.patches) {
    if (patch.label >= 0) continue;
    cv::Mat& page = out->pages[patch.page];
    const int cell = patch.width / std::max(1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(patch.faces.size())))));
    const int columns = patch.width / cell;
    for (size_t i = 0; i < patch.faces.size(); ++i) {
      const Eigen::Vector3f& c = color[patch.faces[i]];
      const cv::Rect rect(patch.x + static_cast<int>(i % columns) * cell, patch.y + static_cast<int>(i / columns) * cell, cell, cell);
      page(rect).setTo(cv::Scalar(c[0], c[1], c[2]));
    }
  }
  return frontier.size();
}

double SeamStepInAtlas(const TexturedMesh& textured, const std::vector<int>& labels,
                       const std::vector<std::array<int, 3>>& adjacency) {
  const TriangleMesh& mesh = textured.mesh;
  // Atlas colour of face f at barycentric b.
  const auto color = [&](int f, const Eigen::Vector3f& b) {
    const cv::Mat& page = textured.pages[textured.face_page[f]];
    const Eigen::Vector2f uv = (b[0] * textured.face_uv[f].row(0) + b[1] * textured.face_uv[f].row(1) + b[2] * textured.face_uv[f].row(2)).transpose();
    const Eigen::Vector2f texel = TexelFromUv(uv, page.cols, page.rows);
    return Bilinear(page, texel.x(), texel.y());
  };
  double sum = 0;
  size_t count = 0;
  for (size_t f = 0; f < adjacency.size(); ++f) {
    for (int e = 0; e < 3; ++e) {
      const int g = adjacency[f][e];
      if (g <= static_cast<int>(f) || labels[f] < 0 || labels[g] < 0 || labels[f] == labels[g]) continue;
      // Points on the shared edge (a quarter, half, three quarters along it) in each face's
      // barycentric coordinates: the same surface points, so a perfect atlas gives equal colours.
      const int a = mesh.faces[f][e], b = mesh.faces[f][(e + 1) % 3];
      int ga = 0, gb = 0;
      for (int k = 0; k < 3; ++k) {
        if (mesh.faces[g][k] == a) ga = k;
        if (mesh.faces[g][k] == b) gb = k;
      }
      for (const float t : {0.25f, 0.5f, 0.75f}) {
        Eigen::Vector3f in_f = Eigen::Vector3f::Zero(), in_g = Eigen::Vector3f::Zero();
        in_f[e] = 1 - t, in_f[(e + 1) % 3] = t;
        in_g[ga] = 1 - t, in_g[gb] = t;
        sum += (color(static_cast<int>(f), in_f) - color(g, in_g)).cwiseAbs().mean();
        ++count;
      }
    }
  }
  return count ? sum / count : 0.0;
}

}  // namespace ibmr
