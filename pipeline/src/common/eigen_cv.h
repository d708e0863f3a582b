// Conversions between OpenCV's fixed-size matrices (public API) and Eigen
// (the implementation's linear algebra). Internal to the pipeline.
#pragma once

#include <Eigen/Core>
#include <opencv2/core/matx.hpp>

namespace craftscan {

inline Eigen::Matrix4d ToEigen(const cv::Matx44d& m) {
  Eigen::Matrix4d e;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) e(r, c) = m(r, c);
  return e;
}

inline cv::Matx44d ToCv(const Eigen::Matrix4d& e) {
  cv::Matx44d m;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m(r, c) = e(r, c);
  return m;
}

}  // namespace craftscan
