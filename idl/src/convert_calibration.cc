// StereoCalibration → sensor_msgs CameraInfo.
#include <string>
#include <vector>

#include "convert_internal.h"
#include "craftscan/dds/convert.h"

namespace craftscan::dds {

bool MakeCameraInfo(const StereoCalibration& calibration, Side side, int64_t stamp_ns,
                    std::string_view frame_id, Outgoing<ros::CameraInfo>* out, std::string* error) {
  std::string why;
  if (!calibration.IsValid(&why)) return internal::Fail(error, "calibration: " + why);
  const bool left = side == Side::kLeft;
  const CameraIntrinsics& intrinsics = left ? calibration.left : calibration.right;
  const cv::Matx33d& rectified_from_raw = left ? calibration.R1 : calibration.R2;
  const cv::Matx34d& projection = left ? calibration.P1 : calibration.P2;

  *out = Outgoing<ros::CameraInfo>();
  ros::CameraInfo& m = out->msg();
  m.header.stamp = RosTimeFromNs(stamp_ns);
  m.header.frame_id = out->Keep(frame_id);
  m.height = static_cast<uint32_t>(calibration.image_size.height);
  m.width = static_cast<uint32_t>(calibration.image_size.width);
  const bool rational = intrinsics.UsesRationalModel();
  m.distortion_model = out->Keep(rational ? "rational_polynomial" : "plumb_bob");
  std::vector<double> d(intrinsics.distortion.val, intrinsics.distortion.val + 5);
  if (rational) {
    d.insert(d.end(), intrinsics.distortion_rational.val, intrinsics.distortion_rational.val + 3);
  }
  const std::size_t d_count = d.size();
  Borrow(&m.d, out->Keep(std::move(d)), d_count);
  for (int i = 0; i < 9; ++i) {
    m.k[i] = intrinsics.camera_matrix.val[i];
    m.r[i] = rectified_from_raw.val[i];
  }
  // ROS wants P's translation column (−fx·Tx) in metres; ours is in mm.
  constexpr double kMetresPerMm = 1e-3;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 4; ++col) {
      m.p[row * 4 + col] = projection(row, col) * (col == 3 ? kMetresPerMm : 1.0);
    }
  }
  m.binning_x = 0;
  m.binning_y = 0;
  return true;
}

}  // namespace craftscan::dds
