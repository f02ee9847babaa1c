// The whole-process peer of `ibmr stereo-pair` for bench_process_start: a plain OpenCV program that
// reads a rectified pair (grey), runs StereoSGBM with bench_stereo_pair's settings (blockSize 5,
// P1 8*25, P2 32*25, MODE_SGBM) and writes the left disparity as PFM (little-endian, rows bottom
// to top; <= 0 where SGBM gives none). What a user of OpenCV would write; nothing of ibmr in it.
// Usage: peer_sgbm_pair LEFT RIGHT NUM_DISPARITIES OUT.pfm
#include <cstdio>
#include <cstdlib>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s LEFT RIGHT NUM_DISPARITIES OUT.pfm\n", argv[0]);
    return 2;
  }
  const cv::Mat left = cv::imread(argv[1], cv::IMREAD_GRAYSCALE), right = cv::imread(argv[2], cv::IMREAD_GRAYSCALE);
  if (left.empty() || right.empty()) {
    std::fprintf(stderr, "cannot read %s or %s\n", argv[1], argv[2]);
    return 1;
  }
  const int disparities = std::atoi(argv[3]);
  cv::Mat raw, disparity;
  cv::StereoSGBM::create(0, disparities, 5, 8 * 25, 32 * 25)->compute(left, right, raw);
  raw.convertTo(disparity, CV_32F, 1.0 / 16.0);
  std::FILE* out = std::fopen(argv[4], "wb");
  if (!out) return 1;
  std::fprintf(out, "Pf\n%d %d\n-1\n", disparity.cols, disparity.rows);
  for (int y = disparity.rows - 1; y >= 0; --y) std::fwrite(disparity.ptr<float>(y), sizeof(float), disparity.cols, out);
  return std::fclose(out) == 0 ? 0 : 1;
}
