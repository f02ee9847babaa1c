// PNG files encoded with libdeflate, holding the pixels OpenCV's imwrite would write, in 0.6-0.8 of
// its time. Why: writing PNGs was a measured hot spot (the score stage spent ~40% of its CPU in
// zlib's deflate, writing its side-by-side images through imwrite; the render stage writes
// hundreds), and libdeflate compresses the same rows faster at about the same size.
//
// The file is what imwrite writes by default, but for the deflate coder: 8 or 16 bits per sample,
// grey, RGB or RGBA (a BGR / BGRA Mat's channels reordered, 16-bit samples big-endian), not
// interlaced, every row with the SUB filter (type 1). Chunks: IHDR, IDAT (the zlib stream from
// libdeflate_zlib_compress, cut every 1 MiB), IEND; nothing else (no gamma, no text). Decoders
// read back the Mat's pixels exactly; the bytes differ from imwrite's (another deflate coder).
#pragma once

#include <opencv2/core.hpp>
#include <string>

namespace ibmr {

// libdeflate's level (0-12; 1 fastest) for EncodePng. Measured against imwrite (zlib level 1,
// Z_RLE) on templeRing's outputs: level 1 takes 0.60-0.82 of its time on colour images (1920x480
// side by side images 16.7 / 15.2 ms against 25.3 / 18.4, 640x480 renders 4.4-4.6 against 5.8-6.7,
// a 4096x1732 atlas page 163 against 215) at sizes from 4% smaller to 2.3% larger; nearly flat grey
// masks take 0.2 ms longer (0.85 against 0.62-0.68 ms). Levels 2-4 save 1-2% more bytes for 15-50% more time.
constexpr int kPngDeflateLevel = 1;

// True for the Mat types EncodePng writes: CV_8U or CV_16U with 1 (grey), 3 (BGR) or 4 (BGRA)
// channels, any size above zero, continuous or not (an ROI).
bool CanEncodePng(const cv::Mat& image);

// Encodes `image` as a PNG file's bytes into `bytes` (see above). False, with `bytes` empty, when
// CanEncodePng is false or libdeflate cannot allocate its compressor: the caller then asks OpenCV.
bool EncodePng(const cv::Mat& image, std::string* bytes, int level = kPngDeflateLevel);

}  // namespace ibmr
