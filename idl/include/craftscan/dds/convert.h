// Conversions between craftscan's data (cv::Mat images and disparity maps,
// craftscan::PointCloud, StereoCalibration) and the DDS messages.
//
// Writing: Make*() fill an Outgoing<Msg> (replacing what it held). Big arrays
// are borrowed, not copied, whenever the wire layout equals the memory
// layout (continuous Mats, PointCloud's vectors); the source must then stay
// alive and unchanged until the message is written. Where a layout change is
// needed (PointCloud2's interleaved points, a non-continuous Mat, ROS's
// disparity convention) the new buffer is owned by the Outgoing.
//
// Reading: *ToMat() return a cv::Mat header over the message's data (no
// copy; valid while the message lives; clone() to keep it); the cloud
// readers copy into a craftscan::PointCloud.
//
// Units: craftscan messages are in millimetres and pixels as the pipeline
// is; the ROS messages follow ROS (REP 103): metres, so PointCloud2 points,
// CameraInfo's P translation and DisparityImage's baseline are converted.
//
// Every function returns false with *error (may be null) naming what is
// wrong, and never throws. All are thread-safe (no shared state).
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core/mat.hpp>
#include <opencv2/core/matx.hpp>

#include "craftscan/dds/messages.h"
#include "craftscan/dds/topics.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/point_cloud.h"

namespace craftscan::dds {

// sensor_msgs/PointField datatype values.
enum class PointFieldType : uint8_t {
  kInt8 = 1,
  kUint8 = 2,
  kInt16 = 3,
  kUint16 = 4,
  kInt32 = 5,
  kUint32 = 6,
  kFloat32 = 7,
  kFloat64 = 8,
};

// --- Time ---------------------------------------------------------------------

// ns since the epoch ↔ ROS Time (sec, nanosec with 0 ≤ nanosec < 10^9;
// negative times floor to the earlier second). Seconds beyond int32 saturate.
ros::Time RosTimeFromNs(int64_t stamp_ns);
int64_t NsFromRosTime(const ros::Time& time);

// --- Images -------------------------------------------------------------------

// The encoding of a Mat: "mono8" (CV_8UC1), "bgr8" (CV_8UC3), "32FC1"
// (CV_32FC1); empty for any other type.
std::string_view ImageEncoding(const cv::Mat& image);

// A sensor_msgs Image of `image` (mono8, bgr8 or 32FC1, not empty), little
// endian, step = width × pixel bytes. Borrows a continuous Mat's pixels.
bool MakeImage(const cv::Mat& image, int64_t stamp_ns, std::string_view frame_id,
               Outgoing<ros::Image>* out, std::string* error);

// A Mat over the pixels of `image` (mono8, bgr8 or 32FC1; step ≥ width ×
// pixel bytes; data exactly step × height bytes). A big-endian 32FC1 image is
// byte-swapped into a new Mat instead.
bool ImageToMat(const ros::Image& image, cv::Mat* mat, std::string* error);

// --- Stereo captures --------------------------------------------------------

// The fields of a StereoCapture besides the pixels and their size/encoding.
struct StereoCaptureMeta {
  std::string session;
  int32_t view_index = 0;
  double angle_deg = 0;  // commanded turntable angle
  double exposure_us = 0;
  double gain_db = 0;
  int64_t left_stamp_ns = 0, right_stamp_ns = 0;
  std::string left_frame_id, right_frame_id;
};

// A StereoCapture of two images of the same size and type, CV_8UC1 (mono8)
// or CV_8UC3 (bgr8). Borrows continuous Mats.
bool MakeStereoCapture(const cv::Mat& left, const cv::Mat& right, const StereoCaptureMeta& meta,
                       Outgoing<msg::StereoCapture>* out, std::string* error);

// Mats over the pixels of `capture` (checks encoding, size and data lengths).
bool StereoCaptureToMats(const msg::StereoCapture& capture, cv::Mat* left, cv::Mat* right,
                         std::string* error);

// --- Disparity ----------------------------------------------------------------

// The fields of a disparity message besides the pixels. Disparities follow
// the pipeline: d = x_left − x_right in rectified px, NaN where invalid.
struct DisparityMeta {
  std::string session;
  int32_t view_index = 0;
  float f_px = 0;           // rectified focal length (StereoCalibration::rectified_focal_px)
  float baseline_mm = 0;    // StereoCalibration::baseline_mm
  float cx_offset_px = 0;   // rectified cx_left − cx_right (P1(0,2) − P2(0,2))
  float min_disparity = 0;  // searched range, px
  float max_disparity = 0;
  float delta_d_px = 1.0f / 16;  // smallest disparity step (ROS DisparityImage.delta_d)
  int64_t stamp_ns = 0;
  std::string frame_id;  // rectified left camera frame
};

// A craftscan Disparity of a CV_32FC1 map (NaN = invalid, kept as is).
// Borrows a continuous Mat. Needs finite f_px > 0, baseline_mm > 0,
// min_disparity ≤ max_disparity.
bool MakeDisparity(const cv::Mat& disparity, const DisparityMeta& meta,
                   Outgoing<msg::Disparity>* out, std::string* error);

// A Mat (CV_32FC1) over the data of `disparity`.
bool DisparityToMat(const msg::Disparity& disparity, cv::Mat* mat, std::string* error);

// A stereo_msgs DisparityImage, in ROS's convention (new buffer): values
// d − cx_offset_px (so Z = f·t/d), invalid (NaN/inf) pixels set to
// min_disparity − 1 (ROS: below min_disparity = invalid); min/max_disparity
// shifted likewise; t = baseline in metres; valid_window = bounding box of
// the valid pixels (all zero if none). Same requirements as MakeDisparity.
bool MakeDisparityImage(const cv::Mat& disparity, const DisparityMeta& meta,
                        Outgoing<ros::DisparityImage>* out, std::string* error);

// --- Point clouds -------------------------------------------------------------

struct CloudMeta {
  std::string session;
  int32_t view_index = -1;                           // −1 = fused
  std::string kind = "fused";                        // "view" or "fused"
  cv::Matx44d world_from_view = cv::Matx44d::eye();  // mm
  int64_t stamp_ns = 0;
  std::string frame_id;
};

// A craftscan PointCloud of `cloud` (which must pass IsValid and hold fewer
// than 2^32/3 points). Borrows the points, colours and normals.
bool MakeCloud(const PointCloud& cloud, const CloudMeta& meta, Outgoing<msg::PointCloud>* out,
               std::string* error);

// Copies `message` into *cloud (replacing it). Checks point_count against
// xyz (3 floats per point), and rgb/normals (empty or 3 per point).
// *meta (may be null) gets the other fields.
bool CloudFromMessage(const msg::PointCloud& message, PointCloud* cloud, CloudMeta* meta,
                      std::string* error);

// A sensor_msgs PointCloud2 of `cloud` (IsValid), unorganised (height 1),
// little endian, in metres: fields x, y, z (FLOAT32, offsets 0, 4, 8), then
// rgb (FLOAT32 holding 0x00RRGGBB, as PCL/rviz pack it) if the cloud has
// colours, then normal_x, normal_y, normal_z (FLOAT32) if it has normals;
// point_step 12/16/24/28 bytes, no padding. is_dense = all points finite.
// Interleaves into a new buffer.
bool MakePointCloud2(const PointCloud& cloud, int64_t stamp_ns, std::string_view frame_id,
                     Outgoing<ros::PointCloud2>* out, std::string* error);

// Reads any little-endian PointCloud2 with x, y, z fields (FLOAT32 or
// FLOAT64) into *cloud in mm; colours from an "rgb" or "rgba" field (FLOAT32
// or UINT32 holding 0x??RRGGBB) and normals from normal_x/y/z (FLOAT32 or
// FLOAT64) when present. Points with a non-finite coordinate are skipped.
// Fails on big-endian data, missing x/y/z, fields outside point_step,
// row_step < width × point_step, or data shorter/longer than row_step × height.
bool CloudFromPointCloud2(const ros::PointCloud2& message, PointCloud* cloud, std::string* error);

// --- Calibration --------------------------------------------------------------

// sensor_msgs CameraInfo of one camera of `calibration` (must pass IsValid),
// for its raw images, as ROS's image_proc expects: K and D the raw
// intrinsics ("plumb_bob" with 5 coefficients, or "rational_polynomial" with
// 8), R = R1/R2 (rectified_from_raw), P = P1/P2 with the translation column in
// metres (P(0,3) = −fx·baseline for the right camera). Binning 0, ROI empty
// (the full image).
bool MakeCameraInfo(const StereoCalibration& calibration, Side side, int64_t stamp_ns,
                    std::string_view frame_id, Outgoing<ros::CameraInfo>* out, std::string* error);

// --- Transforms (/tf, /tf_static) ---------------------------------------------

// The frames of one station, named as REP 103 and REP 105 expect and
// prefixed with the station id (all stations of a domain share /tf):
//
//   <station>_base_link                       root, fixed: the rig's body. REP 103
//   │                                         axes: x forward (the left camera's
//   │                                         viewing direction), y left, z up;
//   │                                         origin at the left camera
//   └─ <station>_rig_optical_frame            the rectified left camera (z forward,
//      │                                      x right, y down): craftscan's rig
//      │                                      frame; disparity and view clouds
//      ├─ <station>_left_camera_optical_frame   raw left camera (image_raw,
//      ├─ <station>_right_camera_optical_frame  camera_info; R1/R2 and baseline)
//      └─ <station>_turntable_base            fixed: origin where the axis meets
//         │                                   the platter, +Z along the axis
//         │                                   (TurntableFromRig); the fused cloud
//         └─ <station>_turntable              the platter: turned from
//                                             turntable_base by the angle since the
//                                             session's first view (/tf, per view)
//
// Everything above the turntable is on /tf_static; a calibration without a
// turntable axis puts turntable_base at the rig optical frame (identity),
// as the pipeline then fuses in the first view's rig frame.
struct StationFrames {
  std::string base, rig, left, right, turntable_base, turntable;
};
StationFrames FramesOf(std::string_view station);

// One transform of the tree: p_in_parent = parent_from_child · p_in_child
// (rigid, translation in mm).
struct FrameTransform {
  std::string parent, child;
  cv::Matx44d parent_from_child = cv::Matx44d::eye();
};

// The static transforms of `frames` from `calibration` (must pass IsValid):
// base_link → rig, rig → left, rig → right, rig → turntable_base, in that
// order. False with *error otherwise.
bool StaticStationTransforms(const StereoCalibration& calibration, const StationFrames& frames,
                             std::vector<FrameTransform>* transforms, std::string* error);

// turntable_base → turntable: a right-handed turn about +Z by `angle_rad`.
FrameTransform TurntableTransform(const StationFrames& frames, double angle_rad);

// A tf2_msgs TFMessage of `transforms` (each rigid: an orthonormal rotation
// with determinant +1 within 1e-6, finite), all stamped `stamp_ns`, in
// metres with unit quaternions (w ≥ 0). False with *error naming the
// transform that is not rigid.
bool MakeTfMessage(const std::vector<FrameTransform>& transforms, int64_t stamp_ns,
                   Outgoing<ros::TFMessage>* out, std::string* error);

// The unit quaternion (x, y, z, w; w ≥ 0) of a rotation matrix.
cv::Vec4d QuaternionFromRotation(const cv::Matx33d& rotation);

}  // namespace craftscan::dds
