#include "craftscan/pipeline/stereo/adcensus.h"
#include "craftscan/pipeline/common/status.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "adcensus_internal.h"
#include "craftscan/pipeline/stereo/view_processing.h"

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
  const CoarseToFineOptions& c = coarse_to_fine;
  if (c.lanes < 16 || c.lanes > 1024 || c.lanes % 16 != 0)
    return Fail(why, "coarse_to_fine.lanes must be a multiple of 16 in [16, 1024]");
  if (c.coarse_width_px < 64 || c.coarse_width_px > 4096)
    return Fail(why, "coarse_to_fine.coarse_width_px must be in [64, 4096]");
  if (c.window_coarse_px < 0 || c.window_coarse_px > 32 ||
      c.wide_window_coarse_px < c.window_coarse_px || c.wide_window_coarse_px > 64)
    return Fail(why,
                "coarse_to_fine: need 0 ≤ window_coarse_px ≤ wide_window_coarse_px ≤ 64 "
                "(window_coarse_px ≤ 32)");
  if (!(c.speckle_area_pct >= 0 && c.speckle_area_pct <= 10))
    return Fail(why, "coarse_to_fine.speckle_area_pct must be in [0, 10]");
  if (c.margin_px < 0 || c.margin_px > 256)
    return Fail(why, "coarse_to_fine.margin_px must be in [0, 256]");
  if (c.min_num_disparities < c.lanes)
    return Fail(why, "coarse_to_fine.min_num_disparities must be ≥ lanes");
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
  std::vector<std::uint64_t> census_left, census_right;
  Preprocessed preprocessed_left, preprocessed_right;
  PreprocessScratch preprocess_scratch, preprocess_scratch_right;
  adcensus::Arms arms;                         // and BuildArms's working memory
  adcensus::PassFactors pass_factors;          // the aggregation's
  adcensus::RefineWorkspace refine;            // the refinement's maps
  cv::Mat left_index, right_index, runner_up;  // the winners (CV_32FC1) and costs
  cv::Mat winner_sums;                         // the sums around them (CV_16SC3)
  std::unique_ptr<StereoMatcher> coarse;       // coarse-to-fine's first pass
  // The memory of the last result's two maps, written again by the next
  // call once the caller has let go of them (Reusable).
  cv::Mat disparity, disparity_right;
};

namespace {

// *kept, to be written again when no one but the workspace holds its memory
// any more (a caller that dropped the last result): a fresh map is
// hundreds of new pages, each a page fault on first touch. Otherwise it is
// let go and the caller's copy stays as it is.
cv::Mat& Reusable(cv::Mat* kept) {
  if (kept->u && CV_XADD(&kept->u->refcount, 0) > 1) kept->release();
  return *kept;
}

// cv::erode (min) or cv::dilate (max) of a disparity map over a square
// window, NaN ignored (NaN where the window holds no value).
cv::Mat WindowExtreme(const cv::Mat& disparity, int radius, bool max) {
  const float none =
      max ? -std::numeric_limits<float>::infinity() : std::numeric_limits<float>::infinity();
  cv::Mat filled = disparity.clone();
  filled.setTo(none, disparity != disparity);
  cv::Mat out;
  const cv::Mat kernel =
      cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * radius + 1, 2 * radius + 1));
  if (max) {
    cv::dilate(filled, out, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(none));
  } else {
    cv::erode(filled, out, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(none));
  }
  return out;
}

// Per-pixel offsets (indices into [min_disparity, min_disparity + ndisp))
// from the coarse disparity map, as CoarseToFineOptions describes.
// The coarse pass's downscale: its images about coarse_width_px wide.
int CoarseFactor(int width, const CoarseToFineOptions& o) {
  return std::clamp(static_cast<int>(std::lround(static_cast<double>(width) / o.coarse_width_px)),
                    2, 8);
}

std::vector<std::int32_t> RangesFromCoarse(const cv::Mat& coarse, cv::Size size, int min_disparity,
                                           int ndisp, int factor, const CoarseToFineOptions& o) {
  const cv::Mat lo = WindowExtreme(coarse, o.window_coarse_px, false);
  const cv::Mat hi = WindowExtreme(coarse, o.window_coarse_px, true);
  const cv::Mat wide_lo = WindowExtreme(coarse, o.wide_window_coarse_px, false);
  const cv::Mat wide_hi = WindowExtreme(coarse, o.wide_window_coarse_px, true);
  std::vector<float> valid;
  for (int y = 0; y < coarse.rows; ++y)
    for (int x = 0; x < coarse.cols; ++x)
      if (IsValidDisparity(coarse.at<float>(y, x))) valid.push_back(coarse.at<float>(y, x));
  float median = static_cast<float>(min_disparity + ndisp / 2) / static_cast<float>(factor);
  if (!valid.empty()) {
    std::nth_element(valid.begin(), valid.begin() + valid.size() / 2, valid.end());
    median = valid[valid.size() / 2];
  }
  // Each coarse pixel's own disparity, where the coarse pass left none the
  // smaller of its row's nearest values either side (within the wide window):
  // a pixel without a match is most often occluded, and occluded pixels
  // belong to the farther surface.
  cv::Mat own = coarse.clone();
  for (int y = 0; y < coarse.rows; ++y) {
    const float* c = coarse.ptr<float>(y);
    float* out = own.ptr<float>(y);
    std::vector<float> from_left(coarse.cols, kInvalidDisparity);
    float last_value = kInvalidDisparity;
    int last_x = -1000000;
    for (int x = 0; x < coarse.cols; ++x) {
      if (IsValidDisparity(c[x])) {
        last_value = c[x];
        last_x = x;
      } else if (x - last_x <= o.wide_window_coarse_px) {
        from_left[x] = last_value;
      }
    }
    last_x = 1000000;
    for (int x = coarse.cols - 1; x >= 0; --x) {
      if (IsValidDisparity(c[x])) {
        last_value = c[x];
        last_x = x;
        continue;
      }
      const float right = last_x - x <= o.wide_window_coarse_px ? last_value : kInvalidDisparity;
      if (IsValidDisparity(from_left[x]) && IsValidDisparity(right)) {
        out[x] = std::min(from_left[x], right);
      } else {
        out[x] = IsValidDisparity(right) ? right : from_left[x];
      }
    }
  }
  const double f = factor;
  const int lanes = o.lanes, last = ndisp - lanes;
  // A pixel's offset depends only on its coarse pixel: each coarse pixel's
  // is computed once, and the full rows are filled from them.
  cv::Mat coarse_offset(coarse.size(), CV_32SC1);
  for (int cy = 0; cy < coarse.rows; ++cy) {
    for (int cx = 0; cx < coarse.cols; ++cx) {
      float a = lo.at<float>(cy, cx), b = hi.at<float>(cy, cx);
      if (!std::isfinite(a)) {
        a = wide_lo.at<float>(cy, cx);
        b = wide_hi.at<float>(cy, cx);
      }
      if (!std::isfinite(a)) a = b = median;
      // Full-size disparities, widened by the margin and the coarse pixel's
      // own uncertainty.
      const double d_lo = a * f - o.margin_px - f, d_hi = b * f + o.margin_px + f;
      double start;
      if (d_hi - d_lo + 1 <= lanes) {
        start = (d_lo + d_hi) / 2 - lanes / 2.0;
      } else {
        const float mine = own.at<float>(cy, cx);
        const double centre = IsValidDisparity(mine) ? mine * f : d_hi - o.margin_px - f;
        start = centre - lanes / 2.0;
      }
      coarse_offset.at<std::int32_t>(cy, cx) =
          std::clamp(static_cast<int>(std::lround(start)) - min_disparity, 0, last);
    }
  }
  std::vector<std::int32_t> offsets(static_cast<std::size_t>(size.area()));
  for (int y = 0; y < size.height; ++y) {
    std::int32_t* out = offsets.data() + static_cast<std::size_t>(y) * size.width;
    const int cy = std::min(y / factor, coarse.rows - 1);
    if (y > 0 && cy == std::min((y - 1) / factor, coarse.rows - 1)) {
      std::copy_n(out - size.width, size.width, out);  // the same coarse row
      continue;
    }
    const std::int32_t* row = coarse_offset.ptr<std::int32_t>(cy);
    for (int x = 0; x < size.width; ++x) out[x] = row[std::min(x / factor, coarse.cols - 1)];
  }
  return offsets;
}

// A winner on the first or last disparity a pixel searched (not an end of
// the whole band) may be the edge of a minimum that lies outside its range:
// no estimate there.
void DropRangeEdges(const adcensus::CostVolume& cost, int total_ndisp, cv::Mat* index) {
  const int lanes = cost.ndisp();
  for (int y = 0; y < index->rows; ++y) {
    float* d = index->ptr<float>(y);
    const std::int32_t* offsets = cost.offset_row(y);
    for (int x = 0; x < index->cols; ++x) {
      if (!IsValidDisparity(d[x])) continue;
      const int o = offsets[x];
      const float k = d[x] - static_cast<float>(o);
      if ((o > 0 && k < 1.f) || (o + lanes < total_ndisp && k > static_cast<float>(lanes - 2)))
        d[x] = kInvalidDisparity;
    }
  }
}

}  // namespace

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
  const CoarseToFineOptions& ctf = options.coarse_to_fine;
  const bool coarse_to_fine = ctf.enabled && options.aggregation_iterations == 0 &&
                              options.scanline_optimization &&
                              options.num_disparities > ctf.min_num_disparities &&
                              left.cols >= 16 * CoarseFactor(left.cols, ctf) &&
                              left.rows >= 16 * CoarseFactor(left.cols, ctf);
  const int lanes = coarse_to_fine ? ctf.lanes : (options.num_disparities + 15) / 16 * 16;
  const double voxels = static_cast<double>(left.cols) * left.rows * lanes;
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
    std::vector<std::int32_t> offsets;
    if (coarse_to_fine) {
      const int factor = CoarseFactor(left.cols, ctf);
      ADCensusOptions coarse_options = options;
      coarse_options.coarse_to_fine.enabled = false;
      coarse_options.min_disparity =
          static_cast<int>(std::floor(static_cast<double>(dmin) / factor));
      coarse_options.num_disparities =
          static_cast<int>(std::ceil(static_cast<double>(dmin + ndisp) / factor)) -
          coarse_options.min_disparity + 1;
      coarse_options.refinement.interpolate = false;
      if (!workspace_->coarse ||
          workspace_->coarse->options().num_disparities != coarse_options.num_disparities ||
          workspace_->coarse->options().min_disparity != coarse_options.min_disparity) {
        workspace_->coarse = std::make_unique<StereoMatcher>(coarse_options);
      }
      cv::Mat small_left, small_right;
      const double scale = 1.0 / factor;
      cv::resize(left, small_left, cv::Size(), scale, scale, cv::INTER_AREA);
      cv::resize(right, small_right, cv::Size(), scale, scale, cv::INTER_AREA);
      DisparityResult coarse = workspace_->coarse->Compute(small_left, small_right);
      if (!coarse.IsUsable()) return InvalidInput("coarse pass: " + coarse.message);
      // Small patches that passed the left-right check are mostly wrong, and
      // one wrong value would set the range of every pixel around it.
      RemoveDisparitySpeckles(
          static_cast<int>(std::lround(ctf.speckle_area_pct / 100 * coarse.disparity.total())), 1.0,
          &coarse.disparity);
      offsets = RangesFromCoarse(coarse.disparity, left.size(), dmin, ndisp, factor, ctf);
      result.time_ms.coarse = MsSince(t);
      t = Clock::now();
    }
    result.searched_disparities = coarse_to_fine ? lanes : ndisp;
    Preprocessed& pl = workspace_->preprocessed_left;
    Preprocessed& pr = workspace_->preprocessed_right;
    // The equalized grey images first, the two views at once (OpenCV's
    // calls on one image are mostly serial). The right view feeds only the
    // census and the colour costs, the equalized colour images only a
    // matcher that matches them. The left view's gradient and edges (for the
    // arms; Canny alone is about 10 ms at 1280×1024, on one thread) are then
    // computed alongside the census transforms, their time counted as cost.
    const bool colour = options.match_equalized;
    const PreprocessParts parts =
        colour ? PreprocessParts::kEqualizedOnly : PreprocessParts::kGreyOnly;
    parallel.For(0, 2, [&](int v0, int v1) {
      for (int v = v0; v < v1; ++v) {
        if (v == 0) {
          Preprocess(left, options.preprocess, parts, &pl, &workspace_->preprocess_scratch);
        } else {
          Preprocess(right, options.preprocess, parts, &pr, &workspace_->preprocess_scratch_right);
        }
      }
    });
    if (!pl.IsUsable()) return InvalidInput("left: " + pl.message);
    if (!pr.IsUsable()) return InvalidInput("right: " + pr.message);
    const cv::Mat& img_l = options.match_equalized ? pl.image : left;
    const cv::Mat& img_r = options.match_equalized ? pr.image : right;
    result.time_ms.preprocess = MsSince(t);

    t = Clock::now();
    std::vector<std::uint64_t>& census_l = workspace_->census_left;
    std::vector<std::uint64_t>& census_r = workspace_->census_right;
    parallel.For(0, 2, [&](int v0, int v1) {
      for (int v = v0; v < v1; ++v) {
        if (v == 0) {
          PreprocessEdges(options.preprocess, &pl, &workspace_->preprocess_scratch);
        } else {
          adcensus::CensusTransform(pl.grey, options.census_width, options.census_height, parallel,
                                    &census_l);
          adcensus::CensusTransform(pr.grey, options.census_width, options.census_height, parallel,
                                    &census_r);
        }
      }
    });
    if (!pl.IsUsable()) return InvalidInput("left: " + pl.message);
    adcensus::CostVolume& cost = workspace_->cost;
    cost.Reshape(left.cols, left.rows, coarse_to_fine ? lanes : ndisp);
    if (coarse_to_fine) cost.SetOffsets(std::move(offsets), ndisp);
    const adcensus::CostComputer cost_computer(img_l, img_r, census_l, census_r, dmin, cost.ndisp(),
                                               options.lambda_ad, options.lambda_census,
                                               options.out_of_image_cost);
    // The station's matcher (scanline paths straight on the matching costs)
    // computes them row by row as its paths need them, so here only the
    // census transforms count as "cost".
    // With aggregation the costs are computed as its first pass takes them
    // (its time is counted as aggregation).
    const bool recompute = options.scanline_optimization && options.aggregation_iterations == 0;
    const bool fused = !recompute && options.aggregation_iterations > 0;
    if (!recompute && !fused) adcensus::ComputeCost(cost_computer, parallel, &cost);
    result.time_ms.cost = MsSince(t);

    t = Clock::now();
    const adcensus::Arms& arms = workspace_->arms;
    adcensus::BuildArms(img_l, pl.gradient, pl.edges, options, parallel, &workspace_->arms);
    result.time_ms.arms = MsSince(t);

    t = Clock::now();
    adcensus::Aggregate(arms, options.aggregation_iterations, parallel, &cost,
                        &workspace_->pass_factors, fused ? &cost_computer : nullptr);
    result.time_ms.aggregation = MsSince(t);

    // Scanline optimization (when on) is fused with the winner-take-all; its
    // time is counted as scanline.
    t = Clock::now();
    cv::Mat& left_index = workspace_->left_index;
    cv::Mat& right_index = workspace_->right_index;
    cv::Mat& runner_up = workspace_->runner_up;
    cv::Mat* const wants_runner_up =
        options.refinement.enabled && options.refinement.uniqueness > 0 ? &runner_up : nullptr;
    cv::Mat* const wants_winner_sums =
        options.refinement.enabled && options.refinement.subpixel && options.scanline_optimization
            ? &workspace_->winner_sums
            : nullptr;
    const adcensus::CostVolume* final_cost = &cost;
    if (recompute) {
      // The costs are cheap to compute row by row: the volume holds only
      // the scanline sums.
      adcensus::ScanlineOptimize(img_l, img_r, dmin, options, parallel, nullptr, &cost_computer,
                                 &cost, &left_index, &right_index, wants_runner_up,
                                 wants_winner_sums, &workspace_->scratch);
    } else if (options.scanline_optimization) {
      adcensus::ScanlineOptimize(img_l, img_r, dmin, options, parallel, &cost, nullptr,
                                 &workspace_->scratch, &left_index, &right_index, wants_runner_up,
                                 wants_winner_sums);
      final_cost = &workspace_->scratch;
    }
    result.time_ms.scanline = MsSince(t);

    t = Clock::now();
    if (!options.scanline_optimization)
      adcensus::WinnerTakeAll(cost, dmin, parallel, &left_index, &right_index);
    cv::Mat index;
    if (options.refinement.enabled) {
      adcensus::RefineStats stats;
      index = adcensus::Refine(
          left_index, right_index, *final_cost, dmin, img_l, arms, options.refinement, parallel,
          &stats, wants_runner_up && options.scanline_optimization ? &runner_up : nullptr,
          &workspace_->refine, wants_winner_sums);
      result.occluded_pct = stats.occluded_pct;
      result.mismatch_pct = stats.mismatch_pct;
      result.ambiguous_pct = stats.ambiguous_pct;
    } else {
      index = left_index;
    }
    if (coarse_to_fine) DropRangeEdges(cost, ndisp, &index);
    // Indices → disparities (NaN stays NaN).
    index.convertTo(Reusable(&workspace_->disparity), CV_32F, 1.0, dmin);
    right_index.convertTo(Reusable(&workspace_->disparity_right), CV_32F, 1.0, dmin);
    result.disparity = workspace_->disparity;
    result.disparity_right = workspace_->disparity_right;
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
