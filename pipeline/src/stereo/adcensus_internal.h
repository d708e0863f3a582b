// Stages of the AD-Census matcher, exposed for tests (brute-force reference
// checks) and for the orchestration in adcensus.cc. Not a public API.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <memory>
#include <new>
#include <opencv2/core/mat.hpp>
#include <utility>
#include <vector>

#include "common/parallel.h"
#include "craftscan/pipeline/stereo/adcensus.h"

namespace craftscan::adcensus {

// Mei's colour difference D_c: the largest absolute channel difference.
inline int ColourDiff(const std::uint8_t* a, const std::uint8_t* b, int channels) {
  int d = std::abs(a[0] - b[0]);
  for (int c = 1; c < channels; ++c) d = std::max(d, std::abs(a[c] - b[c]));
  return d;
}

// Costs are 16-bit fixed point: kCostScale is 1.0 on Mei's cost scale, so a
// matching cost (ρ_AD + ρ_census, in [0, 2]) is at most 2·kCostScale, a
// scanline path value at most 2·kCostScale + Π2·kCostScale, and the sum of the
// four paths stays below 32767 for Π2 ≤ 6 (Mei's Π2 is 3). Integer sums are
// exact, so no pass depends on the order in which threads visit pixels.
using Cost = std::int16_t;
inline constexpr int kCostScale = 1000;

// Cost volume laid out [y][x][d] with the disparity axis padded to a
// multiple of 16 costs (32 B) so that inner loops over d vectorize. Padding
// lanes hold kPadCost: more than any real scanline value, so they never win
// a minimum (arithmetic on them saturates).
//
// Per-pixel ranges: with offsets set, pixel (y, x) holds disparity indices
// offset(y, x) … offset(y, x) + ndisp − 1 of a band of total_ndisp() (its
// lane k is index offset + k); ndisp is then a multiple of 16 (no padding
// lanes) and 0 ≤ offset ≤ total_ndisp − ndisp. Without offsets every pixel
// holds the whole band (offset 0, total_ndisp = ndisp). Disparity maps are
// always in indices of the whole band.
class CostVolume {
 public:
  static constexpr Cost kPadCost = 16383;
  CostVolume() = default;
  CostVolume(int width, int height, int ndisp) { Reshape(width, height, ndisp); }
  // Sets the dimensions and clears the offsets; reallocates only when the
  // capacity is too small. Contents are unspecified afterwards.
  void Reshape(int width, int height, int ndisp);
  // Per-pixel offsets (width × height, row-major) within a band of
  // total_ndisp indices; see above.
  void SetOffsets(std::vector<std::int32_t> offsets, int total_ndisp);
  void CopyOffsetsFrom(const CostVolume& other) {
    offsets_ = other.offsets_;
    total_ndisp_ = other.total_ndisp_;
  }
  void swap(CostVolume& other) noexcept {
    std::swap(width_, other.width_);
    std::swap(height_, other.height_);
    std::swap(ndisp_, other.ndisp_);
    std::swap(stride_, other.stride_);
    std::swap(capacity_, other.capacity_);
    std::swap(total_ndisp_, other.total_ndisp_);
    offsets_.swap(other.offsets_);
    data_.swap(other.data_);
  }
  static int StrideFor(int ndisp) { return (ndisp + 15) / 16 * 16; }
  int width() const { return width_; }
  int height() const { return height_; }
  int ndisp() const { return ndisp_; }    // disparities held per pixel
  int stride() const { return stride_; }  // costs between consecutive pixels
  int total_ndisp() const { return total_ndisp_; }
  bool has_offsets() const { return !offsets_.empty(); }
  // Offsets of row y (null without offsets).
  const std::int32_t* offset_row(int y) const {
    return offsets_.empty() ? nullptr : offsets_.data() + static_cast<std::size_t>(y) * width_;
  }
  int offset(int y, int x) const {
    return offsets_.empty() ? 0 : offsets_[static_cast<std::size_t>(y) * width_ + x];
  }
  Cost* at(int y, int x) {
    return data_.get() + (static_cast<std::size_t>(y) * width_ + x) * stride_;
  }
  const Cost* at(int y, int x) const {
    return data_.get() + (static_cast<std::size_t>(y) * width_ + x) * stride_;
  }
  Cost* row(int y) { return at(y, 0); }

 private:
  struct Free {
    void operator()(Cost* p) const { std::free(p); }
  };
  int width_ = 0, height_ = 0, ndisp_ = 0, stride_ = 0, total_ndisp_ = 0;
  std::vector<std::int32_t> offsets_;
  std::size_t capacity_ = 0;  // costs
  std::unique_ptr<Cost[], Free> data_;
};

// Census transform over a win_w × win_h window (≤ 65 positions; the centre is
// skipped): bit k is set when neighbour k is darker than the centre. Borders
// replicate. One word per pixel, row-major, into *census (its memory reused
// when large enough), or returned.
void CensusTransform(const cv::Mat& grey, int win_w, int win_h, const Parallel& parallel,
                     std::vector<std::uint64_t>* census);
std::vector<std::uint64_t> CensusTransform(const cv::Mat& grey, int win_w, int win_h,
                                           const Parallel& parallel);

// Matching cost ρ(C_AD, λ_AD) + ρ(C_census, λ_census), ρ(c, λ) = 1 − exp(−c/λ),
// with C_AD the mean absolute difference over the channels, in fixed point:
// each ρ term rounded to 1/kCostScale. Disparities whose right pixel falls
// outside the image get `out_of_image_cost` (on the [0, 2] scale).
// Computes a row of the volume at a time, so that a pass that needs the
// costs again can recompute a row instead of keeping the volume. Keeps
// references to its arguments. Row() is thread-safe with one Scratch per
// thread.
class CostComputer {
 public:
  struct Scratch {  // per-thread working memory, sized on first use
    std::vector<std::uint64_t> rev_census;
    std::vector<std::int32_t> rev_colour, hamming;
    std::vector<std::int16_t> rev_colour16;
  };
  CostComputer(const cv::Mat& left, const cv::Mat& right,
               const std::vector<std::uint64_t>& census_left,
               const std::vector<std::uint64_t>& census_right, int min_disparity, int ndisp,
               double lambda_ad, double lambda_census, double out_of_image_cost);
  // Writes row y: width × stride costs, padding lanes kPadCost. With
  // `offsets` (row y's per-pixel offsets, may be null) pixel x's lane k is
  // disparity min_disparity + offsets[x] + k.
  void Row(int y, Scratch* scratch, Cost* out, const std::int32_t* offsets = nullptr) const;

 private:
  const cv::Mat& left_;
  const cv::Mat& right_;
  const std::vector<std::uint64_t>& census_left_;
  const std::vector<std::uint64_t>& census_right_;
  int min_disparity_, ndisp_, stride_;
  Cost outside_;
  int ad_size_;                    // entries of the AD table: 255 · channels + 1
  std::vector<std::int32_t> lut_;  // ρ_AD + ρ_census, [hamming][sum of differences]
  // The same terms apart, for the in-register look-ups (PermuteRow): ρ_AD
  // for sums 0 … 255 (it is constant from 255 on when permute_ is set) and
  // ρ_census for Hamming distances 0 … 64.
  std::int16_t ad16_[256] = {};
  std::int16_t census16_[65] = {};
  bool permute_ = false;
  void PermuteRow(int y, Scratch* scratch, Cost* out, const std::int32_t* offsets) const;
  // Without AVX-512 (AVX2): ρ_AD + ρ_census as 16-bit entries
  // [hamming · 256 + min(sum, 255)] (33 kB) when ρ_AD saturates by 255 and
  // every cost fits 16 bits; empty otherwise.
  std::vector<std::int16_t> lut16_;
  void TableRow(int y, Scratch* scratch, Cost* out, const std::int32_t* offsets) const;
};

// The whole volume, row by row in parallel (*cost shaped by the caller).
void ComputeCost(const CostComputer& computer, const Parallel& parallel, CostVolume* cost);
void ComputeCost(const cv::Mat& left, const cv::Mat& right,
                 const std::vector<std::uint64_t>& census_left,
                 const std::vector<std::uint64_t>& census_right, int min_disparity,
                 double lambda_ad, double lambda_census, float out_of_image_cost,
                 const Parallel& parallel, CostVolume* cost);

// Cross arms of every pixel: the number of pixels the arm extends beyond the
// anchor in each direction (0 … max length).
struct Arms {
  int width = 0, height = 0;
  std::vector<std::uint8_t> left, right, up, down;
  std::size_t index(int y, int x) const { return static_cast<std::size_t>(y) * width + x; }
  // BuildArms's working memory, kept for the next call: the image's planes
  // and the colour differences between neighbouring rows.
  std::vector<cv::Mat> planes;
  std::vector<std::uint8_t> vertical_diff;
};

// Builds arms on `image` (CV_8UC1/CV_8UC3) with the classic rule, or with the
// improved rule when `gradient` (CV_32FC1) is given; `edges` (CV_8UC1, may be
// empty) marks extra edge pixels for the improved rule.
Arms BuildArms(const cv::Mat& image, const cv::Mat& gradient, const cv::Mat& edges,
               const ADCensusOptions& options, const Parallel& parallel);
// The same into *arms, reusing its memory (a matcher's next call).
void BuildArms(const cv::Mat& image, const cv::Mat& gradient, const cv::Mat& edges,
               const ADCensusOptions& options, const Parallel& parallel, Arms* arms);

// True when pixel (y, x) counts as an edge pixel under the improved rule.
bool IsEdgePixel(const cv::Mat& gradient, const cv::Mat& edges, int y, int x,
                 const ImprovedArmOptions& options);

// Per-pixel factors of the aggregation's passes (arm segment lengths along
// each axis, their inverses, 1 / support size for each iteration order) and
// their working memory; a matcher keeps one between calls (a fresh one is
// megabytes of new pages to fault in and zero each call).
struct PassFactors {
  std::vector<std::int32_t> len_h, len_v, down_column;
  std::vector<float> inv_len_h, inv_len_v, inv_support_h, inv_support_v;
};

// Cross-based aggregation, `iterations` passes alternating horizontal-first
// (even) and vertical-first (odd); each result is normalized by the number of
// pixels in the support region and rounded to the nearest integer cost.
// `factors`: working memory (may be null: a temporary one).
// With `source`, the matching costs are not read from *cost but computed row
// by row by `source` as the first (horizontal) pass takes them, while each
// row is in cache: the volume is written once, with the pass's output, and
// never holds the raw costs. The result is the same as ComputeCost then
// Aggregate.
void Aggregate(const Arms& arms, int iterations, const Parallel& parallel, CostVolume* cost,
               PassFactors* factors = nullptr, const CostComputer* source = nullptr);

// Support-region pixel count of (y, x) for horizontal-first (true) or
// vertical-first aggregation.
int SupportSize(const Arms& arms, int y, int x, bool horizontal_first);

// Four-direction scanline optimization (Mei et al.) fused with the
// winner-take-all. The aggregated costs C come from `cost`, or, when `cost`
// is nullptr, from `recompute` row by row (the matching costs, never stored
// as a volume; *result, shaped and offset by the caller, then only receives
// the sums). On return *result holds the sum of the four path costs (4× Mei's
// mean; the refinement reads it), and the integer disparity indices of the
// left and right views are as WinnerTakeAll gives them. Penalties depend on
// colour differences in both images. *result is reshaped as needed when
// `cost` is given. With up to two threads it sweeps whole rows (two sweeps,
// one per thread); with more, it passes over the volume in bands of columns
// and then rows, split between all of them. Both give the same result.
// With `runner_up` (may be null) it also gives each left pixel's winning and
// runner-up costs (RunnerUpCost) while the sum is in cache (CV_32SC2), which
// the refinement's uniqueness test would otherwise read from the volume again.
// With `winner_sums` (may be null) likewise the final sums at the winning
// lane and its two neighbours, S(k − 1), S(k), S(k + 1) (CV_16SC3; 0 where a
// neighbour lies outside the lanes), for the sub-pixel step.
// With `recompute` and `store` (may be null) on up to two threads, each
// row's costs are computed once, by the sweep that reaches the row first,
// into *store (reshaped like *result), and the other sweep reads them there
// instead of computing them again.
void ScanlineOptimize(const cv::Mat& left, const cv::Mat& right, int min_disparity,
                      const ADCensusOptions& options, const Parallel& parallel,
                      const CostVolume* cost, const CostComputer* recompute, CostVolume* result,
                      cv::Mat* left_index, cv::Mat* right_index, cv::Mat* runner_up = nullptr,
                      cv::Mat* winner_sums = nullptr, CostVolume* store = nullptr);

// The uniqueness test's runner-up: the least of c[j] over the disparities a
// pixel holds (j < n) at least 2 from its winner k (|j − k| ≥ 2; the winner's
// neighbours are the same minimum, blurred), or kNoRunnerUp when there is
// none. c holds `stride` costs (a multiple of 16).
inline constexpr int kNoRunnerUp = std::numeric_limits<int>::max();
int RunnerUpCost(const Cost* c, int n, int stride, int k);

// Winner-take-all: integer disparity index (0 … ndisp−1, the first minimum)
// per pixel of the left view, and of the right view through cost(y, x_r + d, d)
// (NaN where no left pixel can match).
void WinnerTakeAll(const CostVolume& cost, int min_disparity, const Parallel& parallel,
                   cv::Mat* left_index, cv::Mat* right_index);

struct RefineStats {
  double occluded_pct = 0, mismatch_pct = 0, ambiguous_pct = 0;
};

// The refinement's image-sized maps, kept between calls of one matcher:
// fresh maps are fresh pages, and on this project's machine (a VM) a page
// fault costs ~15 µs, ~630 of them a Middlebury scene (README 11.4).
struct RefineWorkspace {
  cv::Mat labels;              // CV_8UC1
  cv::Mat disparity, scratch;  // CV_32FC1: the map and the next step's output
  // Region voting: the bins (CV_16SC1), per row prefix counts over x (CV_32SC1,
  // height × (width + 1)), the changed pixels (CV_8UC1) and the region sums
  // down the columns (CV_32SC1, (height + 1) × width).
  cv::Mat bins, reliable_prefix, changed_flag, region;
  // Region voting: the unreliable pixels row by row, each with its column
  // and the rows [lo, hi) of its vertical arm.
  struct VotingPixel {
    std::int32_t x, lo, hi;
  };
  std::vector<int> todo_start;
  std::vector<VotingPixel> todo;
  // What each one's last look found: its region's reliable pixels (−1: never
  // counted) and an upper bound on its histogram's largest bin (−1: no
  // histogram yet); `voted`: it took a vote (reliable from the next
  // iteration).
  struct VotingState {
    std::int16_t reliable = -1, most = -1;
    bool voted = false;
  };
  std::vector<VotingState> known;
  // Those left for a histogram (todo index, row, arm, reliable count), from
  // blocks of rows, then by column; the votes by column.
  struct VotingPending {
    int t, y, lo, hi, reliable;
  };
  std::vector<std::vector<VotingPending>> block_pending;
  std::vector<VotingPending> pending;
  struct Vote {
    int y;
    float disparity;
  };
  std::vector<std::vector<Vote>> votes;
};

// The last step of Mei's refinement: each valid pixel of *disparity
// (CV_32FC1) becomes the median of the valid pixels of its size × size window
// (the element count / 2 of them in order); NaN stays NaN. *scratch is
// working memory.
void MedianFilter(int size, const Parallel& parallel, cv::Mat* disparity, cv::Mat* scratch);

// Mei's refinement on disparity indices (CV_32FC1, values 0 … ndisp−1); the
// result is a disparity index map with sub-pixel values and NaN where none.
// `runner_up` (may be null): ScanlineOptimize's winning and runner-up costs
// for the uniqueness test, the same as `cost` and RunnerUpCost would give.
// `workspace` (may be null: a fresh one per call): the result is its
// `disparity`, valid until the next call with the same workspace.
// `winner_sums` (may be null): ScanlineOptimize's sums around each left
// pixel's winner; the sub-pixel step reads them instead of the volume where
// the refined disparity is still the winner.
cv::Mat Refine(const cv::Mat& left_index, const cv::Mat& right_index, const CostVolume& cost,
               int min_disparity, const cv::Mat& left_image, const Arms& arms,
               const RefinementOptions& options, const Parallel& parallel, RefineStats* stats,
               const cv::Mat* runner_up = nullptr, RefineWorkspace* workspace = nullptr,
               const cv::Mat* winner_sums = nullptr);

}  // namespace craftscan::adcensus
