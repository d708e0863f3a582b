// Rectification of raw stereo pairs with cached maps (method.md §4).
#pragma once

#include <opencv2/core/mat.hpp>
#include <string>
#include <vector>

#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan {

// Holds the undistort+rectify maps (cv::initUndistortRectifyMap, fixed-point
// CV_16SC2 + CV_16UC1 for a fast remap) of one calibration. Build it once per
// calibration and rectify every pair with it.
//
// Thread-safety: Init() must not run concurrently with anything else;
// Rectify() and the accessors are const and may run concurrently.
class Rectifier {
 public:
  Rectifier() = default;

  // Builds the maps for `calibration` (must pass StereoCalibration::IsValid).
  // A second call with a calibration of equal geometry (intrinsics,
  // distortion, image size, R1, R2, P1, P2) keeps the cached maps.
  // Returns false with *error (may be null) and leaves the rectifier empty
  // on invalid input.
  bool Init(const StereoCalibration& calibration, std::string* error);

  bool IsReady() const { return !left_map1_.empty(); }
  const StereoCalibration& calibration() const { return calibration_; }
  // Size of the rectified images (= the calibration's image size).
  cv::Size rectified_size() const { return calibration_.image_size; }
  // How many times Init() actually built maps (for tests of the cache).
  int maps_built() const { return maps_built_; }

  // Rectifies a raw pair (any type cv::remap takes; both of the
  // calibration's image size) with bilinear interpolation; pixels from
  // outside the raw image are 0. Returns false with *error (may be null) if
  // not ready or the images do not match. Outputs may not alias the inputs.
  bool Rectify(const cv::Mat& left, const cv::Mat& right, cv::Mat* left_rectified,
               cv::Mat* right_rectified, std::string* error) const;

  // The left image alone (a texture frame), as Rectify does it.
  bool RectifyLeft(const cv::Mat& left, cv::Mat* left_rectified, std::string* error) const;

  // Raw left/right pixel → rectified pixel (undistorted, rotated, projected
  // with P1/P2). Empty output when not ready.
  std::vector<cv::Point2f> RectifyLeftPoints(const std::vector<cv::Point2f>& raw) const;
  std::vector<cv::Point2f> RectifyRightPoints(const std::vector<cv::Point2f>& raw) const;

 private:
  StereoCalibration calibration_;
  cv::Mat left_map1_, left_map2_, right_map1_, right_map2_;
  int maps_built_ = 0;
};

}  // namespace craftscan
