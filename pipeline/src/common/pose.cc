#include "craftscan/pipeline/common/pose.h"

#include <cmath>

namespace craftscan {

cv::Matx33d RotationFromQuaternion(double w, double x, double y, double z) {
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  if (!(n > 0.0)) return cv::Matx33d::eye();
  w /= n;
  x /= n;
  y /= n;
  z /= n;
  return cv::Matx33d(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y));
}

double RotationErrorDeg(const cv::Matx44d& a, const cv::Matx44d& b) {
  const cv::Matx33d ra = a.get_minor<3, 3>(0, 0);
  const cv::Matx33d rb = b.get_minor<3, 3>(0, 0);
  const cv::Matx33d d = ra.t() * rb;
  // atan2 of sin and cos stays accurate near 0 and 180 degrees, unlike acos.
  const double s = 0.5 * std::sqrt((d(2, 1) - d(1, 2)) * (d(2, 1) - d(1, 2)) +
                                   (d(0, 2) - d(2, 0)) * (d(0, 2) - d(2, 0)) +
                                   (d(1, 0) - d(0, 1)) * (d(1, 0) - d(0, 1)));
  const double c = 0.5 * (cv::trace(d) - 1.0);
  return std::atan2(s, c) * 180.0 / M_PI;
}

double TranslationErrorMm(const cv::Matx44d& a, const cv::Matx44d& b) {
  const double dx = a(0, 3) - b(0, 3), dy = a(1, 3) - b(1, 3), dz = a(2, 3) - b(2, 3);
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

cv::Matx44d InvertRigid(const cv::Matx44d& a_from_b) {
  const cv::Matx33d r = a_from_b.get_minor<3, 3>(0, 0);
  const cv::Vec3d t(a_from_b(0, 3), a_from_b(1, 3), a_from_b(2, 3));
  const cv::Matx33d rt = r.t();
  const cv::Vec3d ti = -(rt * t);
  cv::Matx44d b_from_a = cv::Matx44d::eye();
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) b_from_a(i, j) = rt(i, j);
    b_from_a(i, 3) = ti[i];
  }
  return b_from_a;
}

cv::Matx44d RelativePose(const cv::Matx44d& world_from_target,
                         const cv::Matx44d& world_from_source) {
  return InvertRigid(world_from_target) * world_from_source;
}

PointCloud TransformCloud(const cv::Matx44d& to_from_cloud, const PointCloud& cloud) {
  PointCloud out = cloud;
  const cv::Matx33d r = to_from_cloud.get_minor<3, 3>(0, 0);
  const cv::Vec3d t(to_from_cloud(0, 3), to_from_cloud(1, 3), to_from_cloud(2, 3));
  for (cv::Vec3f& p : out.points_mm) p = cv::Vec3f(r * cv::Vec3d(p) + t);
  for (cv::Vec3f& n : out.normals) n = cv::Vec3f(r * cv::Vec3d(n));
  return out;
}

}  // namespace craftscan
