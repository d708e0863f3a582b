// Improved AD-Census stereo matching (method.md §5): AD + census cost,
// cross-based aggregation with the paper's gradient-split arms, scanline
// optimization and Mei et al.'s multi-step refinement.
//
// Input: a rectified pair (left, right), both CV_8UC1 or both CV_8UC3 (BGR),
// same size. Disparity d = x_left − x_right is searched in
// [min_disparity, min_disparity + num_disparities).
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <opencv2/core/mat.hpp>
#include <string>
#include <string_view>

#include "craftscan/pipeline/stereo/preprocess.h"

namespace craftscan {

// The value of a pixel with no disparity estimate (quiet NaN). Test with
// IsValidDisparity(), never with ==.
inline constexpr float kInvalidDisparity = std::numeric_limits<float>::quiet_NaN();
inline bool IsValidDisparity(float d) { return d == d; }

// How cross arms are built.
enum class ArmRule {
  kClassic,   // Mei et al. 2011: colour and length limits only
  kImproved,  // the paper: gradient split into weak-texture and edge pixels
};
std::string_view ToString(ArmRule rule);
bool ArmRuleFromString(std::string_view text, ArmRule* rule);

struct ClassicArmOptions {  // Mei's published values
  int l1_px = 34;           // maximum arm length
  int l2_px = 17;           // beyond this length the colour limit tightens to tau2
  double tau1 = 20;         // colour limit (max channel abs difference, grey levels)
  double tau2 = 6;          // colour limit beyond l2_px
};

struct ImprovedArmOptions {        // the paper's values
  double beta_max = 120;           // gradient magnitude at and above which a pixel is an edge pixel
  double beta1 = 40;               // gradient magnitude difference limit along an arm
  double tau_max = 20;             // colour limit (to the anchor and to the next pixel)
  double tau2 = 10;                // colour limit to the anchor beyond l2_px
  int l_max_px = 34;               // maximum arm length
  int l2_px = 17;                  // length beyond which tau2 applies
  double edge_length_scale = 0.5;  // edge pixels: l_max, l2 multiplied by this
  double edge_tau_scale = 0.75;    // edge pixels: tau_max multiplied by this
  bool canny_edges_are_edges = true;  // pixels on the dilated Canny map are edge pixels
};

struct RefinementOptions {
  bool enabled = true;
  double lr_tolerance_px = 1.0;  // left-right check: |dL − dR| above this is an outlier
  // Uniqueness test, [0, 1); 0 = off. A pixel whose winning cost is not at
  // least this fraction below the best cost two or more disparities away
  // (c_best > (1 − uniqueness) · c_second) is unreliable, like a failed
  // left-right check: a flat cost curve (weak texture, a repeated pattern)
  // picks its winner by noise, and both views can agree on it.
  double uniqueness = 0;
  int voting_iterations = 5;  // iterative region voting
  int tau_s = 20;             // minimum reliable votes in the support region
  double tau_h = 0.4;         // minimum share of the winning disparity
  bool interpolate = true;    // proper interpolation of the remaining outliers
  bool adjust_discontinuities = true;
  bool subpixel = true;  // parabola fit on the final cost
  int median_size = 3;   // 0 (off), 3 or 5
};

// Per-pixel disparity ranges from a coarse pass, for wide bands (a station's
// working volume spans hundreds of disparities at full size while each
// pixel's surface lies within a few). The pair is first matched about
// coarse_width_px wide (downscaled by an integer factor 2 … 8) over the whole
// band (left-right checked, no interpolation, patches of at most
// speckle_area_pct % of its pixels removed); each pixel then searches only
// `lanes` disparities around
// what the coarse map found in its neighbourhood (window_coarse_px coarse
// pixels either side, widened by margin_px), so the volume and the work
// shrink by num_disparities / lanes. Where the neighbourhood spans more than
// `lanes` (a depth edge), the pixel's own coarse disparity is centred (where
// it has none, the smaller of its row's nearest either side: the farther
// surface, as occlusions go; else the nearest surface's); where the coarse
// pass found nothing within wide_window_coarse_px, the image's median. Used only without
// cross-based aggregation (aggregation_iterations 0, scanline optimization on: the station's
// matcher) and when num_disparities exceeds min_num_disparities; otherwise ignored.
struct CoarseToFineOptions {
  bool enabled = false;
  int min_num_disparities = 192;  // narrower bands are matched whole
  int lanes = 64;                 // disparities per pixel, a multiple of 16
  int coarse_width_px = 320;      // the coarse pass's image width, about
  int window_coarse_px = 2;       // neighbourhood half-size, coarse pixels
  int wide_window_coarse_px = 8;  // second look where the first window has nothing
  int margin_px = 8;              // full-size disparities added on either side
  double speckle_area_pct = 0.1;  // of the coarse image, [0, 10]
};

struct ADCensusOptions {
  int min_disparity = 0;     // px, may be negative
  int num_disparities = 64;  // px, ≥ 1: the range [min, min + num)

  // Equalization and Canny feed the arms (gradient, edge pixels). Matching
  // itself uses the raw images by default: equalizing each view on its own
  // maps the same surface to different grey levels in the two views, which
  // costs accuracy on every Middlebury scene we measured (see bench/README).
  PreprocessOptions preprocess;
  bool match_equalized = false;  // match on the equalized images instead of the raw ones

  int census_width = 9;       // odd, census window (width × height ≤ 64 + 1 bits)
  int census_height = 7;      // odd
  double lambda_ad = 10;      // robust scale of the AD cost
  double lambda_census = 30;  // robust scale of the census cost
  // Cost of a disparity whose right pixel lies outside the image, on the
  // [0, 2] cost scale. Neutral (1) rather than maximal: a maximal cost drags
  // scanline paths towards small disparities along the left border.
  double out_of_image_cost = 1.0;

  ArmRule arm_rule = ArmRule::kImproved;
  ClassicArmOptions classic;
  ImprovedArmOptions improved;
  // Cross-based aggregation iterations, alternating horizontal-first /
  // vertical-first. method.md's (the paper's) 4; here one of each order:
  // over the 23 Middlebury scenes 2 beat 4 on bad-1, bad-2 and the mean
  // error in 21–22 of them (the scanline paths that follow already carry
  // support along rows and columns, and 4 smear costs across depth edges),
  // at half the aggregation's time (README 11.4). 0: the station's matcher.
  int aggregation_iterations = 2;

  bool scanline_optimization = true;
  double pi1 = 1.0;  // scanline penalties (on the normalized cost scale)
  double pi2 = 3.0;
  double tau_so = 15;  // colour difference that lowers the penalties

  RefinementOptions refinement;
  CoarseToFineOptions coarse_to_fine;

  int num_threads = 1;  // worker threads for this call; 1 = serial. Results do not depend on it.

  bool IsValid(std::string* why) const;
};

struct DisparityResult {
  enum class Status { kOk, kInvalidInput };
  Status status = Status::kInvalidInput;
  std::string message;
  cv::Mat disparity;         // CV_32FC1, left view, kInvalidDisparity where none
  cv::Mat disparity_right;   // CV_32FC1, right view (integer, before refinement)
  double occluded_pct = 0;   // of all pixels, outliers classified as occlusion
  double mismatch_pct = 0;   // of all pixels, outliers classified as mismatch
  double ambiguous_pct = 0;  // of all pixels, passed the left-right check, failed uniqueness
  double valid_pct = 0;      // of all pixels with a disparity in the output
  // Disparities searched per pixel: num_disparities, or the coarse-to-fine
  // lanes when that was used (then coarse_ms > 0).
  int searched_disparities = 0;
  struct Timings {      // wall-clock milliseconds per stage
    double coarse = 0;  // the coarse pass and the per-pixel ranges (coarse-to-fine)
    double preprocess = 0, cost = 0, arms = 0, aggregation = 0;
    double scanline = 0;    // with the winner-take-all of both views, fused into it
    double refinement = 0;  // (and the winner-take-all when scanline optimization is off)
    double total = 0;
  } time_ms;

  bool IsUsable() const { return status == Status::kOk; }
};

// A matcher that keeps its working memory between calls (cost volumes of
// width·height·num_disparities 16-bit costs, the disparity count rounded up
// to a multiple of 16: one volume without aggregation, two with it), so a
// station matching view after view pays for allocation and first-touch page
// faults once. Not thread-safe: use one matcher per thread.
class StereoMatcher {
 public:
  explicit StereoMatcher(ADCensusOptions options);
  ~StereoMatcher();
  StereoMatcher(StereoMatcher&&) noexcept;
  StereoMatcher& operator=(StereoMatcher&&) noexcept;

  const ADCensusOptions& options() const { return options_; }

  // Computes the left disparity map. Never throws for bad input: returns a
  // result with status kInvalidInput and a message naming what is wrong
  // (including invalid options). Uses options().num_threads threads.
  DisparityResult Compute(const cv::Mat& left, const cv::Mat& right);

 private:
  struct Workspace;
  ADCensusOptions options_;
  std::unique_ptr<Workspace> workspace_;
};

// One-shot form of StereoMatcher::Compute. Thread-safe.
DisparityResult ComputeDisparity(const cv::Mat& left, const cv::Mat& right,
                                 const ADCensusOptions& options);

}  // namespace craftscan
