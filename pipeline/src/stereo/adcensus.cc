#include "craftscan/pipeline/stereo/adcensus.h"
#include "craftscan/pipeline/common/status.h"

#include <algorithm>
#include <chrono>
#include <exception>
#include <opencv2/core.hpp>

#include "adcensus_internal.h"

namespace craftscan {

std::string_view ToString(ArmRule rule) {
  switch (rule) {
    case ArmRule::kClassic:
      return "classic";
    case ArmRule::kImproved:
      return "improved";
  }
  return "unknown";
}

bool ArmRuleFromString(std::string_view text, ArmRule* rule) {
  if (text == "classic") {
    *rule = ArmRule::kClassic;
  } else if (text == "improved") {
    *rule = ArmRule::kImproved;
  } else {
    return false;
  }
  return true;
}

bool ADCensusOptions::IsValid(std::string* why) const {
  std::string reason;
  if (num_disparities < 1 || num_disparities > 4096)
    return Fail(why, "num_disparities must be in [1, 4096]");
  if (min_disparity < -65536 || min_disparity > 65536)
    return Fail(why, "min_disparity must be in [-65536, 65536]");
  if (!preprocess.IsValid(&reason)) return Fail(why, reason);
  if (census_width < 1 || census_height < 1 || census_width % 2 == 0 || census_height % 2 == 0)
    return Fail(why, "census_width and census_height must be odd and positive");
  if (census_width * census_height > 65)
    return Fail(why, "census window has more than 64 neighbours (census_width·census_height > 65)");
  if (!(lambda_ad > 0) || !(lambda_census > 0))
    return Fail(why, "lambda_ad and lambda_census must be > 0");
  if (!(out_of_image_cost >= 0 && out_of_image_cost <= 2))
    return Fail(why, "out_of_image_cost must be in [0, 2]");
  if (classic.l1_px < 1 || classic.l1_px > 255 || classic.l2_px < 0 ||
      classic.l2_px > classic.l1_px)
    return Fail(why, "classic arms: need 1 ≤ l1_px ≤ 255 and 0 ≤ l2_px ≤ l1_px");
  if (!(classic.tau1 > 0) || !(classic.tau2 > 0))
    return Fail(why, "classic arms: tau1, tau2 must be > 0");
  const ImprovedArmOptions& im = improved;
  if (im.l_max_px < 1 || im.l_max_px > 255 || im.l2_px < 0 || im.l2_px > im.l_max_px)
    return Fail(why, "improved arms: need 1 ≤ l_max_px ≤ 255 and 0 ≤ l2_px ≤ l_max_px");
  if (!(im.tau_max > 0) || !(im.tau2 > 0) || !(im.beta1 > 0) || !(im.beta_max > 0))
    return Fail(why, "improved arms: tau_max, tau2, beta1, beta_max must be > 0");
  if (!(im.edge_length_scale > 0 && im.edge_length_scale <= 1) ||
      !(im.edge_tau_scale > 0 && im.edge_tau_scale <= 1))
    return Fail(why, "improved arms: edge_length_scale and edge_tau_scale must be in (0, 1]");
  if (aggregation_iterations < 0 || aggregation_iterations > 16)
    return Fail(why, "aggregation_iterations must be in [0, 16]");
  if (!(pi1 >= 0) || !(pi2 >= pi1)) return Fail(why, "scanline penalties need 0 ≤ pi1 ≤ pi2");
  if (!(tau_so >= 0)) return Fail(why, "tau_so must be ≥ 0");
  const RefinementOptions& r = refinement;
  if (!(r.lr_tolerance_px >= 0)) return Fail(why, "refinement.lr_tolerance_px must be ≥ 0");
  if (!(r.uniqueness >= 0 && r.uniqueness < 1))
    return Fail(why, "refinement.uniqueness must be in [0, 1)");
  if (r.voting_iterations < 0 || r.voting_iterations > 100)
    return Fail(why, "refinement.voting_iterations must be in [0, 100]");
  if (r.tau_s < 0) return Fail(why, "refinement.tau_s must be ≥ 0");
  if (!(r.tau_h >= 0 && r.tau_h < 1)) return Fail(why, "refinement.tau_h must be in [0, 1)");
  if (r.median_size != 0 && r.median_size != 1 && r.median_size != 3 && r.median_size != 5)
    return Fail(why, "refinement.median_size must be 0, 3 or 5");
  if (num_threads < 1 || num_threads > 256) return Fail(why, "num_threads must be in [1, 256]");
  return true;
}

namespace {

using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

DisparityResult InvalidInput(std::string message) {
  return Failed<DisparityResult>(DisparityResult::Status::kInvalidInput, std::move(message));
}

}  // namespace

struct StereoMatcher::Workspace {
  explicit Workspace(int num_threads) : parallel(num_threads) {}
  Parallel parallel;                   // the arena lives as long as the matcher
  adcensus::CostVolume cost, scratch;  // aggregated costs; scanline sums
};

StereoMatcher::StereoMatcher(ADCensusOptions options)
    : options_(std::move(options)),
      workspace_(std::make_unique<Workspace>(std::clamp(options_.num_threads, 1, 256))) {}
StereoMatcher::~StereoMatcher() = default;
StereoMatcher::StereoMatcher(StereoMatcher&&) noexcept = default;
StereoMatcher& StereoMatcher::operator=(StereoMatcher&&) noexcept = default;

DisparityResult ComputeDisparity(const cv::Mat& left, const cv::Mat& right,
                                 const ADCensusOptions& options) {
  StereoMatcher matcher(options);
  return matcher.Compute(left, right);
}

DisparityResult StereoMatcher::Compute(const cv::Mat& left, const cv::Mat& right) {
  const ADCensusOptions& options = options_;
  std::string why;
  if (!options.IsValid(&why)) return InvalidInput("invalid options: " + why);
  if (left.empty() || right.empty()) return InvalidInput("left or right image is empty");
  if (left.size() != right.size())
    return InvalidInput("image sizes differ: left " + std::to_string(left.cols) + "x" +
                        std::to_string(left.rows) + ", right " + std::to_string(right.cols) + "x" +
                        std::to_string(right.rows));
  if (left.type() != right.type() || (left.type() != CV_8UC1 && left.type() != CV_8UC3))
    return InvalidInput("images must both be CV_8UC1 or both CV_8UC3");
  if (left.cols < 2 || left.rows < 2) return InvalidInput("images must be at least 2x2 pixels");
  const double voxels =
      static_cast<double>(left.cols) * left.rows * ((options.num_disparities + 15) / 16 * 16);
  if (voxels > 1.0e9)  // up to two 16-bit volumes live at once: 4 GB at this limit
    return InvalidInput("cost volume too large: width·height·num_disparities = " +
                        std::to_string(static_cast<long long>(voxels)) +
                        " exceeds 1e9; narrow the disparity range or match at lower resolution");
  if (options.min_disparity >= left.cols ||
      options.min_disparity + options.num_disparities - 1 <= -left.cols)
    return InvalidInput("disparity range [" + std::to_string(options.min_disparity) + ", " +
                        std::to_string(options.min_disparity + options.num_disparities) +
                        ") lies entirely outside the image width " + std::to_string(left.cols));

  try {
    const auto t_start = Clock::now();
    DisparityResult result;
    const Parallel& parallel = workspace_->parallel;
    const int ndisp = options.num_disparities, dmin = options.min_disparity;

    auto t = Clock::now();
    const Preprocessed pl = Preprocess(left, options.preprocess);
    // The right view feeds only the census and the colour costs.
    const Preprocessed pr = Preprocess(right, options.preprocess, PreprocessParts::kEqualizedOnly);
    if (!pl.IsUsable()) return InvalidInput("left: " + pl.message);
    if (!pr.IsUsable()) return InvalidInput("right: " + pr.message);
    const cv::Mat& img_l = options.match_equalized ? pl.image : left;
    const cv::Mat& img_r = options.match_equalized ? pr.image : right;
    result.time_ms.preprocess = MsSince(t);

    t = Clock::now();
    const auto census_l =
        adcensus::CensusTransform(pl.grey, options.census_width, options.census_height, parallel);
    const auto census_r =
        adcensus::CensusTransform(pr.grey, options.census_width, options.census_height, parallel);
    adcensus::CostVolume& cost = workspace_->cost;
    cost.Reshape(left.cols, left.rows, ndisp);
    const adcensus::CostComputer cost_computer(img_l, img_r, census_l, census_r, dmin, ndisp,
                                               options.lambda_ad, options.lambda_census,
                                               options.out_of_image_cost);
    adcensus::ComputeCost(cost_computer, parallel, &cost);
    result.time_ms.cost = MsSince(t);

    t = Clock::now();
    const adcensus::Arms arms =
        adcensus::BuildArms(img_l, pl.gradient, pl.edges, options, parallel);
    result.time_ms.arms = MsSince(t);

    t = Clock::now();
    adcensus::Aggregate(arms, options.aggregation_iterations, parallel, &cost);
    result.time_ms.aggregation = MsSince(t);

    // Scanline optimization (when on) is fused with the winner-take-all; its
    // time is counted as scanline.
    t = Clock::now();
    cv::Mat left_index, right_index;
    const adcensus::CostVolume* final_cost = &cost;
    if (options.scanline_optimization && options.aggregation_iterations == 0) {
      // The costs are cheap to recompute row by row: the scanline sums
      // overwrite them in place, one volume instead of two.
      adcensus::ScanlineOptimize(img_l, img_r, dmin, options, parallel, nullptr, &cost_computer,
                                 &cost, &left_index, &right_index);
    } else if (options.scanline_optimization) {
      adcensus::ScanlineOptimize(img_l, img_r, dmin, options, parallel, &cost, nullptr,
                                 &workspace_->scratch, &left_index, &right_index);
      final_cost = &workspace_->scratch;
    }
    result.time_ms.scanline = MsSince(t);

    t = Clock::now();
    if (!options.scanline_optimization)
      adcensus::WinnerTakeAll(cost, dmin, parallel, &left_index, &right_index);
    cv::Mat index;
    if (options.refinement.enabled) {
      adcensus::RefineStats stats;
      index = adcensus::Refine(left_index, right_index, *final_cost, dmin, img_l, arms,
                               options.refinement, parallel, &stats);
      result.occluded_pct = stats.occluded_pct;
      result.mismatch_pct = stats.mismatch_pct;
      result.ambiguous_pct = stats.ambiguous_pct;
    } else {
      index = left_index;
    }
    // Indices → disparities (NaN stays NaN).
    index.convertTo(result.disparity, CV_32F, 1.0, dmin);
    right_index.convertTo(result.disparity_right, CV_32F, 1.0, dmin);
    result.time_ms.refinement = MsSince(t);

    int valid = 0;
    for (int y = 0; y < result.disparity.rows; ++y) {
      const float* d = result.disparity.ptr<float>(y);
      for (int x = 0; x < result.disparity.cols; ++x) valid += IsValidDisparity(d[x]) ? 1 : 0;
    }
    result.valid_pct = 100.0 * valid / static_cast<double>(result.disparity.total());
    result.status = DisparityResult::Status::kOk;
    result.time_ms.total = MsSince(t_start);
    return result;
  } catch (const std::bad_alloc&) {
    return InvalidInput("out of memory for the cost volume; reduce num_disparities or image size");
  } catch (const std::exception& e) {
    return InvalidInput(std::string("matching failed: ") + e.what());
  }
}

}  // namespace craftscan
