// The live preview's frame (live_preview.h): the JPEG decodes to the asked
// width, the histogram counts every pixel, clipped and black shares are the
// image's, the focus measure is higher where the picture is sharp.
#include <gtest/gtest.h>

#include <numeric>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/daemon/live_preview.h"

namespace craftscan::daemon {
namespace {

TEST(LivePreview, JpegHistogramClippingAndFocus) {
  // A 640×480 grey image: left half random texture (sharp), right half the
  // same texture blurred; a 64×48 block clipped white, one black.
  cv::Mat image(480, 640, CV_8UC3);
  cv::RNG rng(7);
  rng.fill(image, cv::RNG::UNIFORM, 30, 220);
  cv::Mat right = image(cv::Rect(320, 0, 320, 480));
  cv::GaussianBlur(right, right, cv::Size(0, 0), 4);
  image(cv::Rect(0, 0, 64, 48)).setTo(cv::Scalar(255, 255, 255));
  image(cv::Rect(600, 440, 40, 40)).setTo(cv::Scalar(0, 0, 0));

  const LivePreviewImage p = MakeLivePreviewImage(image, 320);
  const cv::Mat decoded = cv::imdecode(p.jpeg, cv::IMREAD_UNCHANGED);
  ASSERT_FALSE(decoded.empty());
  EXPECT_EQ(decoded.cols, 320);
  EXPECT_EQ(decoded.rows, 240);
  ASSERT_EQ(p.histogram.size(), static_cast<std::size_t>(kPreviewHistogramBins));
  EXPECT_EQ(std::accumulate(p.histogram.begin(), p.histogram.end(), 0.0), 640.0 * 480);
  EXPECT_NEAR(p.clipped_pct, 100.0 * 64 * 48 / (640 * 480), 0.05);
  EXPECT_NEAR(p.black_pct, 100.0 * 40 * 40 / (640 * 480), 0.05);
  ASSERT_EQ(p.focus.size(), static_cast<std::size_t>(kPreviewGridCols * kPreviewGridRows));
  // Row 1 (no patches): the sharp left cells measure far more than the blurred right ones.
  for (int c = 0; c < kPreviewGridCols / 2; ++c) {
    EXPECT_GT(p.focus[kPreviewGridCols + c],
              20 * p.focus[kPreviewGridCols + kPreviewGridCols - 1 - c])
        << "column " << c;
  }

  // Never enlarged; grey images work too.
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  const PreviewFrame f = MakePreviewFrame(grey, grey, 4096);
  EXPECT_EQ(f.size, cv::Size(640, 480));
  EXPECT_EQ(f.full_size, cv::Size(640, 480));
  EXPECT_EQ(cv::imdecode(f.left.jpeg, cv::IMREAD_UNCHANGED).cols, 640);
}

}  // namespace
}  // namespace craftscan::daemon
