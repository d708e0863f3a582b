// The AD-Census matcher: each stage against a brute-force reading of
// method.md, then whole-matcher accuracy on synthetic pairs with known
// disparity (real Middlebury scenes: tests/integration/test_middlebury.cc).
// The executable also runs test_preprocess.cc.
#include <gtest/gtest.h>

#include <bit>
#include <cstring>
#include <opencv2/imgcodecs.hpp>

#include "craftscan/pipeline/stereo/adcensus.h"
#include "stereo/adcensus_internal.h"
#include "test_util.h"

namespace craftscan {
namespace {

using adcensus::Arms;
using testing::RandomTexture;
using testing::RenderRightView;

cv::Mat Grey(const cv::Mat& bgr) {
  cv::Mat g;
  cv::cvtColor(bgr, g, cv::COLOR_BGR2GRAY);
  return g;
}

// --- census and cost --------------------------------------------------------

// Widths below, at and past a 32-pixel run (the AVX2 path's), windows up to
// 64 neighbours, and grey levels at both ends (0 and 255, where a biased
// signed compare would go wrong if the bias were missing).
TEST(Census, MatchesBruteForceWithReplicatedBorders) {
  struct Case {
    int width, height, win_w, win_h;
  };
  for (const Case& c : {Case{37, 23, 9, 7}, Case{5, 4, 3, 3}, Case{70, 9, 13, 5}, Case{64, 6, 1, 3},
                        Case{33, 7, 5, 13}}) {
    cv::Mat grey = Grey(RandomTexture(c.width, c.height, 1));
    grey.at<std::uint8_t>(0, 0) = 0;
    grey.at<std::uint8_t>(c.height - 1, c.width - 1) = 255;
    for (int x = 0; x < c.width; x += 3) grey.at<std::uint8_t>(c.height / 2, x) = x % 2 ? 255 : 0;
    const Parallel parallel(2);
    const auto census = adcensus::CensusTransform(grey, c.win_w, c.win_h, parallel);
    const int rw = c.win_w / 2, rh = c.win_h / 2;
    for (int y = 0; y < grey.rows; ++y) {
      for (int x = 0; x < grey.cols; ++x) {
        std::uint64_t expected = 0;
        const int centre = grey.at<std::uint8_t>(y, x);
        for (int dy = -rh; dy <= rh; ++dy)
          for (int dx = -rw; dx <= rw; ++dx) {
            if (dx == 0 && dy == 0) continue;
            const int v = grey.at<std::uint8_t>(std::clamp(y + dy, 0, grey.rows - 1),
                                                std::clamp(x + dx, 0, grey.cols - 1));
            expected = (expected << 1) | (v < centre ? 1u : 0u);
          }
        ASSERT_EQ(census[y * grey.cols + x], expected)
            << c.width << "x" << c.height << " window " << c.win_w << "x" << c.win_h << " at " << x
            << "," << y;
      }
    }
  }
}

TEST(Cost, MatchesMeiFormulaIncludingOutOfImageDisparities) {
  const cv::Mat left = RandomTexture(41, 19, 2), right = RandomTexture(41, 19, 3);
  const Parallel parallel(1);
  const auto cl = adcensus::CensusTransform(Grey(left), 9, 7, parallel);
  const auto cr = adcensus::CensusTransform(Grey(right), 9, 7, parallel);
  const int min_disparity = -3, ndisp = 12;
  adcensus::CostVolume cost(left.cols, left.rows, ndisp);
  adcensus::ComputeCost(left, right, cl, cr, min_disparity, 10, 30, 1.5f, parallel, &cost);
  int checked_out_of_image = 0;
  for (int y = 0; y < left.rows; ++y) {
    for (int x = 0; x < left.cols; ++x) {
      for (int k = 0; k < ndisp; ++k) {
        const int xr = x - (min_disparity + k);
        // Fixed point: each ρ term rounded to 1/kCostScale.
        const double got = static_cast<double>(cost.at(y, x)[k]) / adcensus::kCostScale;
        if (xr < 0 || xr >= left.cols) {
          EXPECT_EQ(cost.at(y, x)[k], 1.5 * adcensus::kCostScale);
          ++checked_out_of_image;
          continue;
        }
        const cv::Vec3b a = left.at<cv::Vec3b>(y, x), b = right.at<cv::Vec3b>(y, xr);
        const double ad =
            (std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2])) / 3.0;
        const int hamming = std::popcount(cl[y * left.cols + x] ^ cr[y * left.cols + xr]);
        const double expected = (1 - std::exp(-ad / 10)) + (1 - std::exp(-hamming / 30.0));
        ASSERT_NEAR(got, expected, 1.0 / adcensus::kCostScale + 1e-9)
            << "at " << x << "," << y << " k " << k;
      }
    }
  }
  EXPECT_GT(checked_out_of_image, 0);
}

// Each ρ term rounded to 1/kCostScale on its own, then summed: the exact
// fixed-point value, whichever way the row is computed (when ρ_AD saturates by
// a sum of 255: in-register look-ups on AVX-512, the 16-bit table by vector
// indices on AVX2; the 32-bit table otherwise).
TEST(Cost, RowsAreTheFixedPointTermsExactlyForColourAndGreyAndAnyLambda) {
  const cv::Mat colour_left = RandomTexture(77, 9, 5), colour_right = RandomTexture(77, 9, 6);
  const Parallel parallel(2);
  struct Case {
    bool grey;
    double lambda_ad;  // 10: saturates (in-register); 60 with colour: does not (table)
    int min_disparity, ndisp;
  };
  for (const Case& c : {Case{false, 10, -5, 40}, Case{true, 10, -5, 40}, Case{false, 60, 3, 33},
                        Case{true, 25, 0, 70}, Case{false, 10, -20, 97}}) {
    const cv::Mat left = c.grey ? Grey(colour_left) : colour_left;
    const cv::Mat right = c.grey ? Grey(colour_right) : colour_right;
    const auto cl = adcensus::CensusTransform(Grey(colour_left), 9, 7, parallel);
    const auto cr = adcensus::CensusTransform(Grey(colour_right), 9, 7, parallel);
    adcensus::CostVolume cost(left.cols, left.rows, c.ndisp);
    adcensus::ComputeCost(left, right, cl, cr, c.min_disparity, c.lambda_ad, 30, 1.25f, parallel,
                          &cost);
    const int ch = left.channels();
    const auto fixed = [](double v) { return std::lround(v * adcensus::kCostScale); };
    for (int y = 0; y < left.rows; ++y)
      for (int x = 0; x < left.cols; ++x)
        for (int k = 0; k < cost.stride(); ++k) {
          const int xr = x - (c.min_disparity + k);
          long expected;
          if (k >= c.ndisp) {
            expected = adcensus::CostVolume::kPadCost;
          } else if (xr < 0 || xr >= left.cols) {
            expected = fixed(1.25);
          } else {
            int sad = 0;
            for (int q = 0; q < ch; ++q)
              sad += std::abs(left.ptr<std::uint8_t>(y)[ch * x + q] -
                              right.ptr<std::uint8_t>(y)[ch * xr + q]);
            const int hamming = std::popcount(cl[y * left.cols + x] ^ cr[y * left.cols + xr]);
            expected = fixed(1 - std::exp(-(static_cast<double>(sad) / ch) / c.lambda_ad)) +
                       fixed(1 - std::exp(-hamming / 30.0));
          }
          ASSERT_EQ(cost.at(y, x)[k], expected)
              << (c.grey ? "grey" : "colour") << " lambda_ad " << c.lambda_ad << " at " << x << ","
              << y << " k " << k;
        }
  }
}

// --- cross arms -------------------------------------------------------------

// method.md §5 read literally, one pixel and one direction at a time.
int ReferenceArm(const cv::Mat& img, const cv::Mat& gradient, const cv::Mat& edges, int y, int x,
                 int dx, int dy, const ADCensusOptions& o) {
  auto colour_diff = [&](int y1, int x1, int y2, int x2) {
    const cv::Vec3b a = img.at<cv::Vec3b>(y1, x1), b = img.at<cv::Vec3b>(y2, x2);
    return std::max({std::abs(a[0] - b[0]), std::abs(a[1] - b[1]), std::abs(a[2] - b[2])});
  };
  double l_max, l2, tau, tau2;
  bool use_gradient = false;
  if (o.arm_rule == ArmRule::kClassic) {
    l_max = o.classic.l1_px, l2 = o.classic.l2_px, tau = o.classic.tau1, tau2 = o.classic.tau2;
  } else {
    const auto& im = o.improved;
    const bool edge = gradient.at<float>(y, x) >= im.beta_max || edges.at<std::uint8_t>(y, x) != 0;
    l_max = edge ? std::lround(im.l_max_px * im.edge_length_scale) : im.l_max_px;
    l2 = edge ? im.l2_px * im.edge_length_scale : im.l2_px;
    tau = edge ? im.tau_max * im.edge_tau_scale : im.tau_max;
    tau2 = im.tau2;
    use_gradient = true;
  }
  int len = 0;
  for (int s = 1;; ++s) {
    const int qx = x + s * dx, qy = y + s * dy;
    if (qx < 0 || qy < 0 || qx >= img.cols || qy >= img.rows) break;
    const int to_anchor = colour_diff(qy, qx, y, x);
    const int to_prev = colour_diff(qy, qx, qy - dy, qx - dx);
    if (!(s < l_max) || !(to_anchor < tau) || !(to_prev < tau)) break;
    if (s > l2 && !(to_anchor < tau2)) break;
    if (use_gradient &&
        !(std::abs(gradient.at<float>(qy, qx) - gradient.at<float>(y, x)) < o.improved.beta1))
      break;
    len = s;
  }
  return len;
}

void ExpectArmsMatchReference(const cv::Mat& img, ArmRule rule) {
  ADCensusOptions o;
  o.arm_rule = rule;
  const Preprocessed pre = Preprocess(img, o.preprocess);
  const Arms arms = adcensus::BuildArms(img, pre.gradient, pre.edges, o, Parallel(2));
  for (int y = 0; y < img.rows; ++y) {
    for (int x = 0; x < img.cols; ++x) {
      const std::size_t i = arms.index(y, x);
      ASSERT_EQ(arms.left[i], ReferenceArm(img, pre.gradient, pre.edges, y, x, -1, 0, o))
          << x << "," << y;
      ASSERT_EQ(arms.right[i], ReferenceArm(img, pre.gradient, pre.edges, y, x, 1, 0, o))
          << x << "," << y;
      ASSERT_EQ(arms.up[i], ReferenceArm(img, pre.gradient, pre.edges, y, x, 0, -1, o))
          << x << "," << y;
      ASSERT_EQ(arms.down[i], ReferenceArm(img, pre.gradient, pre.edges, y, x, 0, 1, o))
          << x << "," << y;
    }
  }
}

// Flat patches, gentle ramps, steps and texture: every rule gets exercised.
cv::Mat CraftedArmImage() {
  cv::Mat img(90, 120, CV_8UC3, cv::Scalar(100, 100, 100));
  for (int x = 0; x < 60; ++x)  // a gentle ramp: colour drifts slowly from the anchor
    img.col(x).setTo(cv::Scalar(60 + x / 2, 80, 90));
  img(cv::Rect(60, 0, 30, 45)).setTo(cv::Scalar(200, 40, 40));  // a strong step
  img(cv::Rect(70, 50, 40, 30)) = RandomTexture(40, 30, 7) / 4 + cv::Scalar(90, 90, 90);
  cv::line(img, {10, 60}, {50, 85}, cv::Scalar(0, 0, 0), 1);  // a thin dark edge
  return img;
}

TEST(Arms, ClassicRuleMatchesReference) {
  ExpectArmsMatchReference(CraftedArmImage(), ArmRule::kClassic);
  ExpectArmsMatchReference(RandomTexture(64, 48, 11), ArmRule::kClassic);
}

TEST(Arms, ImprovedRuleMatchesReference) {
  ExpectArmsMatchReference(CraftedArmImage(), ArmRule::kImproved);
  ExpectArmsMatchReference(RandomTexture(64, 48, 12), ArmRule::kImproved);
}

TEST(Arms, EdgePixelsGetShorterArmsThanWeakTexture) {
  // A flat field with one vertical line: pixels on the (dilated) edge may
  // reach at most L_max/2 − 1 = 16 along the line; flat pixels reach 33.
  cv::Mat img(80, 80, CV_8UC3, cv::Scalar(120, 120, 120));
  img.col(40).setTo(cv::Scalar(20, 20, 20));
  ADCensusOptions o;
  const Preprocessed pre = Preprocess(img, o.preprocess);
  ASSERT_TRUE(adcensus::IsEdgePixel(pre.gradient, pre.edges, 40, 40, o.improved));
  ASSERT_FALSE(adcensus::IsEdgePixel(pre.gradient, pre.edges, 40, 10, o.improved));
  const Arms arms = adcensus::BuildArms(img, pre.gradient, pre.edges, o, Parallel(1));
  const std::size_t on_line = arms.index(40, 40), flat = arms.index(40, 10);
  EXPECT_EQ(arms.up[on_line], 16);
  EXPECT_EQ(arms.down[on_line], 16);
  EXPECT_EQ(arms.up[flat], 33);
  EXPECT_EQ(arms.down[flat], 33);
  // The classic rule makes no such distinction.
  o.arm_rule = ArmRule::kClassic;
  const Arms classic = adcensus::BuildArms(img, pre.gradient, pre.edges, o, Parallel(1));
  EXPECT_EQ(classic.up[on_line], 33);
  // Arms never cross the line: the classic arm stops at the line's colour
  // step (x = 40), the improved one already where the gradient rises (x = 39).
  EXPECT_EQ(classic.right[classic.index(40, 30)], 9);
  EXPECT_EQ(arms.right[arms.index(40, 30)], 8);
}

TEST(Aggregation, SupportRegionAverageMatchesBruteForce) {
  const cv::Mat img = CraftedArmImage();
  ADCensusOptions o;
  const Preprocessed pre = Preprocess(img, o.preprocess);
  const Parallel parallel(2);
  const Arms arms = adcensus::BuildArms(img, pre.gradient, pre.edges, o, parallel);
  const int ndisp = 3;
  adcensus::CostVolume cost(img.cols, img.rows, ndisp);
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> u(0, 2 * adcensus::kCostScale);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x)
      for (int k = 0; k < cost.stride(); ++k)
        cost.at(y, x)[k] = static_cast<adcensus::Cost>(k < ndisp ? u(rng) : 0);
  std::vector<float> original(static_cast<std::size_t>(img.total()) * ndisp);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x)
      for (int k = 0; k < ndisp; ++k) original[(y * img.cols + x) * ndisp + k] = cost.at(y, x)[k];

  adcensus::Aggregate(arms, 1, parallel, &cost);  // one horizontal-first iteration
  for (int y = 0; y < img.rows; y += 3) {
    for (int x = 0; x < img.cols; x += 3) {
      const std::size_t i = arms.index(y, x);
      for (int k = 0; k < ndisp; ++k) {
        double sum = 0;
        int n = 0;
        for (int v = y - arms.up[i]; v <= y + arms.down[i]; ++v) {
          const std::size_t j = arms.index(v, x);
          for (int u2 = x - arms.left[j]; u2 <= x + arms.right[j]; ++u2, ++n)
            sum += original[(v * img.cols + u2) * ndisp + k];
        }
        ASSERT_EQ(n, adcensus::SupportSize(arms, y, x, true));
        // Two roundings: the horizontal segment means (at most 0.5 each,
        // weighted back by their lengths) and the region mean.
        ASSERT_NEAR(cost.at(y, x)[k], sum / n, 1.0 + 1e-6) << x << "," << y;
      }
    }
  }
}

// --- the whole matcher on synthetic pairs -----------------------------------

struct Score {
  double bad1 = 0, max_abs_err = 0;
};

// Scores pixels whose match lies inside the right image, away from the
// image border (where no method has support).
Score ScoreAgainst(const cv::Mat& disparity, const cv::Mat& gt, int margin) {
  Score s;
  int n = 0, bad = 0;
  for (int y = margin; y < gt.rows - margin; ++y) {
    for (int x = margin; x < gt.cols - margin; ++x) {
      const float g = gt.at<float>(y, x);
      if (x - g < margin || x - g >= gt.cols - margin) continue;
      ++n;
      const float d = disparity.at<float>(y, x);
      const double e = IsValidDisparity(d) ? std::abs(d - g) : 1e9;
      if (e > 1) ++bad;
      if (IsValidDisparity(d)) s.max_abs_err = std::max(s.max_abs_err, e);
    }
  }
  s.bad1 = 100.0 * bad / std::max(n, 1);
  return s;
}

TEST(Matcher, RecoversConstantDisparityWithOffsetRange) {
  const cv::Mat left = RandomTexture(200, 120, 21);
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 37, 0, 0, &gt);
  for (ArmRule rule : {ArmRule::kImproved, ArmRule::kClassic}) {
    ADCensusOptions o;
    o.arm_rule = rule;
    o.min_disparity = 25;  // the true 37 lies inside [25, 57)
    o.num_disparities = 32;
    o.num_threads = 2;
    const DisparityResult r = ComputeDisparity(left, right, o);
    ASSERT_TRUE(r.IsUsable()) << r.message;
    const Score s = ScoreAgainst(r.disparity, gt, 5);
    EXPECT_LT(s.bad1, 1.0) << ToString(rule);
    EXPECT_GT(r.valid_pct, 95.0);
  }
}

TEST(Matcher, RecoversSlantedPlane) {
  const cv::Mat left = RandomTexture(240, 160, 22);
  cv::Mat gt;
  // d from 30 to ~48 across the image, plus a vertical tilt.
  const cv::Mat right = RenderRightView(left, 30, 0.06, 0.03, &gt);
  ADCensusOptions o;
  o.min_disparity = 20;
  o.num_disparities = 40;
  o.num_threads = 2;
  const DisparityResult r = ComputeDisparity(left, right, o);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  const Score s = ScoreAgainst(r.disparity, gt, 5);
  EXPECT_LT(s.bad1, 1.0);
}

TEST(Matcher, GreyImagesWork) {
  const cv::Mat left = Grey(RandomTexture(160, 100, 23));
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 12, 0, 0, &gt);
  ADCensusOptions o;
  o.num_disparities = 24;
  const DisparityResult r = ComputeDisparity(left, right, o);
  ASSERT_TRUE(r.IsUsable()) << r.message;
  EXPECT_LT(ScoreAgainst(r.disparity, gt, 5).bad1, 1.0);
}

TEST(Matcher, SerialAndThreadedResultsAreIdentical) {
  const cv::Mat left = RandomTexture(180, 140, 24);
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 15, 0.05, 0, &gt);
  // With aggregation (two volumes) and without it, outliers filled or left
  // invalid (the station's setting: one volume, costs recomputed in place).
  for (const int iterations : {4, 0}) {
    ADCensusOptions o;
    o.num_disparities = 40;
    o.aggregation_iterations = iterations;
    o.refinement.interpolate = iterations != 0;
    o.num_threads = 1;
    const DisparityResult serial = ComputeDisparity(left, right, o);
    o.num_threads = 2;
    const DisparityResult two = ComputeDisparity(left, right, o);
    o.num_threads = 3;
    const DisparityResult three = ComputeDisparity(left, right, o);
    ASSERT_TRUE(serial.IsUsable() && two.IsUsable() && three.IsUsable());
    const std::size_t bytes = serial.disparity.total() * sizeof(float);
    EXPECT_EQ(0, std::memcmp(serial.disparity.data, two.disparity.data, bytes)) << iterations;
    EXPECT_EQ(0, std::memcmp(serial.disparity.data, three.disparity.data, bytes)) << iterations;
    EXPECT_EQ(0, std::memcmp(serial.disparity_right.data, three.disparity_right.data, bytes))
        << iterations;
  }
}

// One matcher keeps its volumes and the refinement's maps between calls (a
// station matches view after view): a call must not see what the last one
// left there, whatever the scene, its size or the refinement (the
// uniqueness test's runner-up costs, interpolation on and off).
TEST(Matcher, AReusedMatcherGivesWhatAFreshOneGives) {
  struct Case {
    int width, height, disparity;
    std::uint64_t seed;
  };
  const std::vector<Case> cases = {{180, 120, 15, 31}, {160, 100, 22, 32}, {180, 120, 9, 33}};
  for (const int iterations : {4, 0}) {
    for (const double uniqueness : {0.0, 0.2}) {
      ADCensusOptions o;
      o.num_disparities = 40;
      o.num_threads = 2;
      o.aggregation_iterations = iterations;
      o.refinement.interpolate = iterations != 0;
      o.refinement.uniqueness = uniqueness;
      StereoMatcher reused(o);
      for (const Case& c : cases) {
        const cv::Mat left = RandomTexture(c.width, c.height, c.seed);
        cv::Mat gt;
        const cv::Mat right = RenderRightView(left, c.disparity, 0.04, 0, &gt);
        const DisparityResult again = reused.Compute(left, right);
        const DisparityResult fresh = ComputeDisparity(left, right, o);
        ASSERT_TRUE(again.IsUsable() && fresh.IsUsable()) << again.message << fresh.message;
        ASSERT_EQ(again.disparity.size(), fresh.disparity.size());
        const std::size_t bytes = fresh.disparity.total() * sizeof(float);
        EXPECT_EQ(0, std::memcmp(again.disparity.data, fresh.disparity.data, bytes))
            << iterations << " " << uniqueness << " " << c.seed;
        EXPECT_EQ(0, std::memcmp(again.disparity_right.data, fresh.disparity_right.data, bytes))
            << iterations << " " << uniqueness << " " << c.seed;
        EXPECT_LT(ScoreAgainst(again.disparity, gt, 5).bad1, 5.0);
      }
    }
  }
}

// The matcher writes its next maps into the last result's memory only once
// the caller has dropped it: results a caller keeps stay as they were, and a
// reused matcher's images (colour, grey, colour again, of one size) are
// preprocessed in place without one image's maps leaking into the next.
TEST(Matcher, ResultsACallerKeepsAreNotOverwrittenByLaterCalls) {
  ADCensusOptions o;
  o.num_disparities = 32;
  o.num_threads = 2;
  StereoMatcher reused(o);
  std::vector<DisparityResult> kept;
  std::vector<cv::Mat> copies, truths;
  for (const std::uint64_t seed : {41, 42, 43, 44}) {
    cv::Mat left = RandomTexture(170, 110, seed);
    if (seed % 2 == 0) left = Grey(left);
    cv::Mat gt;
    const cv::Mat right = RenderRightView(left, 8 + static_cast<int>(seed % 4) * 5, 0.03, 0, &gt);
    DisparityResult again = reused.Compute(left, right);
    const DisparityResult fresh = ComputeDisparity(left, right, o);
    ASSERT_TRUE(again.IsUsable() && fresh.IsUsable()) << again.message << fresh.message;
    const std::size_t bytes = fresh.disparity.total() * sizeof(float);
    EXPECT_EQ(0, std::memcmp(again.disparity.data, fresh.disparity.data, bytes)) << seed;
    EXPECT_LT(ScoreAgainst(again.disparity, gt, 5).bad1, 5.0) << seed;
    if (seed != 42) continue;  // 41, 43 and 44 are dropped: their memory serves again
    copies.push_back(again.disparity.clone());
    copies.push_back(again.disparity_right.clone());
    kept.push_back(std::move(again));
  }
  ASSERT_EQ(kept.size(), 1u);
  const std::size_t bytes = copies[0].total() * sizeof(float);  // NaN compares by its bits
  EXPECT_EQ(0, std::memcmp(kept[0].disparity.data, copies[0].data, bytes));
  EXPECT_EQ(0, std::memcmp(kept[0].disparity_right.data, copies[1].data, bytes));
}

TEST(Matcher, WithoutInterpolationOutliersAreMarkedInvalid) {
  const cv::Mat left = RandomTexture(160, 100, 25);
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 20, 0, 0, &gt);
  ADCensusOptions o;
  o.num_disparities = 32;
  o.refinement.interpolate = false;
  const DisparityResult r = ComputeDisparity(left, right, o);
  ASSERT_TRUE(r.IsUsable());
  // The left 20 columns see nothing in the right image: they must be invalid.
  int invalid_border = 0;
  for (int y = 10; y < 90; ++y)
    for (int x = 0; x < 15; ++x)
      invalid_border += IsValidDisparity(r.disparity.at<float>(y, x)) ? 0 : 1;
  EXPECT_GT(invalid_border, 80 * 15 * 9 / 10);
  EXPECT_LT(r.valid_pct, 95.0);
  EXPECT_LT(ScoreAgainst(r.disparity, gt, 5).max_abs_err, 1.0);
}

TEST(Matcher, UniquenessMarksARepeatedPatternUnreliable) {
  // Vertical stripes of period 8 px over the whole image: every disparity
  // 8 px from the true one fits as well, so no winner is unique. A random
  // texture has one clear minimum everywhere.
  cv::Mat stripes(120, 240, CV_8UC3);
  for (int y = 0; y < stripes.rows; ++y)
    for (int x = 0; x < stripes.cols; ++x)
      stripes.at<cv::Vec3b>(y, x) = (x / 4) % 2 ? cv::Vec3b(200, 200, 200) : cv::Vec3b(40, 40, 40);
  const cv::Mat texture = RandomTexture(240, 120, 26);
  cv::Mat gt;
  ADCensusOptions o;
  o.num_disparities = 40;
  o.refinement.interpolate = false;
  for (double uniqueness : {0.0, 0.15}) {
    o.refinement.uniqueness = uniqueness;
    const DisparityResult s = ComputeDisparity(stripes, RenderRightView(stripes, 20, 0, 0, &gt), o);
    const DisparityResult t = ComputeDisparity(texture, RenderRightView(texture, 20, 0, 0, &gt), o);
    ASSERT_TRUE(s.IsUsable() && t.IsUsable()) << s.message << t.message;
    if (uniqueness == 0) {
      EXPECT_EQ(s.ambiguous_pct, 0);
      EXPECT_GT(s.valid_pct, 50);  // the left-right check keeps most of the guesses
    } else {
      EXPECT_GT(s.ambiguous_pct, 50);
      EXPECT_LT(s.valid_pct, 30);
      EXPECT_LT(t.ambiguous_pct, 1);
      EXPECT_LT(ScoreAgainst(t.disparity, gt, 5).bad1, 1.0);
    }
  }
  o.refinement.uniqueness = 1;
  EXPECT_NE(ComputeDisparity(texture, texture, o).message.find("uniqueness"), std::string::npos);
}

TEST(Matcher, RejectsBadInputWithAClearMessage) {
  const cv::Mat a = RandomTexture(50, 40, 1), b = RandomTexture(51, 40, 2);
  ADCensusOptions o;
  DisparityResult r = ComputeDisparity(a, b, o);
  EXPECT_FALSE(r.IsUsable());
  EXPECT_NE(r.message.find("sizes differ"), std::string::npos) << r.message;
  r = ComputeDisparity(a, cv::Mat(), o);
  EXPECT_NE(r.message.find("empty"), std::string::npos) << r.message;
  cv::Mat f;
  a.convertTo(f, CV_32FC3);
  r = ComputeDisparity(f, f, o);
  EXPECT_NE(r.message.find("CV_8UC1"), std::string::npos) << r.message;
  r = ComputeDisparity(a, Grey(a), o);
  EXPECT_FALSE(r.IsUsable());
  o.num_disparities = 0;
  r = ComputeDisparity(a, a, o);
  EXPECT_NE(r.message.find("num_disparities"), std::string::npos) << r.message;
  o = {};
  o.census_width = 8;
  r = ComputeDisparity(a, a, o);
  EXPECT_NE(r.message.find("census"), std::string::npos) << r.message;
  o = {};
  o.min_disparity = 60;  // the images are 50 px wide
  r = ComputeDisparity(a, a, o);
  EXPECT_NE(r.message.find("outside the image"), std::string::npos) << r.message;
  o = {};
  o.num_disparities = 4096;
  r = ComputeDisparity(cv::Mat(1000, 1000, CV_8UC1, cv::Scalar(0)),
                       cv::Mat(1000, 1000, CV_8UC1, cv::Scalar(0)), o);
  EXPECT_NE(r.message.find("too large"), std::string::npos) << r.message;
  o = {};
  o.num_threads = 0;
  r = ComputeDisparity(a, a, o);
  EXPECT_NE(r.message.find("num_threads"), std::string::npos) << r.message;
}

// --- per-pixel disparity ranges (coarse-to-fine) -----------------------------

TEST(Cost, PerPixelOffsetsHoldTheirOwnDisparities) {
  const cv::Mat left = RandomTexture(53, 17, 31), right = RandomTexture(53, 17, 32);
  const Parallel parallel(2);
  const auto cl = adcensus::CensusTransform(Grey(left), 9, 7, parallel);
  const auto cr = adcensus::CensusTransform(Grey(right), 9, 7, parallel);
  const int min_disparity = -5, total = 80, lanes = 32;
  adcensus::CostVolume full(left.cols, left.rows, total), ranged(left.cols, left.rows, lanes);
  adcensus::ComputeCost(left, right, cl, cr, min_disparity, 10, 30, 1.0f, parallel, &full);
  std::vector<std::int32_t> offsets(left.total());
  cv::RNG rng(5);
  for (std::int32_t& o : offsets) o = rng.uniform(0, total - lanes + 1);
  ranged.SetOffsets(offsets, total);
  adcensus::ComputeCost(left, right, cl, cr, min_disparity, 10, 30, 1.0f, parallel, &ranged);
  for (int y = 0; y < left.rows; ++y)
    for (int x = 0; x < left.cols; ++x)
      for (int k = 0; k < lanes; ++k)
        ASSERT_EQ(ranged.at(y, x)[k], full.at(y, x)[ranged.offset(y, x) + k])
            << x << "," << y << " lane " << k;
}

bool SameOrBothNaN(const cv::Mat& a, const cv::Mat& b, float shift) {
  for (int y = 0; y < a.rows; ++y)
    for (int x = 0; x < a.cols; ++x) {
      const float u = a.at<float>(y, x), v = b.at<float>(y, x);
      if (IsValidDisparity(u) != IsValidDisparity(v)) return false;
      // Sub-pixel values: (k + shift) + f against k + f + shift in float.
      if (IsValidDisparity(u) && std::abs(u + shift - v) > 1e-4f) return false;
    }
  return true;
}

// Every pixel holding the same range of a wider band is the narrower band
// itself: the scanline paths, both views' winners and the refinement agree
// exactly, in indices shifted by the offset.
TEST(Scanline, UniformOffsetsEqualTheShiftedBand) {
  const cv::Mat left = RandomTexture(150, 90, 33);
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 30, 0.05, 0, &gt);
  const Parallel parallel(2);
  ADCensusOptions o;
  const Preprocessed pre = Preprocess(left, o.preprocess);
  const auto cl = adcensus::CensusTransform(Grey(left), 9, 7, parallel);
  const auto cr = adcensus::CensusTransform(Grey(right), 9, 7, parallel);
  const Arms arms = adcensus::BuildArms(left, pre.gradient, pre.edges, o, parallel);
  const int offset = 16, lanes = 48, total = 96;
  o.refinement.interpolate = false;

  adcensus::CostVolume band(left.cols, left.rows, lanes);
  const adcensus::CostComputer band_costs(left, right, cl, cr, offset, lanes, 10, 30, 1.0);
  adcensus::ComputeCost(band_costs, parallel, &band);
  cv::Mat band_left, band_right;
  adcensus::ScanlineOptimize(left, right, offset, o, parallel, nullptr, &band_costs, &band,
                             &band_left, &band_right);
  const cv::Mat band_refined = adcensus::Refine(band_left, band_right, band, offset, left, arms,
                                                o.refinement, parallel, nullptr);

  adcensus::CostVolume ranged(left.cols, left.rows, lanes);
  ranged.SetOffsets(std::vector<std::int32_t>(left.total(), offset), total);
  const adcensus::CostComputer ranged_costs(left, right, cl, cr, 0, lanes, 10, 30, 1.0);
  adcensus::ComputeCost(ranged_costs, parallel, &ranged);
  cv::Mat ranged_left, ranged_right;
  adcensus::ScanlineOptimize(left, right, 0, o, parallel, nullptr, &ranged_costs, &ranged,
                             &ranged_left, &ranged_right);
  const cv::Mat ranged_refined = adcensus::Refine(ranged_left, ranged_right, ranged, 0, left, arms,
                                                  o.refinement, parallel, nullptr);

  EXPECT_EQ(0, std::memcmp(band.at(0, 0), ranged.at(0, 0),
                           left.total() * band.stride() * sizeof(adcensus::Cost)));
  EXPECT_TRUE(SameOrBothNaN(band_left, ranged_left, offset));
  EXPECT_TRUE(SameOrBothNaN(band_right, ranged_right, offset));
  EXPECT_TRUE(SameOrBothNaN(band_refined, ranged_refined, offset));
  EXPECT_GT(cv::countNonZero(band_refined == band_refined), static_cast<int>(left.total() / 2));
}

// With a store the sweep that reaches a row first computes its costs for
// both, and the other reads them there (the station's scanline, whose costs
// are never a volume): the sums and both views' winners are those of every
// sweep computing its own rows, at one and two threads, with per-pixel
// ranges that change from pixel to pixel and row to row.
TEST(Scanline, CostRowsSharedByTheSweepsGiveTheRecomputedResult) {
  const cv::Mat left = RandomTexture(170, 110, 57);
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 28, 0.06, 0, &gt);
  ADCensusOptions o;
  const int lanes = 32, total = 80;
  std::vector<std::int32_t> offsets(left.total());
  for (int y = 0; y < left.rows; ++y)
    for (int x = 0; x < left.cols; ++x)
      offsets[static_cast<std::size_t>(y) * left.cols + x] =
          (x / 7 * 5 + y / 3 * 3) % (total - lanes + 1);
  for (int threads : {1, 2}) {
    const Parallel parallel(threads);
    const auto cl = adcensus::CensusTransform(Grey(left), 9, 7, parallel);
    const auto cr = adcensus::CensusTransform(Grey(right), 9, 7, parallel);
    const adcensus::CostComputer costs(left, right, cl, cr, 0, lanes, 10, 30, 1.0);
    adcensus::CostVolume own(left.cols, left.rows, lanes), shared(left.cols, left.rows, lanes),
        store;
    own.SetOffsets(offsets, total);
    shared.SetOffsets(offsets, total);
    cv::Mat own_l, own_r, shared_l, shared_r, own_u, shared_u;
    adcensus::ScanlineOptimize(left, right, 0, o, parallel, nullptr, &costs, &own, &own_l, &own_r,
                               &own_u);
    adcensus::ScanlineOptimize(left, right, 0, o, parallel, nullptr, &costs, &shared, &shared_l,
                               &shared_r, &shared_u, nullptr, &store);
    // The store holds every row's matching costs.
    std::vector<adcensus::Cost> row(static_cast<std::size_t>(left.cols) * own.stride());
    adcensus::CostComputer::Scratch scratch;
    for (int y : {0, left.rows / 2, left.rows - 1}) {
      costs.Row(y, &scratch, row.data(), own.offset_row(y));
      EXPECT_EQ(0, std::memcmp(row.data(), store.row(y), row.size() * sizeof(adcensus::Cost)))
          << threads << " threads, row " << y;
    }
    EXPECT_EQ(0, std::memcmp(own.at(0, 0), shared.at(0, 0),
                             left.total() * own.stride() * sizeof(adcensus::Cost)))
        << threads;
    EXPECT_TRUE(SameOrBothNaN(own_l, shared_l, 0)) << threads;
    EXPECT_TRUE(SameOrBothNaN(own_r, shared_r, 0)) << threads;
    EXPECT_EQ(0, std::memcmp(own_u.data, shared_u.data, own_u.total() * own_u.elemSize()))
        << threads;
    // The sums are the matching costs' paths: not a constant volume.
    EXPECT_GT(cv::countNonZero(own_l != own_l.at<float>(0, 0)), static_cast<int>(left.total() / 2));
  }
}

// The scanline pass hands the uniqueness test each pixel's winning and
// runner-up costs; they are what the volume it leaves gives, and the
// refinement's labels and disparities do not depend on where they came from.
// The runner-up itself: the least cost at least 2 from the winner among the
// disparities held.
// The left-right check, rule by rule: dL within the tolerance of the right
// disparity where it lands, or between that one's and a neighbour's (within
// the tolerance) when the two differ by 2 or 3 px (one steep surface).
bool PassesLeftRight(const float* r, int width, int xr, float dl, double tolerance) {
  if (!IsValidDisparity(r[xr])) return false;
  if (std::abs(r[xr] - dl) <= tolerance) return true;
  for (int a : {xr - 1, xr}) {
    if (a < 0 || a + 1 >= width || !IsValidDisparity(r[a]) || !IsValidDisparity(r[a + 1]) ||
        std::abs(r[a + 1] - r[a]) < 2 || std::abs(r[a + 1] - r[a]) > 3)
      continue;
    if (dl >= std::min(r[a], r[a + 1]) - tolerance && dl <= std::max(r[a], r[a + 1]) + tolerance)
      return true;
  }
  return false;
}

TEST(Scanline, RunnerUpCostsAndWinnerSumsAreTheVolumes) {
  const cv::Mat left = RandomTexture(160, 96, 41);
  cv::Mat gt;
  const cv::Mat right = RenderRightView(left, 24, 0.04, 0, &gt);
  ADCensusOptions o;
  o.refinement.interpolate = false;
  o.refinement.uniqueness = 0.05;
  const Preprocessed pre = Preprocess(left, o.preprocess);
  const int ndisp = 40;  // a padded stride of 48: the padding lanes are not held
  for (int threads : {1, 2, 3}) {
    const Parallel parallel(threads);
    const auto cl = adcensus::CensusTransform(Grey(left), 9, 7, parallel);
    const auto cr = adcensus::CensusTransform(Grey(right), 9, 7, parallel);
    const Arms arms = adcensus::BuildArms(left, pre.gradient, pre.edges, o, parallel);
    adcensus::CostVolume volume(left.cols, left.rows, ndisp);
    const adcensus::CostComputer costs(left, right, cl, cr, 0, ndisp, 10, 30, 1.0);
    cv::Mat l, r, runner_up, winner_sums;
    adcensus::ScanlineOptimize(left, right, 0, o, parallel, nullptr, &costs, &volume, &l, &r,
                               &runner_up, &winner_sums);
    ASSERT_EQ(runner_up.type(), CV_32SC2);
    ASSERT_EQ(winner_sums.type(), CV_16SC3);
    int checked = 0, with_runner_up = 0;
    for (int y = 0; y < left.rows; ++y) {
      for (int x = 0; x < left.cols; ++x) {
        const adcensus::Cost* c = volume.at(y, x);
        const int k = static_cast<int>(l.at<float>(y, x));
        int brute = adcensus::kNoRunnerUp;
        for (int j = 0; j < ndisp; ++j)
          if (std::abs(j - k) >= 2) brute = std::min(brute, static_cast<int>(c[j]));
        const cv::Vec2i given = runner_up.at<cv::Vec2i>(y, x);
        ASSERT_EQ(given[0], c[k]) << y << "," << x;
        ASSERT_EQ(given[1], brute) << y << "," << x;
        ASSERT_EQ(adcensus::RunnerUpCost(c, ndisp, volume.stride(), k), brute);
        const cv::Vec3s sums = winner_sums.at<cv::Vec3s>(y, x);
        ASSERT_EQ(sums[0], k > 0 ? c[k - 1] : 0) << y << "," << x;
        ASSERT_EQ(sums[1], c[k]) << y << "," << x;
        ASSERT_EQ(sums[2], c[k + 1]) << y << "," << x;  // k + 1 < 40 < the stride
        ++checked;
        with_runner_up += brute != adcensus::kNoRunnerUp;
      }
    }
    EXPECT_EQ(checked, with_runner_up);
    adcensus::RefineStats from_pass, from_volume;
    const cv::Mat a = adcensus::Refine(l, r, volume, 0, left, arms, o.refinement, parallel,
                                       &from_pass, &runner_up);
    const cv::Mat b = adcensus::Refine(l, r, volume, 0, left, arms, o.refinement, parallel,
                                       &from_volume, nullptr);
    EXPECT_TRUE(SameOrBothNaN(a, b, 0));
    EXPECT_EQ(from_pass.ambiguous_pct, from_volume.ambiguous_pct);
    // The sub-pixel step from the kept sums: the same values to the bit.
    const cv::Mat kept = adcensus::Refine(l, r, volume, 0, left, arms, o.refinement, parallel,
                                          nullptr, &runner_up, nullptr, &winner_sums)
                             .clone();
    ASSERT_EQ(kept.size(), a.size());
    EXPECT_EQ(std::memcmp(kept.data, a.data, a.total() * a.elemSize()), 0);
    int fractional = 0;  // the step moved them
    for (int y = 0; y < kept.rows; ++y)
      for (int x = 0; x < kept.cols; ++x) {
        const float v = kept.at<float>(y, x);
        fractional += IsValidDisparity(v) && v != std::floor(v) ? 1 : 0;
      }
    EXPECT_GT(fractional, static_cast<int>(kept.total() / 4));
    // The left-right check's labels against a brute-force search: a pixel
    // failing it is a mismatch when some disparity j has r(x − j) = j.
    int mismatched = 0, occluded = 0;
    for (int y = 0; y < left.rows; ++y) {
      for (int x = 0; x < left.cols; ++x) {
        const float d = l.at<float>(y, x);
        const int xr = x - static_cast<int>(d);
        if (xr >= 0 && xr < left.cols &&
            PassesLeftRight(r.ptr<float>(y), left.cols, xr, d, o.refinement.lr_tolerance_px))
          continue;
        bool mismatch = false;
        for (int j = 0; j < ndisp && !mismatch; ++j)
          mismatch = x - j >= 0 && r.at<float>(y, x - j) == static_cast<float>(j);
        ++(mismatch ? mismatched : occluded);
      }
    }
    const double n = static_cast<double>(left.total());
    EXPECT_EQ(from_pass.mismatch_pct, 100.0 * mismatched / n);
    EXPECT_EQ(from_pass.occluded_pct, 100.0 * occluded / n);
    EXPECT_GT(mismatched, 0);
    EXPECT_GT(occluded, 0);
    EXPECT_GT(from_pass.ambiguous_pct, 0.1);  // the test marks some pixels
    EXPECT_GT(cv::countNonZero(a == a), static_cast<int>(left.total() / 2));
  }
  // A band of three held disparities around the winner leaves no runner-up.
  const adcensus::Cost three[16] = {5,     1,     7,     16383, 16383, 16383, 16383, 16383,
                                    16383, 16383, 16383, 16383, 16383, 16383, 16383, 16383};
  EXPECT_EQ(adcensus::RunnerUpCost(three, 3, 16, 1), adcensus::kNoRunnerUp);
  EXPECT_EQ(adcensus::RunnerUpCost(three, 3, 16, 0), 7);
}

// A textured plane with a nearer textured box in front of it, as a station
// sees an object before its backdrop: d = 60 + slant on the plane, 150 on
// the box. The right view is drawn from the left with the nearer surface
// winning; what the left view does not show gets fresh texture.
cv::Mat RenderTwoLayerRight(const cv::Mat& left, const cv::Rect& box, cv::Mat* gt) {
  gt->create(left.size(), CV_32F);
  cv::Mat right = RandomTexture(left.cols, left.rows, 99);
  cv::Mat depth(left.size(), CV_32F, cv::Scalar(-1));
  for (int y = 0; y < left.rows; ++y) {
    for (int x = 0; x < left.cols; ++x) {
      const float d = box.contains({x, y}) ? 150.f : 60.f + 0.02f * x;
      gt->at<float>(y, x) = d;
      const int xr = static_cast<int>(std::lround(x - d));
      if (xr < 0 || xr >= left.cols || depth.at<float>(y, xr) >= d) continue;
      depth.at<float>(y, xr) = d;
      right.at<cv::Vec3b>(y, xr) = left.at<cv::Vec3b>(y, x);
    }
  }
  for (int y = 0; y < left.rows; ++y)
    for (int x = 0; x < left.cols; ++x) gt->at<float>(y, x) = std::round(gt->at<float>(y, x));
  return right;
}

// Region voting as method.md states it, one pixel at a time: each
// iteration, every unreliable pixel with more than tau_s reliable pixels in
// its horizontal-first support region, whose most frequent disparity among
// those it searched holds more than tau_h of them, takes that disparity (the
// lowest on a tie) and becomes reliable; all of an iteration's votes are
// written after it. The matcher's shortcuts (block bounds, running windows,
// the bounds kept between iterations) must give the same disparities.
cv::Mat ReferenceVoting(const cv::Mat& start, const Arms& arms, const adcensus::CostVolume& cost,
                        const RefinementOptions& o) {
  cv::Mat d = start.clone();
  const int range = cost.has_offsets() ? cost.ndisp() : cost.total_ndisp();
  for (int it = 0; it < o.voting_iterations; ++it) {
    cv::Mat next = d.clone();
    bool changed = false;
    for (int y = 0; y < d.rows; ++y)
      for (int x = 0; x < d.cols; ++x) {
        if (IsValidDisparity(d.at<float>(y, x))) continue;
        const std::size_t i = arms.index(y, x);
        const int offset = cost.offset(y, x);
        std::vector<int> histogram(static_cast<std::size_t>(range), 0);
        int reliable = 0;
        for (int v = y - arms.up[i]; v <= y + arms.down[i]; ++v) {
          const std::size_t j = arms.index(v, x);
          for (int u = x - arms.left[j]; u <= x + arms.right[j]; ++u) {
            const float q = d.at<float>(v, u);
            if (!IsValidDisparity(q)) continue;
            ++reliable;
            const int k = static_cast<int>(q) - offset;
            if (k >= 0 && k < range) ++histogram[static_cast<std::size_t>(k)];
          }
        }
        if (reliable <= o.tau_s) continue;
        const auto most = std::max_element(histogram.begin(), histogram.end());
        if (*most <= o.tau_h * reliable) continue;
        next.at<float>(y, x) = static_cast<float>(offset + (most - histogram.begin()));
        changed = true;
      }
    d = next;
    if (!changed) break;
  }
  return d;
}

TEST(Refinement, RegionVotingEqualsTheRuleAppliedPixelByPixel) {
  // Patches of one colour with faint noise: support regions of tens of
  // pixels, enough to vote.
  cv::Mat left, faint(90, 150, CV_8UC3);
  cv::resize(RandomTexture(10, 6, 43), left, cv::Size(150, 90), 0, 0, cv::INTER_NEAREST);
  cv::randu(faint, 0, 4);
  left += faint;
  cv::Mat gt;
  cv::Mat right = RenderRightView(left, 14, 0.05, 0.02, &gt);
  // Unmatched patches for the votes to fill: flat grey and noise.
  cv::rectangle(right, cv::Rect(30, 20, 25, 30), cv::Scalar(128, 128, 128), cv::FILLED);
  cv::Mat noise(40, 30, CV_8UC3);
  cv::randu(noise, 0, 255);
  noise.copyTo(right(cv::Rect(90, 45, 30, 40)));
  ADCensusOptions o;
  const Preprocessed pre = Preprocess(left, o.preprocess);
  RefinementOptions only_voting = o.refinement;
  only_voting.interpolate = only_voting.adjust_discontinuities = only_voting.subpixel = false;
  only_voting.median_size = 0;
  RefinementOptions no_voting = only_voting;
  no_voting.voting_iterations = 0;
  const int lanes = 32, total = 48;
  for (const bool offsets : {false, true}) {
    for (int threads : {1, 2}) {
      const Parallel parallel(threads);
      const auto cl = adcensus::CensusTransform(Grey(left), 9, 7, parallel);
      const auto cr = adcensus::CensusTransform(Grey(right), 9, 7, parallel);
      const Arms arms = adcensus::BuildArms(left, pre.gradient, pre.edges, o, parallel);
      adcensus::CostVolume volume(left.cols, left.rows, offsets ? lanes : total);
      if (offsets) {  // ranges that move along the image
        std::vector<std::int32_t> offset(left.total());
        for (int y = 0; y < left.rows; ++y)
          for (int x = 0; x < left.cols; ++x)
            offset[static_cast<std::size_t>(y) * left.cols + x] =
                (x / 10 + y / 30) % (total - lanes + 1);
        volume.SetOffsets(std::move(offset), total);
      }
      const adcensus::CostComputer costs(left, right, cl, cr, 0, volume.ndisp(), 10, 30, 1.0);
      cv::Mat l, r;
      adcensus::ScanlineOptimize(left, right, 0, o, parallel, nullptr, &costs, &volume, &l, &r,
                                 nullptr);
      const cv::Mat before =
          adcensus::Refine(l, r, volume, 0, left, arms, no_voting, parallel, nullptr, nullptr);
      const cv::Mat voted =
          adcensus::Refine(l, r, volume, 0, left, arms, only_voting, parallel, nullptr, nullptr);
      const cv::Mat expected = ReferenceVoting(before, arms, volume, only_voting);
      const int unreliable = static_cast<int>(before.total()) - cv::countNonZero(before == before);
      const int filled = cv::countNonZero(voted == voted) - cv::countNonZero(before == before);
      EXPECT_GT(unreliable, 1000) << "offsets " << offsets;  // the patches failed to match
      EXPECT_GT(filled, 300) << "offsets " << offsets;       // and voting filled part of them
      EXPECT_TRUE(SameOrBothNaN(voted, expected, 0))
          << "offsets " << offsets << " threads " << threads;
    }
  }
}

// The refinement's last step, where holes stay holes (NaN: the station's
// maps): each valid pixel the median of the valid pixels of its window, the
// (n / 2)-th in order, as sorting each window gives it. Maps wider and
// narrower than a vector, many equal values, a third of them NaN.
TEST(Refinement, MedianOfTheValidPixelsEqualsSortingEachWindow) {
  cv::RNG rng(4711);
  for (const cv::Size size : {cv::Size(7, 5), cv::Size(53, 37), cv::Size(130, 41)}) {
    cv::Mat map(size, CV_32FC1);
    for (int y = 0; y < map.rows; ++y)
      for (int x = 0; x < map.cols; ++x)
        map.at<float>(y, x) = rng.uniform(0.0, 1.0) < 0.35
                                  ? std::numeric_limits<float>::quiet_NaN()
                                  : static_cast<float>(rng.uniform(0, 24)) * 0.5f;
    for (const int window : {3, 5}) {
      const int r = window / 2;
      cv::Mat expected = map.clone();
      for (int y = 0; y < map.rows; ++y)
        for (int x = 0; x < map.cols; ++x) {
          if (!IsValidDisparity(map.at<float>(y, x))) continue;
          std::vector<float> values;
          for (int v = std::max(0, y - r); v <= std::min(map.rows - 1, y + r); ++v)
            for (int u = std::max(0, x - r); u <= std::min(map.cols - 1, x + r); ++u)
              if (IsValidDisparity(map.at<float>(v, u))) values.push_back(map.at<float>(v, u));
          std::sort(values.begin(), values.end());
          expected.at<float>(y, x) = values[values.size() / 2];
        }
      for (const int threads : {1, 2}) {
        cv::Mat filtered = map.clone(), scratch;
        adcensus::MedianFilter(window, Parallel(threads), &filtered, &scratch);
        int differing = 0;
        for (int y = 0; y < map.rows; ++y)
          for (int x = 0; x < map.cols; ++x) {
            const float a = filtered.at<float>(y, x), b = expected.at<float>(y, x);
            differing +=
                IsValidDisparity(a) != IsValidDisparity(b) || (IsValidDisparity(a) && a != b) ? 1
                                                                                              : 0;
          }
        EXPECT_EQ(differing, 0) << size << " window " << window << " threads " << threads;
      }
    }
  }
}

// A surface turned steeply away from the right camera: the right view holds
// it on r = 1 − g of the left's pixels. With exact (rounded) disparities in
// both maps every left pixel is the same surface, yet where g > 2/3 the
// disparity it lands on in the right map can be more than 1 px off its own
// (the right map steps by g / r per pixel). The check passes those where
// the right neighbours differ by 2 or 3 px (1/4 ≤ r ≤ 1/2), and still fails
// a disparity between the two sides of a depth edge.
TEST(Refinement, LeftRightCheckPassesASteepSlantButNotADepthEdge) {
  const int width = 240, height = 6, ndisp = 200;
  cv::Mat image = RandomTexture(width, height, 5);
  ADCensusOptions o;
  const Preprocessed pre = Preprocess(image, o.preprocess);
  const Parallel parallel(1);
  const Arms arms = adcensus::BuildArms(image, pre.gradient, pre.edges, o, parallel);
  adcensus::CostVolume volume(width, height, ndisp);
  RefinementOptions check_only = o.refinement;
  check_only.voting_iterations = 0;
  check_only.interpolate = check_only.adjust_discontinuities = check_only.subpixel = false;
  check_only.median_size = 0;
  const auto nan = std::numeric_limits<float>::quiet_NaN();
  for (const double g : {0.3, 0.6, 0.7, 0.74}) {
    // d(x) = 10 + g·x on the left; the right pixel x_r = x − d(x) sees the
    // same point, so d_R(x_r) = d((x_r + 10) / (1 − g)).
    cv::Mat l(height, width, CV_32F, cv::Scalar(nan)), r(height, width, CV_32F, cv::Scalar(nan));
    int landed = 0, classic_fails = 0;
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        l.at<float>(y, x) = static_cast<float>(std::lround(10 + g * x));
        const double x_left = (x + 10) / (1 - g);
        if (x_left < width) r.at<float>(y, x) = static_cast<float>(std::lround(10 + g * x_left));
      }
    for (int x = 0; x < width; ++x) {
      const float d = l.at<float>(0, x);
      const int xr = x - static_cast<int>(d);
      if (xr < 0 || !IsValidDisparity(r.at<float>(0, xr))) continue;
      ++landed;
      classic_fails += std::abs(r.at<float>(0, xr) - d) > 1;
    }
    const cv::Mat out =
        adcensus::Refine(l, r, volume, 0, image, arms, check_only, parallel, nullptr, nullptr);
    EXPECT_EQ(cv::countNonZero(out == out), landed * height) << "g " << g;
    if (g > 0.65) {  // where the old rule alone lost pixels
      EXPECT_GT(classic_fails, landed / 10) << "g " << g;
    }
  }
  // A depth edge in the right view (d 10, then 30): a left disparity of 20
  // landing on it is between the two sides but consistent with neither.
  cv::Mat l(height, width, CV_32F, cv::Scalar(20)), r(height, width, CV_32F);
  r.colRange(0, 100).setTo(10);
  r.colRange(100, width).setTo(30);
  l.at<float>(0, 140) = 30;  // lands on the near side (x_r 110): consistent
  l.at<float>(0, 160) = 32;  // 2 px off a flat stretch (x_r 128): no slope excuses it
  const cv::Mat out =
      adcensus::Refine(l, r, volume, 0, image, arms, check_only, parallel, nullptr, nullptr);
  for (int x : {119, 120, 121}) EXPECT_NE(out.at<float>(0, x), out.at<float>(0, x)) << x;
  EXPECT_EQ(out.at<float>(0, 140), 30.f);
  EXPECT_NE(out.at<float>(0, 160), out.at<float>(0, 160));
}

TEST(Matcher, CoarseToFineMatchesAsWellAsTheWholeBand) {
  const cv::Mat left = RandomTexture(640, 200, 34);
  const cv::Rect box(300, 50, 160, 100);
  cv::Mat gt;
  const cv::Mat right = RenderTwoLayerRight(left, box, &gt);
  ADCensusOptions o;  // the station's matcher: no aggregation, no interpolation
  o.aggregation_iterations = 0;
  o.refinement.interpolate = false;
  o.min_disparity = -40;
  o.num_disparities = 320;
  o.num_threads = 2;
  const DisparityResult whole = ComputeDisparity(left, right, o);
  o.coarse_to_fine.enabled = true;
  const DisparityResult ranged = ComputeDisparity(left, right, o);
  ASSERT_TRUE(whole.IsUsable() && ranged.IsUsable()) << whole.message << ranged.message;
  EXPECT_EQ(whole.searched_disparities, 320);
  EXPECT_EQ(ranged.searched_disparities, o.coarse_to_fine.lanes);
  EXPECT_GT(ranged.time_ms.coarse, 0);
  // Scored where the right view shows the pixel's own surface.
  int n = 0, whole_good = 0, ranged_good = 0, ranged_valid = 0, ranged_bad = 0;
  for (int y = 10; y < left.rows - 10; ++y) {
    for (int x = 10; x < left.cols - 10; ++x) {
      const float g = gt.at<float>(y, x);
      const bool in_box = box.contains({x, y});
      if (x - g < 10 || (!in_box && x - g >= box.x - 150 && x - g < box.br().x - 150)) continue;
      ++n;
      const float a = whole.disparity.at<float>(y, x), b = ranged.disparity.at<float>(y, x);
      whole_good += IsValidDisparity(a) && std::abs(a - g) <= 1 ? 1 : 0;
      ranged_good += IsValidDisparity(b) && std::abs(b - g) <= 1 ? 1 : 0;
      ranged_valid += IsValidDisparity(b) ? 1 : 0;
      ranged_bad += IsValidDisparity(b) && std::abs(b - g) > 2 ? 1 : 0;
    }
  }
  ASSERT_GT(n, 50000);
  EXPECT_GT(whole_good, n * 9 / 10);
  EXPECT_GE(ranged_good, whole_good - n / 100)
      << "ranged " << ranged_good << " whole " << whole_good;
  EXPECT_LT(ranged_bad, ranged_valid / 100) << ranged_bad << " of " << ranged_valid;

  // Still the same for any number of threads.
  o.num_threads = 1;
  const DisparityResult one = ComputeDisparity(left, right, o);
  o.num_threads = 3;
  const DisparityResult three = ComputeDisparity(left, right, o);
  const std::size_t bytes = left.total() * sizeof(float);
  EXPECT_EQ(0, std::memcmp(one.disparity.data, ranged.disparity.data, bytes));
  EXPECT_EQ(0, std::memcmp(three.disparity.data, ranged.disparity.data, bytes));
  EXPECT_EQ(0, std::memcmp(three.disparity_right.data, ranged.disparity_right.data, bytes));
}

TEST(Matcher, CoarseToFineOptionsAreChecked) {
  ADCensusOptions o;
  std::string why;
  o.coarse_to_fine.lanes = 40;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("lanes"), std::string::npos) << why;
  o = {};
  o.coarse_to_fine.coarse_width_px = 10;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("coarse_width_px"), std::string::npos) << why;
  o = {};
  o.coarse_to_fine.min_num_disparities = 32;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("min_num_disparities"), std::string::npos) << why;
}

TEST(ArmRule, StringRoundTrip) {
  for (ArmRule rule : {ArmRule::kClassic, ArmRule::kImproved}) {
    ArmRule parsed;
    ASSERT_TRUE(ArmRuleFromString(ToString(rule), &parsed));
    EXPECT_EQ(parsed, rule);
  }
  ArmRule parsed;
  EXPECT_FALSE(ArmRuleFromString("fancy", &parsed));
}

}  // namespace
}  // namespace craftscan
