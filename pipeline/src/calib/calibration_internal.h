// Helpers shared by the calibration*.cc files. Not part of the public API.
#pragma once

#include <cmath>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/status.h"

namespace craftscan::calib_internal {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Fail(why, reason): common/status.h.
using craftscan::Fail;

template <int M, int N>
bool AllFinite(const cv::Matx<double, M, N>& m) {
  for (int i = 0; i < M * N; ++i) {
    if (!std::isfinite(m.val[i])) return false;
  }
  return true;
}

// A proper rotation within `tolerance` (orthonormal, det +1).
bool IsRotation(const cv::Matx33d& r, double tolerance = 1e-6);

// "%.*f" without iostreams.
std::string Fixed(double value, int precision);

// Fraction of the cells of a grid × grid partition of `image_size` holding
// at least one of the points.
double Coverage(const std::vector<std::vector<cv::Point2f>>& points, cv::Size image_size, int grid);

// OpenCV calibration flags for a lens model (without USE_INTRINSIC_GUESS /
// FIX_INTRINSIC / SAME_FOCAL_LENGTH).
int LensFlags(const LensModelOptions& lens);

// Camera matrix to start cv::calibrateCamera from (identity: only the
// aspect ratio 1 matters when FIX_ASPECT_RATIO is set without a guess).
cv::Mat InitialCameraMatrix();

// cv::Exception::what() without OpenCV's version/source-file prefix and the
// trailing newline, e.g. "(-212:Parsing error) ... Missing ':'".
std::string CvErrorText(const cv::Exception& e);

// RMS of the distances between two equally long point lists.
double RmsDistance(const std::vector<cv::Point2f>& a, const std::vector<cv::Point2f>& b);

}  // namespace craftscan::calib_internal
