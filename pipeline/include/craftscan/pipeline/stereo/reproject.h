// Disparity → coloured 3D points through OpenCV's Q matrix (method.md §6).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core/mat.hpp>

namespace craftscan {

struct ColoredPoint {
  float x, y, z;  // mm, in the rig frame (rectified left camera)
  std::uint8_t r, g, b;
};

struct ReprojectOptions {
  double min_depth_mm = 0;  // points with z outside [min, max] are dropped
  double max_depth_mm = 1e9;
  // Texture filter (OpenCV StereoBM's textureThreshold): a pixel is dropped
  // when the grey-level standard deviation of `color` over the
  // texture_window × texture_window pixels around it is below
  // min_texture_std (grey levels, 0 = off; needs `color`). Matchers guess on
  // textureless surfaces such as a dark backdrop, and when the surface's true
  // disparity lies outside the search band the guesses are consistent in both
  // views and survive the left-right check. On the simulated station the
  // dark cloth measures 0.6–1.1 (sensor noise), the objects ≥ 5 at 5 %
  // (window 7): 2.5 removes the cloth, and with it dark paint the matcher
  // got right (the station no longer uses it by default: ViewProcessorOptions).
  double min_texture_std = 0;
  int texture_window = 7;  // odd, ≥ 3
  // Pixels where this is non-zero (CV_8UC1, the disparity's size; empty =
  // none) are kept whatever their texture: the station exempts what it sees
  // over the platter, which is the platter or the object, never the
  // backdrop (ViewProcessor).
  cv::Mat texture_exempt;
  bool IsValid(std::string* why) const;
};

// Reprojects every valid disparity (see IsValidDisparity) of `disparity`
// (CV_32FC1) with `Q` (4×4, CV_64F or CV_32F, from cv::stereoRectify) into
// points in the units of Q (mm for craftscan calibrations):
// [X Y Z W]ᵀ = Q·[x y d 1]ᵀ, point = (X/W, Y/W, Z/W), as cv::reprojectImageTo3D.
// Skipped: invalid or infinite disparities, W ≈ 0 (points at infinity) and
// z outside [min_depth_mm, max_depth_mm]. Points come in row-major pixel order.
// `color` is the rectified left image (CV_8UC1 grey or CV_8UC3 BGR, same size)
// or empty (grey 255).
// Fails (kInvalidInput, the message says why) on mismatched inputs, a Q that
// is not finite, or invalid options; kFailed if OpenCV reports an error.
// Never throws. Thread-safe.
struct ReprojectResult {
  enum class Status { kOk, kInvalidInput, kFailed };
  Status status = Status::kFailed;
  std::string message;               // why not kOk
  std::vector<ColoredPoint> points;  // row-major pixel order

  bool IsUsable() const { return status == Status::kOk; }
};
ReprojectResult ReprojectToPoints(const cv::Mat& disparity, const cv::Mat& Q, const cv::Mat& color,
                                  const ReprojectOptions& options = {});

// The texture mask of ReprojectOptions::min_texture_std: CV_8UC1, 255 where
// the grey-level standard deviation of `color` (CV_8UC1 or CV_8UC3 BGR) over
// the window × window neighbourhood is at least min_std. Throws
// std::invalid_argument on an empty or unsupported image or an even or
// too small window.
cv::Mat TextureMask(const cv::Mat& color, int window, double min_std);

}  // namespace craftscan
