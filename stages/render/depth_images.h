// Multiple depth images as a scene model (Nyland et al., seed 004; seed 000 lines 5812-5905):
// per source image its colour, z depth, confidence and a flag byte per pixel ([N 4.3], lines
// 135-139), silhouette "skins" found by warping one depth image into another ([N 4.4], lines
// 145-152), and redundant samples culled by 32x32 tiles ranked by quality ([N 4.5-4.6], lines
// 158-170). The splat renderer (splat.h) draws what is left.
//
// Skins and outliers. A regular mesh through a depth image's pixels connects, across a depth step, a foreground
// sample to a background one: a false surface. A depth image B says that space is empty in front of
// its surface, so a connection of image A whose interior lies in front of B's depth (by more than
// a relative tolerance) crosses space B saw empty: it is a skin, and both its end samples are
// flagged. The paper finds them by rasterizing A's mesh into B and comparing z-buffers; here each
// connection (right and down neighbours) is tested directly at its midpoint and quarter points,
// which needs no repeated warps when one skin hides another. A sample that itself lies in front of
// other views' depth is an outlier: fattened silhouettes in stereo depth maps put background
// colours at foreground depth, and another view sees through them. Where no view sees through a
// fattened sample (it lies on the object's surface, seen from the side), its colour gives it away:
// the views that see that surface point see the object's colour, not the background's. (These two
// tests extend the paper's flags for stereo depth; its range scanner had no fattening.)
//
// Merging. A sample's quality is its sampling density on the surface: confidence * |cos| / z^2
// (the paper's "range and viewing angle"). A tile's rank is the mean quality of its drawable samples
// times the fraction that is neither a skin nor of low confidence. Tiles are visited from worst to
// best; each drawable sample is projected into the other images, and where one of them holds the
// same surface (|z - z_B| <= tolerance * z at the nearest pixel) with a drawable sample of higher
// quality, the sample is culled. Quality is a strict order, so the best sample of a surface point
// is never culled: merging removes redundancy, not surface.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "pipeline/core/camera.h"
#include "pipeline/core/float_map.h"
#include "pipeline/core/rigid3.h"

namespace ibmr {

// Flag bits of a depth-image pixel [N 139].
enum DepthSampleFlag : uint8_t {
  kSampleInvalid = 1,         // no depth or no colour
  kSampleLowConfidence = 2,   // confidence below the threshold
  kSampleSkin = 4,            // an end of a connection that crosses space another view saw empty
  kSampleMerged = 8,          // culled: another image holds the same surface better
  kSampleFreeSpace = 16,      // lies where other views saw empty space (an outlier, a fattened edge)
  kSampleInconsistent = 32,   // its colour disagrees with most views that see the same surface
};

// A sample that is drawn: neither invalid, low-confidence, nor merged away (skins are drawn: they
// are real samples, only their connections are false).
inline bool IsDrawable(uint8_t flags) {
  return (flags & (kSampleInvalid | kSampleLowConfidence | kSampleMerged | kSampleFreeSpace | kSampleInconsistent)) == 0;
}

struct DepthImage {
  std::string name;
  Camera camera;           // pinhole, at the depth map's resolution
  Rigid3d cam_from_world;
  cv::Mat image;           // CV_8UC3 at the depth map's resolution
  DepthMap depth;          // z depth; <= 0: none
  FloatMap confidence;     // 1 channel in [0, 1]; empty: every sample 1
  FloatMap normals;        // 3 channels, camera frame, towards the camera; empty or 0: unknown
  std::vector<uint8_t> flags;  // width * height, row-major

  int width() const { return depth.width; }
  int height() const { return depth.height; }
  float Confidence(int x, int y) const { return confidence.Empty() ? 1.f : confidence.At(x, y); }
};

struct DepthImageOptions {
  double min_confidence = 0.0;    // samples below: kSampleLowConfidence, in [0, 1]
  double skin_tolerance = 0.02;   // relative free-space margin of the skin test, in (0, 1)
  int skin_views = 8;             // nearest images each image is tested against (0: no skin test), in [0, 64]
  int free_space_views = 2;       // a sample in front of this many of those images' depth is an outlier
                                  // (0: kept), in [0, 64]
  int color_tolerance = 0;        // a sample whose colour differs by more than this (largest channel, 0-255)
                                  // from most of those images that see it on their surface is an outlier
                                  // (0: no colour test), in [0, 255]
  bool merge = true;              // cull redundant samples by ranked tiles
  double merge_tolerance = 0.01;  // relative depth agreement of two samples of one surface, in (0, 1)
  int merge_views = 8;            // nearest images a sample is compared with, in [1, 64]
  int tile_size = 32;             // tile side in pixels [N 159], in [4, 256]

  bool Check(std::string* error) const;  // error starts with the YAML key
};

// Sets kSampleInvalid and kSampleLowConfidence (clears every other flag).
void FlagSamples(DepthImage* image, double min_confidence);

// For each image, the indices of the `count` other images whose viewing directions are nearest
// (smallest angle), nearest first.
std::vector<std::vector<int>> NearestImages(const std::vector<DepthImage>& images, int count);

// [N 4.4] Flags kSampleSkin on both ends of every skin connection, kSampleFreeSpace on samples
// that lie in front of the depth of `free_space_views` of the tested images (the same free-space
// argument applied to a sample instead of a connection), and kSampleInconsistent on samples whose
// colour disagrees with more than half of the tested images that hold the same surface (at least
// one). Returns the skin connections found; `outliers` (optional) receives the samples flagged
// kSampleFreeSpace or kSampleInconsistent.
size_t DetectSkins(std::vector<DepthImage>* images, const DepthImageOptions& options, size_t* outliers = nullptr);

// [N 4.6] Flags kSampleMerged on culled samples; returns the number culled.
size_t MergeTiles(std::vector<DepthImage>* images, const DepthImageOptions& options);

// Per-sample quality (sampling density): confidence * |cos(normal, ray)| / z^2; 0 where not drawable.
float SampleQuality(const DepthImage& image, int x, int y);

// A sparser depth image for model selection ("splats at several densities"): one sample per
// factor x factor block, its depth the median of the block's depths (none when fewer than half have
// one), its colour the mean of the block's pixels on that surface (within 5% of the median depth),
// normal from the pixel nearest the median, confidence the block's mean; the camera scaled to the
// new size. Flags are not carried: FlagSamples again. factor 1 returns the image as it is.
DepthImage DownsampleDepthImage(const DepthImage& image, int factor);

}  // namespace ibmr
