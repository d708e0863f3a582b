// MergeExposures: a bracketed view merged into one 8-bit image.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/pipeline/stereo/exposure_merge.h"

namespace craftscan {
namespace {

// An 8-bit exposure of `radiance` (grey levels at exposure 1) at `t` times
// the exposure: noise of 1 grey level, rounded and clipped as a sensor does.
cv::Mat Expose(const cv::Mat& radiance, double t, int seed) {
  cv::Mat noise(radiance.size(), CV_32F);
  cv::RNG rng(static_cast<std::uint64_t>(seed));
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
  cv::Mat out;
  cv::Mat(radiance * t + noise).convertTo(out, CV_8U);  // rounds and saturates
  return out;
}

// The merged image decoded back to radiance (grey levels at exposure 1).
cv::Mat Decode(const cv::Mat& merged, double gamma) {
  cv::Mat f;
  merged.convertTo(f, CV_32F, 1.0 / 255);
  cv::pow(f, gamma, f);
  return f * 255;
}

double Rms(const cv::Mat& a, const cv::Mat& b) {
  const cv::Mat d = a - b;
  return std::sqrt(cv::mean(d.mul(d))[0]);
}

TEST(ExposureMerge, DarkSurfacesGainTheLongExposuresPrecisionAndBrightOnesStayUnclipped) {
  // Left half: dark paint (radiance 8–14 levels, a faint texture); right half:
  // white paint (200 levels), which the ×4 exposure clips.
  cv::Mat radiance(64, 128, CV_32F);
  for (int y = 0; y < radiance.rows; ++y)
    for (int x = 0; x < radiance.cols; ++x)
      radiance.at<float>(y, x) =
          x < 64 ? static_cast<float>(11 + 3 * std::sin(0.7 * x + 0.3 * y)) : 200.f;
  const std::vector<double> t{1, 4};
  const std::vector<cv::Mat> shots{Expose(radiance, 1, 1), Expose(radiance, 4, 2)};
  ASSERT_EQ(cv::countNonZero(shots[1].colRange(64, 128) == 255), 64 * 64);  // clipped
  const ExposureMergeOptions options;
  cv::Mat merged;
  std::string error;
  ASSERT_TRUE(MergeExposures(shots, t, options, &merged, &error)) << error;
  ASSERT_EQ(merged.type(), CV_8UC1);
  ASSERT_EQ(merged.size(), radiance.size());
  const cv::Mat decoded = Decode(merged, options.gamma);

  // Dark half: the reference exposure alone is off by its noise (~1 level);
  // the merge by about a quarter of it plus the output's quantisation.
  cv::Mat single;
  shots[0].convertTo(single, CV_32F);
  const cv::Range dark(0, 64), bright(64, 128);
  const double single_rms = Rms(single.colRange(dark), radiance.colRange(dark));
  const double merged_rms = Rms(decoded.colRange(dark), radiance.colRange(dark));
  EXPECT_GT(single_rms, 0.85);
  EXPECT_LT(merged_rms, 0.45);
  // The texture (6 levels of radiance) spans more output levels than that:
  // gamma spreads the dark (255·(r/255)^(1/2.2): 54 … 69 for r = 8 … 14).
  double lo = 0, hi = 0;
  cv::minMaxLoc(merged.colRange(dark), &lo, &hi);
  EXPECT_GT(hi - lo, 12);
  // Bright half: from the reference exposure, within its noise and the
  // encoding's step there (~1.3 levels of radiance per output level).
  EXPECT_LT(Rms(decoded.colRange(bright), radiance.colRange(bright)), 1.6);

  // One image: its gamma encoding.
  cv::Mat one;
  ASSERT_TRUE(MergeExposures({shots[0]}, {1.0}, options, &one, &error)) << error;
  EXPECT_LT(Rms(Decode(one, options.gamma), single), 0.6);
}

TEST(ExposureMerge, NoSeamWhereTheLongExposureClips) {
  // A ramp of radiance through the ×4 exposure's clip level (62.5 levels):
  // the merge must follow it without a step where the weights switch (using
  // the clipped long exposure would be off by up to 16 levels). The column
  // means keep the output's quantisation (≤ 0.7 levels of radiance here).
  cv::Mat radiance(64, 256, CV_32F);
  for (int x = 0; x < radiance.cols; ++x) radiance.col(x).setTo(30.0 + 60.0 * x / 255.0);
  const std::vector<cv::Mat> shots{Expose(radiance, 1, 3), Expose(radiance, 4, 4)};
  cv::Mat merged;
  std::string error;
  ASSERT_TRUE(MergeExposures(shots, {1, 4}, ExposureMergeOptions{}, &merged, &error)) << error;
  cv::Mat row_mean;
  cv::reduce(Decode(merged, 2.2), row_mean, 0, cv::REDUCE_AVG);
  cv::Mat truth = radiance.row(0);
  double worst = 0;
  for (int x = 0; x < radiance.cols; ++x)
    worst =
        std::max(worst, static_cast<double>(std::abs(row_mean.at<float>(x) - truth.at<float>(x))));
  EXPECT_LT(worst, 1.2);
}

TEST(ExposureMerge, RefusesWhatItCannotMergeAndSaysWhy) {
  const cv::Mat a(8, 8, CV_8UC3, cv::Scalar::all(10)), b(8, 8, CV_8UC3, cv::Scalar::all(40));
  const ExposureMergeOptions options;
  cv::Mat merged;
  std::string error;
  EXPECT_FALSE(MergeExposures({}, {}, options, &merged, &error));
  EXPECT_NE(error.find("no images"), std::string::npos) << error;
  EXPECT_FALSE(MergeExposures({a, b}, {1}, options, &merged, &error));
  EXPECT_NE(error.find("2 images but 1 exposures"), std::string::npos) << error;
  EXPECT_FALSE(MergeExposures({a, b}, {1, 0.5}, options, &merged, &error));
  EXPECT_NE(error.find("ascend"), std::string::npos) << error;
  EXPECT_FALSE(MergeExposures({a, b}, {2, 4}, options, &merged, &error));
  EXPECT_NE(error.find("ascend"), std::string::npos) << error;
  EXPECT_FALSE(MergeExposures({a, cv::Mat(8, 9, CV_8UC3)}, {1, 4}, options, &merged, &error));
  EXPECT_NE(error.find("image 1 differs"), std::string::npos) << error;
  EXPECT_FALSE(MergeExposures({cv::Mat(8, 8, CV_16UC1)}, {1}, options, &merged, &error));
  EXPECT_NE(error.find("not 8-bit"), std::string::npos) << error;
  ExposureMergeOptions bad;
  bad.gamma = 0.5;
  EXPECT_FALSE(MergeExposures({a}, {1}, bad, &merged, &error));
  EXPECT_NE(error.find("gamma"), std::string::npos) << error;
  // A colour pair merges per channel.
  ASSERT_TRUE(MergeExposures({a, b}, {1, 4}, options, &merged, &error)) << error;
  EXPECT_EQ(merged.type(), CV_8UC3);
  // Radiance 10 from both: 255·(10/255)^(1/2.2) = 59.
  EXPECT_NEAR(merged.at<cv::Vec3b>(3, 3)[1], 59, 1);
}

// Automatic bracketing's measure: dark windows without texture, counted in
// the region only.
TEST(AutoBracket, CountsDarkUntexturedWindowsInTheRegion) {
  const AutoBracketOptions options;
  std::string why;
  ASSERT_TRUE(options.IsValid(&why)) << why;
  cv::Mat image(100, 200, CV_8UC1, cv::Scalar(200));      // bright, flat
  image(cv::Rect(0, 0, 100, 100)).setTo(cv::Scalar(12));  // dark, flat: the left half
  EXPECT_NEAR(DarkUntexturedSharePct(image, cv::Mat(), options), 50.0, 3.0);
  // Texture (a random pattern, std ~20 levels) in the dark half: not counted.
  cv::Mat textured = image.clone();
  cv::Mat noise(100, 100, CV_8UC1);
  cv::RNG(7).fill(noise, cv::RNG::UNIFORM, 0, 40);
  noise.copyTo(textured(cv::Rect(0, 0, 100, 100)));
  EXPECT_LT(DarkUntexturedSharePct(textured, cv::Mat(), options), 3.0);
  // The region: its right half only is bright, so none; its left half all.
  cv::Mat region(image.size(), CV_8UC1, cv::Scalar(0));
  region(cv::Rect(120, 0, 80, 100)).setTo(255);
  EXPECT_EQ(DarkUntexturedSharePct(image, region, options), 0.0);
  region.setTo(0);
  region(cv::Rect(10, 10, 50, 50)).setTo(255);
  EXPECT_EQ(DarkUntexturedSharePct(image, region, options), 100.0);
  // Colour images are judged by their grey.
  cv::Mat colour;
  cv::cvtColor(image, colour, cv::COLOR_GRAY2BGR);
  EXPECT_EQ(DarkUntexturedSharePct(colour, region, options), 100.0);
  // What it cannot judge: NaN.
  EXPECT_TRUE(std::isnan(DarkUntexturedSharePct(image, cv::Mat(10, 10, CV_8UC1), options)));
  EXPECT_TRUE(std::isnan(DarkUntexturedSharePct(cv::Mat(), cv::Mat(), options)));
  EXPECT_TRUE(std::isnan(
      DarkUntexturedSharePct(image, cv::Mat(image.size(), CV_8UC1, cv::Scalar(0)), options)));
  AutoBracketOptions bad = options;
  bad.window = 4;
  EXPECT_FALSE(bad.IsValid(&why));
  EXPECT_NE(why.find("window"), std::string::npos) << why;
  bad = options;
  bad.multiple = 1;
  EXPECT_FALSE(bad.IsValid(&why));
}

}  // namespace
}  // namespace craftscan
