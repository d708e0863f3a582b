// The station's transform tree (StationFrames) → tf2_msgs TFMessage.
#include <cmath>
#include <string>
#include <vector>

#include "convert_internal.h"
#include "craftscan/dds/convert.h"
#include "craftscan/pipeline/common/pose.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan::dds {
namespace {

constexpr double kMetresPerMm = 1e-3;
constexpr double kRigidTolerance = 1e-6;

cv::Matx44d FromRotationTranslation(const cv::Matx33d& rotation, const cv::Vec3d& translation) {
  cv::Matx44d m = cv::Matx44d::eye();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m(r, c) = rotation(r, c);
    m(r, 3) = translation[r];
  }
  return m;
}

bool IsRigid(const cv::Matx44d& m) {
  for (double v : m.val) {
    if (!std::isfinite(v)) return false;
  }
  const cv::Matx33d r = m.get_minor<3, 3>(0, 0);
  const cv::Matx33d should_be_eye = r.t() * r;
  return cv::norm(should_be_eye - cv::Matx33d::eye(), cv::NORM_INF) < kRigidTolerance &&
         std::abs(cv::determinant(r) - 1) < kRigidTolerance && m(3, 0) == 0 && m(3, 1) == 0 &&
         m(3, 2) == 0 && m(3, 3) == 1;
}

}  // namespace

StationFrames FramesOf(std::string_view station) {
  const std::string s(station);
  StationFrames f;
  f.base = s + "_base_link";
  f.rig = s + "_rig_optical_frame";
  f.left = s + "_left_camera_optical_frame";
  f.right = s + "_right_camera_optical_frame";
  f.turntable_base = s + "_turntable_base";
  f.turntable = s + "_turntable";
  return f;
}

bool StaticStationTransforms(const StereoCalibration& calibration, const StationFrames& frames,
                             std::vector<FrameTransform>* transforms, std::string* error) {
  std::string why;
  if (!calibration.IsValid(&why)) return internal::Fail(error, "calibration: " + why);
  // REP 103: an optical frame (z forward, x right, y down) seen from a body
  // frame (x forward, y left, z up).
  const cv::Matx33d base_from_optical(0, 0, 1,   //
                                      -1, 0, 0,  //
                                      0, -1, 0);
  // P2 = K' [I | t']: p_in_rectified_right = p_in_rig + t', so the right
  // camera's centre is at −t' in the rig frame.
  const cv::Vec3d t_right(calibration.P2(0, 3) / calibration.P2(0, 0),
                          calibration.P2(1, 3) / calibration.P2(1, 1), calibration.P2(2, 3));
  transforms->clear();
  transforms->push_back({frames.base, frames.rig, FromRotationTranslation(base_from_optical, {})});
  transforms->push_back({frames.rig, frames.left, FromRotationTranslation(calibration.R1, {})});
  transforms->push_back(
      {frames.rig, frames.right, FromRotationTranslation(calibration.R2, -t_right)});
  transforms->push_back({frames.rig, frames.turntable_base,
                         calibration.turntable.valid
                             ? InvertRigid(TurntableFromRig(calibration.turntable))
                             : cv::Matx44d::eye()});
  return true;
}

FrameTransform TurntableTransform(const StationFrames& frames, double angle_rad) {
  const double c = std::cos(angle_rad), s = std::sin(angle_rad);
  const cv::Matx33d rotation(c, -s, 0,  //
                             s, c, 0,   //
                             0, 0, 1);
  return {frames.turntable_base, frames.turntable, FromRotationTranslation(rotation, {})};
}

cv::Vec4d QuaternionFromRotation(const cv::Matx33d& m) {
  // Shepperd's method: divide by the largest of the four candidates.
  const double trace = m(0, 0) + m(1, 1) + m(2, 2);
  cv::Vec4d q;  // x, y, z, w
  if (trace > 0) {
    const double s = 2 * std::sqrt(1 + trace);
    q = {(m(2, 1) - m(1, 2)) / s, (m(0, 2) - m(2, 0)) / s, (m(1, 0) - m(0, 1)) / s, s / 4};
  } else if (m(0, 0) > m(1, 1) && m(0, 0) > m(2, 2)) {
    const double s = 2 * std::sqrt(1 + m(0, 0) - m(1, 1) - m(2, 2));
    q = {s / 4, (m(0, 1) + m(1, 0)) / s, (m(0, 2) + m(2, 0)) / s, (m(2, 1) - m(1, 2)) / s};
  } else if (m(1, 1) > m(2, 2)) {
    const double s = 2 * std::sqrt(1 + m(1, 1) - m(0, 0) - m(2, 2));
    q = {(m(0, 1) + m(1, 0)) / s, s / 4, (m(1, 2) + m(2, 1)) / s, (m(0, 2) - m(2, 0)) / s};
  } else {
    const double s = 2 * std::sqrt(1 + m(2, 2) - m(0, 0) - m(1, 1));
    q = {(m(0, 2) + m(2, 0)) / s, (m(1, 2) + m(2, 1)) / s, s / 4, (m(1, 0) - m(0, 1)) / s};
  }
  q /= cv::norm(q);
  return q[3] < 0 ? -q : q;
}

bool MakeTfMessage(const std::vector<FrameTransform>& transforms, int64_t stamp_ns,
                   Outgoing<ros::TFMessage>* out, std::string* error) {
  *out = Outgoing<ros::TFMessage>();
  std::vector<ros::TransformStamped> list;
  for (const FrameTransform& t : transforms) {
    if (!IsRigid(t.parent_from_child)) {
      return internal::Fail(error, "transform " + t.parent + " → " + t.child + " is not rigid");
    }
    if (t.parent.empty() || t.child.empty() || t.parent == t.child) {
      return internal::Fail(error, "transform '" + t.parent + "' → '" + t.child +
                                       "': frames must be named and distinct");
    }
    ros::TransformStamped s{};
    s.header.stamp = RosTimeFromNs(stamp_ns);
    s.header.frame_id = out->Keep(t.parent);
    s.child_frame_id = out->Keep(t.child);
    s.transform.translation.x = t.parent_from_child(0, 3) * kMetresPerMm;
    s.transform.translation.y = t.parent_from_child(1, 3) * kMetresPerMm;
    s.transform.translation.z = t.parent_from_child(2, 3) * kMetresPerMm;
    const cv::Vec4d q = QuaternionFromRotation(t.parent_from_child.get_minor<3, 3>(0, 0));
    s.transform.rotation.x = q[0];
    s.transform.rotation.y = q[1];
    s.transform.rotation.z = q[2];
    s.transform.rotation.w = q[3];
    list.push_back(s);
  }
  const std::size_t count = list.size();
  Borrow(&out->msg().transforms, out->Keep(std::move(list)), count);
  return true;
}

}  // namespace craftscan::dds
