// Rigid transforms in tests: 4x4 homogeneous matrices from a rotation and a
// translation.
#pragma once

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

namespace craftscan::testing {

// [r | t; 0 0 0 1]: p' = r·p + t.
inline cv::Matx44d PoseFromRotation(const cv::Matx33d& r, const cv::Vec3d& t) {
  cv::Matx44d m = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m(i, j) = r(i, j);
    m(i, 3) = t[i];
  }
  return m;
}

// The same with the rotation as a Rodrigues vector (axis · angle in radians).
inline cv::Matx44d Pose(const cv::Vec3d& rodrigues, const cv::Vec3d& t) {
  cv::Matx33d r;
  cv::Rodrigues(rodrigues, r);
  return PoseFromRotation(r, t);
}

}  // namespace craftscan::testing
