// The live preview (verb `preview`, and the guided calibration job): a
// stereo frame made small enough to stream a few times a second, with what
// a person needs to frame, focus and expose the cameras: each image as a
// JPEG scaled to a given width, a focus measure per image region (variance
// of the Laplacian of the grey image: a sharper picture has more high
// frequencies, so a higher value; OpenCV's usual focus measure) and a
// 64-bin grey-level histogram with the clipped (255) and black (0) shares.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace craftscan::daemon {

struct LivePreviewImage {
  std::vector<std::uint8_t> jpeg;
  std::vector<float> focus;              // grid_rows × grid_cols, row-major
  std::vector<std::uint32_t> histogram;  // 64 bins of 4 grey levels
  float clipped_pct = 0;                 // pixels with a channel at 255, % of the image
  float black_pct = 0;                   // pixels with every channel at 0, %
};

struct PreviewFrame {
  std::string job_id;
  std::uint32_t sequence = 0;
  std::int64_t stamp_ns = 0;  // capture (wall clock)
  std::int64_t ready_ns = 0;  // the frame in the daemon's hands (wall clock)
  double exposure_us = 0, gain_db = 0;
  cv::Size full_size;  // the cameras' images
  cv::Size size;       // the JPEGs'
  int grid_cols = 0, grid_rows = 0;
  LivePreviewImage left, right;
  std::string overlay;  // JSON from the job, or ""
};

inline constexpr int kPreviewGridCols = 4;
inline constexpr int kPreviewGridRows = 4;
inline constexpr int kPreviewHistogramBins = 64;

// One image's preview: `image` CV_8UC1 or CV_8UC3, non-empty; scaled to
// `width` px wide (never enlarged), JPEG quality 80.
LivePreviewImage MakeLivePreviewImage(const cv::Mat& image, int width);

// The wall-clock time of a frame stamped on the steady clock (the drivers'
// HostServices::now_ns) within the last 10 s; now for any other stamp (the
// simulated technician's clock). Preview stamps are wall clock, so a
// console can tell its latency.
std::int64_t WallStamp(std::int64_t steady_ns);
// The wall clock now, ns since the epoch.
std::int64_t WallNow();

// Both images (the same size); the job fills in job_id, sequence, stamp,
// exposure, gain and overlay.
PreviewFrame MakePreviewFrame(const cv::Mat& left, const cv::Mat& right, int width);

}  // namespace craftscan::daemon
