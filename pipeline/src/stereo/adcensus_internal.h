// Stages of the AD-Census matcher, exposed for tests (brute-force reference
// checks) and for the orchestration in adcensus.cc. Not a public API.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstdlib>
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

// Cost volume laid out [y][x][d] with the disparity axis padded to a
// multiple of 16 floats (64 B) so that inner loops over d vectorize and rows
// start on cache lines. Padding lanes hold kPadCost.
class CostVolume {
 public:
  static constexpr float kPadCost = 1e4f;
  CostVolume() = default;
  CostVolume(int width, int height, int ndisp) { Reshape(width, height, ndisp); }
  // Sets the dimensions; reallocates only when the capacity is too small.
  // Contents are unspecified afterwards.
  void Reshape(int width, int height, int ndisp);
  void swap(CostVolume& other) noexcept {
    std::swap(width_, other.width_);
    std::swap(height_, other.height_);
    std::swap(ndisp_, other.ndisp_);
    std::swap(stride_, other.stride_);
    std::swap(capacity_, other.capacity_);
    data_.swap(other.data_);
  }
  int width() const { return width_; }
  int height() const { return height_; }
  int ndisp() const { return ndisp_; }
  int stride() const { return stride_; }  // floats between consecutive pixels
  float* at(int y, int x) {
    return data_.get() + (static_cast<std::size_t>(y) * width_ + x) * stride_;
  }
  const float* at(int y, int x) const {
    return data_.get() + (static_cast<std::size_t>(y) * width_ + x) * stride_;
  }
  float* row(int y) { return at(y, 0); }

 private:
  struct Free {
    void operator()(float* p) const { std::free(p); }
  };
  int width_ = 0, height_ = 0, ndisp_ = 0, stride_ = 0;
  std::size_t capacity_ = 0;  // floats
  std::unique_ptr<float[], Free> data_;
};

// Census transform over a win_w × win_h window (≤ 65 positions; the centre is
// skipped): bit k is set when neighbour k is darker than the centre. Borders
// replicate. Returns one word per pixel, row-major.
std::vector<std::uint64_t> CensusTransform(const cv::Mat& grey, int win_w, int win_h,
                                           const Parallel& parallel);

// Matching cost ρ(C_AD, λ_AD) + ρ(C_census, λ_census), ρ(c, λ) = 1 − exp(−c/λ),
// with C_AD the mean absolute difference over the channels. Disparities whose
// right pixel falls outside the image get `out_of_image_cost`.
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
};

// Builds arms on `image` (CV_8UC1/CV_8UC3) with the classic rule, or with the
// improved rule when `gradient` (CV_32FC1) is given; `edges` (CV_8UC1, may be
// empty) marks extra edge pixels for the improved rule.
Arms BuildArms(const cv::Mat& image, const cv::Mat& gradient, const cv::Mat& edges,
               const ADCensusOptions& options, const Parallel& parallel);

// True when pixel (y, x) counts as an edge pixel under the improved rule.
bool IsEdgePixel(const cv::Mat& gradient, const cv::Mat& edges, int y, int x,
                 const ImprovedArmOptions& options);

// Cross-based aggregation, `iterations` passes alternating horizontal-first
// (even) and vertical-first (odd); each result is normalized by the number of
// pixels in the support region.
void Aggregate(const Arms& arms, int iterations, const Parallel& parallel, CostVolume* cost);

// Support-region pixel count of (y, x) for horizontal-first (true) or
// vertical-first aggregation.
int SupportSize(const Arms& arms, int y, int x, bool horizontal_first);

// Four-direction scanline optimization (Mei et al.), result = mean of the
// four path costs, left in *cost. Penalties depend on colour differences in
// both images. `scratch` is working memory (reshaped as needed).
void ScanlineOptimize(const cv::Mat& left, const cv::Mat& right, int min_disparity,
                      const ADCensusOptions& options, const Parallel& parallel, CostVolume* cost,
                      CostVolume* scratch);

// Winner-take-all: integer disparity index (0 … ndisp−1) per pixel of the
// left view, and of the right view through cost(y, x_r + d, d) (NaN where no
// left pixel can match).
void WinnerTakeAll(const CostVolume& cost, int min_disparity, const Parallel& parallel,
                   cv::Mat* left_index, cv::Mat* right_index);

struct RefineStats {
  double occluded_pct = 0, mismatch_pct = 0, ambiguous_pct = 0;
};

// Mei's refinement on disparity indices (CV_32FC1, values 0 … ndisp−1); the
// result is a disparity index map with sub-pixel values and NaN where none.
cv::Mat Refine(const cv::Mat& left_index, const cv::Mat& right_index, const CostVolume& cost,
               int min_disparity, const cv::Mat& left_image, const Arms& arms,
               const RefinementOptions& options, const Parallel& parallel, RefineStats* stats);

}  // namespace craftscan::adcensus
