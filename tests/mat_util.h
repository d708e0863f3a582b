// Images in tests: bit-exact comparison of cv::Mat.
#pragma once

#include <cstring>

#include <opencv2/core/mat.hpp>

namespace craftscan::testing {

// Same size, type and bytes, row by row (so NaN payloads, ±0 and ±inf are
// compared exactly, and a Mat that is a view into a larger one works too).
inline bool BitExact(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
  }
  return true;
}

}  // namespace craftscan::testing
