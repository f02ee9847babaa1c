// The textured mesh drawn with its atlas (see textured.h; seed 003 §6 for the hole filling the
// atlas carries).
#include "stages/render/textured.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "pipeline/core/rasterizer.h"

namespace ibmr {

Eigen::Vector3f SampleAtlas(const TexturedMesh& mesh, int face, const Eigen::Vector3f& bary) {
  const Eigen::Matrix<float, 3, 2>& uv = mesh.face_uv[face];
  const Eigen::Vector2f at = (bary.transpose() * uv).transpose();
  const cv::Mat& page = mesh.pages[mesh.face_page[face]];
  const Eigen::Vector2f texel = TexelFromUv(at, page.cols, page.rows);
  return SampleBilinear(page, texel.x(), texel.y());
}

RenderResult RenderTextured(const TexturedMesh& mesh, const Camera& camera, const Rigid3d& cam_from_world,
                            int extend_px) {
  RasterResult raster = Rasterize(mesh.mesh, camera, cam_from_world);
  ExtendIntoHoles(&raster, extend_px);
  RenderResult result;
  result.image = cv::Mat(camera.height, camera.width, CV_8UC3, cv::Scalar::all(0));
  result.coverage = cv::Mat(camera.height, camera.width, CV_8UC1, cv::Scalar::all(0));
  std::vector<size_t> row_covered(camera.height, 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
    for (int y = rows.begin(); y < rows.end(); ++y) {
      uint8_t* out = result.image.ptr<uint8_t>(y);
      uint8_t* covered = result.coverage.ptr<uint8_t>(y);
      for (int x = 0; x < camera.width; ++x) {
        const int face = raster.face_id[static_cast<size_t>(y) * camera.width + x];
        if (face < 0) continue;
        const Eigen::Vector3f bary(raster.barycentric.At(x, y, 0), raster.barycentric.At(x, y, 1),
                                   raster.barycentric.At(x, y, 2));
        const Eigen::Vector3f bgr = SampleAtlas(mesh, face, bary);
        for (int c = 0; c < 3; ++c) out[3 * x + c] = cv::saturate_cast<uint8_t>(bgr[c]);
        covered[x] = 255;
        ++row_covered[y];
      }
    }
  });
  for (const size_t n : row_covered) result.covered_pixels += n;
  return result;
}

}  // namespace ibmr
