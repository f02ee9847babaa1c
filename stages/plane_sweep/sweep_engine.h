// The engine shared by multi-view plane sweep and two-view stereo: a cost volume over planes
// (one plane = one homography per neighbour view; for a rectified pair the plane of disparity d
// is the shift by -d), filled plane by plane (streamed: only one plane's slices are live per
// worker), semi-global aggregation, winner-take-all with parabola sub-pixel refinement and a
// certainty from the cost curve.
//
// Follows seed 000, lines 5300-5525 (Kang et al. course notes section 2, "Depth maps": a cost in
// generalized disparity space, aggregation over a support window, winner-take-all, sub-pixel
// refinement, certainty), lines 3659-3760 (dense stereo by matching along epipolar lines over a
// disparity/plane range) and lines 4352-4453 (section 4: sub-pixel minimum by fitting a parabola
// to the cost around the integer minimum; its curvature gives the variance). The census cost is
// Zabih & Woodfill (ECCV 1994); the semi-global aggregation is Hirschmueller (PAMI 2008), with
// costs as uint16 so the inner loops vectorise over planes.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "pipeline/core/cpu_isa.h"
#include "pipeline/core/large_buffer.h"
#include "stages/plane_sweep/cost_curve_confidence.h"

namespace ibmr {
namespace sweep {

// Matching cost units: 0 = perfect match, about 1000 = worst match (census: 16 per differing
// bit of a 62-bit code; SAD: 4 per grey level; ZNCC: 500 * (1 - ncc)).
constexpr uint16_t kMaxCost = 1023;

enum class Cost { kCensus, kSad, kZncc };

// How the census cost of a warped neighbour reads its codes around the correspondence (u, v),
// which falls between pixels: the cost is the Hamming distances to the codes around it, weighted.
//  * kAlongEpipolar: linearly between the two codes on either side along the axis (rows or
//    columns) the neighbour's epipolar lines run closer to, at the nearest row (column) across
//    it. From plane to plane the correspondence moves along the epipolar line, so the cost curve
//    is as smooth in the plane index as the bilinear one's where it matters for the sub-plane
//    parabola; across the line the nearest code is a fixed offset of at most half a pixel, which
//    the census window's 9 x 7 pixels absorb. The AVX-512 build's lane kernel then reads half
//    the codes of kBilinear (the other builds read four, two of them weighted 0: same costs).
//  * kBilinear: the four codes around it, weighted bilinearly.
// Rectified pairs (integer shifts) read one code either way.
enum class CensusSampling { kAlongEpipolar, kBilinear };

struct EngineOptions {
  Cost cost = Cost::kCensus;
  int census_radius_x = 4;   // census window half width (9x7 -> 62 bits)
  int census_radius_y = 3;
  CensusSampling census_sampling = CensusSampling::kAlongEpipolar;
  int window_radius = 1;     // box aggregation radius per neighbour, pixels (0: none)
  int best_k = 2;            // per pixel and plane, average of the k lowest neighbour costs
  bool semi_global = true;   // false: box window only (winner-take-all on the box costs)
  int paths = 8;             // semi-global paths, 4 or 8
  int p1 = 120;              // small-jump penalty, cost units
  int p2 = 900;              // large-jump penalty, cost units
  double p2_gamma = 12.0;    // P2 is divided by (1 + |grey step| / gamma); 0: constant P2
  // 2: each semi-global pass steps its paths on two threads (the row path, the one from above and
  // one diagonal on a helper thread, the other diagonal a row behind), for a sweep that has the
  // cores to itself (one view in flight when memory is short); the same sums and winners as 1.
  int sgm_threads = 1;
};

// Cost volume: layout [y][x][plane], `stride` >= planes (multiple of 16, padding at kMaxCost).
struct CostVolume {
  int width = 0, height = 0, planes = 0, stride = 0;
  LargeBuffer<uint16_t> data;
  // Per pixel (row-major), 1 where the pixel is not matched (its plane range is empty, see
  // PlaneRanges); empty: every pixel is. BuildCostVolume sets it. Such a pixel's costs still carry
  // the semi-global paths across it, but its own path sums are not kept and it has no winner.
  std::vector<uint8_t> unmatched;
  // Where each pixel's costs lie in `data` (row-major, one entry per pixel), or kNotStored: the
  // pixel's curve is `flat` (`stride` entries, all one cost: the semi-global passes step a path
  // across a run of such pixels at once), which `data` does not repeat; empty: pixel p at
  // p * stride. BuildCostVolume leaves out the unmatched pixels no matched one reaches through the
  // box filter (their filtered curve stays flat), when plane ranges leave some out.
  static constexpr uint32_t kNotStored = 0xFFFFFFFFu;
  std::vector<uint32_t> slots;
  std::vector<uint16_t> flat;
  bool Matched(size_t pixel) const { return unmatched.empty() || unmatched[pixel] == 0; }
  bool Stored(size_t pixel) const { return slots.empty() || slots[pixel] != kNotStored; }
  // A pixel's costs; only a stored pixel's may be written (a pixel not stored points at `flat`).
  uint16_t* At(int x, int y) { return const_cast<uint16_t*>(static_cast<const CostVolume&>(*this).At(x, y)); }
  const uint16_t* At(int x, int y) const {
    const size_t pixel = static_cast<size_t>(y) * width + x;
    if (slots.empty()) return data.data() + pixel * stride;
    return slots[pixel] != kNotStored ? data.data() + static_cast<size_t>(slots[pixel]) * stride : flat.data();
  }
};

// A neighbour: its grey image and one homography per plane mapping reference pixel coordinates
// (pixel centre at +0.5) to the neighbour's.
struct Neighbour {
  cv::Mat gray;  // CV_8UC1
  std::vector<Eigen::Matrix3d> homographies;
  // Optional: CensusTransform(gray, census_radius_x, census_radius_y) computed by the caller, who
  // matches each view against several references and so transforms it once (null: computed here).
  std::shared_ptr<const std::vector<uint64_t>> census;
};

// A neighbour held upside down against the reference (rolled more than 90 degrees about its axis,
// as templeRing's templeR0040 is against the views beside it): a census code lists its window's
// comparisons in the image's own raster order, so in a half-turned image the comparison with
// offset (dx, dy) sits where the reference keeps (-dx, -dy). Its codes are compared with their
// bits reversed (the window is symmetric about its centre, so the reversed order is the
// reference's). Uncorrected, the Hamming distances at the true plane are those of unrelated codes
// and the view's depth fails (templeR0040: confirmed fraction 0.15 against a median of 0.87).
// A quarter turn (portrait among landscape photos) has no such fix with a 9x7 window.
//
// Whether a neighbour at `neighbour_rotation` (cam_from_world) is held upside down against a
// reference at `reference_rotation`: its image x and y axes turned more than 90 degrees from the
// reference's about the viewing direction (the trace of the relative rotation's image-plane block
// is negative).
bool IsHalfTurned(const Eigen::Matrix3d& reference_rotation, const Eigen::Matrix3d& neighbour_rotation);

// `codes` (CensusTransform with `bits` comparisons each) as a half-turned image's codes read in
// the upright image's order: each code's low `bits` bits reversed.
std::vector<uint64_t> ReverseCensusBits(const std::vector<uint64_t>& codes, int bits);

// Per-pixel plane ranges (row-major, one entry per reference pixel): the pixel's surface lies on
// planes first..last (inclusive), as a hull bounds it; first > last: no surface (the pixel is not
// matched). Planes outside a pixel's range take the mean of its in-range costs, neutral for the
// aggregation and for the certainty (the curve's mean is the in-range mean); an unmatched pixel's
// curve is flat (no certainty). The census cost's box filter runs after the ranges are applied, so
// near a range's edge (and near a matched pixel) it mixes in the neighbours' curves; SAD and ZNCC
// apply the ranges last. With the census cost only in-range planes (in blocks of 16) are
// evaluated.
struct PlaneRanges {
  std::vector<uint16_t> first, last;
  // Whether `pixel` has no plane of the sweep's `planes` in its range (it is not matched).
  bool Empty(size_t pixel, int planes) const { return first[pixel] > std::min<int>(last[pixel], planes - 1); }
};

// The matching costs' work in one volume: plane-pixel-neighbour evaluations done, and the CPU
// time the threads spent on them (census: the loop that evaluates and combines the neighbours'
// costs, and fills each pixel's planes outside its range while they are in cache, summed over the
// threads that ran it; not the census transforms or the box filter). evaluations / seconds is the
// evaluations per second of one core at it. `box_filter_seconds`: the threads' CPU time in the
// census volume's box filter, summed the same way (each task times its own work: a thread that
// waits inside a parallel loop may run other tasks, which a clock around the loop would count).
struct VolumeWork {
  int64_t evaluations = 0;
  double seconds = 0;
  double box_filter_seconds = 0;
};

// CPU time of the calling thread, seconds (the clock VolumeWork's times come from).
double ThreadCpuSeconds();

// Fills the matching-cost volume (reusing `volume`'s buffers when large enough): costs of all
// neighbours per plane, best-k combined; `ranges` (optional) limits the planes per pixel.
// `reference_census` (optional) is CensusTransform(reference_gray) like Neighbour::census.
// `origin`: where pixel (0, 0) of `reference_gray` (and of the volume) lies in the image whose pixel
// coordinates the homographies take, when the volume covers only a part of it (a crop or a band):
// the census cost then projects each pixel from exactly the coordinates of the whole image, so the
// part's costs are those of the same pixels in the whole (with `reference_census` the whole
// image's codes of the part: a census window must not be cut at the part's edge).
VolumeWork BuildCostVolume(const cv::Mat& reference_gray, const std::vector<Neighbour>& neighbours,
                           const EngineOptions& options, CostVolume* volume, const PlaneRanges* ranges = nullptr,
                           const std::vector<uint64_t>* reference_census = nullptr, cv::Point origin = cv::Point(0, 0));

// Aggregated volume: the sum over paths (or the data cost itself without semi-global).
struct Aggregated {
  int width = 0, height = 0, planes = 0, stride = 0;
  // The forward and backward passes' partial sums; with b empty, a holds the whole sum (one
  // buffer, or no semi-global aggregation).
  LargeBuffer<uint16_t> a, b;
  std::vector<uint8_t> unmatched;  // the volume's: these pixels' sums are unspecified
  bool Matched(size_t pixel) const { return unmatched.empty() || unmatched[pixel] == 0; }
  uint16_t Sum(size_t pixel, int plane) const {
    const size_t i = pixel * stride + plane;
    return b.empty() ? a[i] : static_cast<uint16_t>(a[i] + b[i]);
  }
};
// `out` may hold buffers of an earlier call: they are reused (no new pages to fault in). The sums
// of pixels the volume marks unmatched are left unspecified (neither read nor written: most of a
// view where the scene's bounds leave its background unmatched).
// The forward and backward passes run at once into `a` and `b`, or, with `one_buffer`, one after
// the other into `a` alone (the backward pass adds to it): half the memory and half the pages to
// fault in, for callers that already keep the cores busy with several sweeps, which lose nothing
// by running the passes one after the other (the multi-view stage goes further: AggregateAndPick).
void Aggregate(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options, Aggregated* out,
               bool one_buffer = false);

// Per-pixel winner: plane index with sub-pixel offset (-1 where undefined, as at unmatched pixels),
// and certainty in [0, 1] from the data-cost curve (CurveConfidence, cost_curve_confidence.h: how
// far the winner's matching cost lies below the curve's mean, times, when enabled, how clearly it
// beats the best other local minimum; 0 at unmatched pixels).
// Two-view only, `right`: the winner of each right-view pixel from the same aggregated volume
// (plane = disparity: right pixel xr matches left pixel xr + d), integer disparities, -1 where
// undefined; found in the same pass over the volume.
struct Winners {
  cv::Mat plane;       // CV_32F, sub-pixel plane index, -1: none
  cv::Mat confidence;  // CV_32F in [0, 1]: the certainty (margin times peak ratio)
  cv::Mat margin;      // CV_32F in [0, 1]: its margin factor alone (whether there is a match)
  cv::Mat right;       // CV_32S, with `right_winners` only
};
// `data_cost` nullptr: no confidence (left at 0).
Winners WinnerTakeAll(const Aggregated& aggregated, const CostVolume* data_cost, const CertaintyOptions& certainty,
                      bool right_winners = false);

// The winners of Aggregate(one_buffer) and WinnerTakeAll(data_cost = volume), found without the
// second pass over the sums: the forward pass stores the matched pixels' sums in `sums`, one after
// the other in scan order (reused like Aggregated's buffers; a buffer with the capacity of a whole
// view touches only the pages of the matched pixels' share), and the backward pass, which
// completes each matched pixel's sum, picks its winner at once instead of storing the sum.
// Without semi-global passes the winners come from the volume itself and `sums` is left empty.
// Same winners and certainties. The picking runs inside the backward pass, on one thread
// (WinnerTakeAll's search is spread over the rows): for callers that keep the cores busy with
// several sweeps, as the multi-view stage does; with options.sgm_threads 2 each pass's paths are
// split over two threads (one sweep at a time).
Winners AggregateAndPick(const CostVolume& volume, const cv::Mat& reference_gray, const EngineOptions& options,
                         const CertaintyOptions& certainty, LargeBuffer<uint16_t>* sums);

// Cost-volume buffers lent from a process-wide pool, so that consecutive views (or pairs) reuse
// already-faulted pages; at most one set per concurrently running sweep is alive.
struct Buffers {
  CostVolume volume;
  Aggregated aggregated;
};
class BufferLease {
 public:
  BufferLease();
  ~BufferLease();
  BufferLease(const BufferLease&) = delete;
  BufferLease& operator=(const BufferLease&) = delete;
  Buffers* operator->() { return buffers_.get(); }

 private:
  std::unique_ptr<Buffers> buffers_;
};
// Frees the pooled buffers (call when a stage is done).
void ReleaseBufferPool();

// The engine's loops exist in three builds (sweep_kernels.cc): portable (the baseline instruction
// set), AVX2 (16 x 16-bit lanes for aggregation, 8 floats for the projections) and AVX-512
// (gathers and VPOPCNTQ for the census cost, 32 x 16-bit lanes). The best one the CPU runs is
// chosen at start-up (IBMR_ISA=portable or avx2 in the environment forces that one, where the
// CPU runs it); all give bit-identical volumes, winners and depth maps.
using ::ibmr::Isa;      // pipeline/core/cpu_isa.h
using ::ibmr::IsaName;
bool IsaSupported(Isa isa);  // the CPU runs it and this build has it
Isa BestIsa();     // the fastest build this CPU runs
Isa ActiveIsa();   // the build in use
bool SetIsa(Isa isa);  // false (and no change) when the CPU cannot run `isa`

// Census codes of a grey image (bit set where the neighbour is darker than the centre).
std::vector<uint64_t> CensusTransform(const cv::Mat& gray, int radius_x, int radius_y);  // row-major

}  // namespace sweep
}  // namespace ibmr
