// Conversions between craftscan data and DDS messages (no DDS traffic):
// layouts, zero-copy borrowing, units, ROS conventions and error messages.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "craftscan/dds/convert.h"
#include "craftscan/dds/messages.h"
#include "craftscan/dds/ros2_definitions.h"
#include "craftscan/dds/topics.h"
#include "craftscan/pipeline/common/pose.h"

namespace craftscan::dds {
namespace {

// --- Time ---------------------------------------------------------------------

TEST(DdsConvertTime, RoundTripsAndNormalisesNegativeTimes) {
  const ros::Time t = RosTimeFromNs(1'700'000'000'123'456'789);
  EXPECT_EQ(t.sec, 1'700'000'000);
  EXPECT_EQ(t.nanosec, 123'456'789u);
  EXPECT_EQ(NsFromRosTime(t), 1'700'000'000'123'456'789);

  const ros::Time negative = RosTimeFromNs(-1);  // 1 ns before the epoch
  EXPECT_EQ(negative.sec, -1);
  EXPECT_EQ(negative.nanosec, 999'999'999u);
  EXPECT_EQ(NsFromRosTime(negative), -1);

  const ros::Time saturated = RosTimeFromNs(std::numeric_limits<int64_t>::max());
  EXPECT_EQ(saturated.sec, std::numeric_limits<int32_t>::max());
}

// --- Images -------------------------------------------------------------------

// A 32FC1 ros::Image over `bytes` (borrowed).
ros::Image FloatImage(uint32_t width, uint32_t height, uint32_t step, std::vector<uint8_t>* bytes) {
  ros::Image image{};
  image.width = width;
  image.height = height;
  image.step = step;
  image.encoding = const_cast<char*>("32FC1");
  EXPECT_TRUE(Borrow(&image.data, bytes->data(), bytes->size()));
  return image;
}

TEST(DdsConvertImage, ContinuousMatsAreBorrowedAndRoundTrip) {
  for (int type : {CV_8UC1, CV_8UC3, CV_32FC1}) {
    cv::Mat image(48, 64, type);
    cv::randu(image, 0, 255);
    Outgoing<ros::Image> out;
    std::string error;
    ASSERT_TRUE(MakeImage(image, 5'000'000'001, "cam_left", &out, &error)) << error;
    const ros::Image& m = out.msg();
    EXPECT_EQ(m.data._buffer, image.data) << "a continuous Mat must not be copied";
    EXPECT_FALSE(m.data._release);
    EXPECT_EQ(m.width, 64u);
    EXPECT_EQ(m.height, 48u);
    EXPECT_EQ(m.step, 64u * image.elemSize());
    EXPECT_EQ(m.is_bigendian, 0);
    EXPECT_EQ(View(m.encoding), ImageEncoding(image));
    EXPECT_EQ(View(m.header.frame_id), "cam_left");
    EXPECT_EQ(m.header.stamp.sec, 5);
    EXPECT_EQ(m.header.stamp.nanosec, 1u);

    cv::Mat back;
    ASSERT_TRUE(ImageToMat(m, &back, &error)) << error;
    EXPECT_EQ(back.type(), type);
    EXPECT_EQ(cv::norm(back, image, cv::NORM_INF), 0);
  }
  EXPECT_EQ(ImageEncoding(cv::Mat(2, 2, CV_8UC1)), "mono8");
  EXPECT_EQ(ImageEncoding(cv::Mat(2, 2, CV_8UC3)), "bgr8");
  EXPECT_EQ(ImageEncoding(cv::Mat(2, 2, CV_32FC1)), "32FC1");
  EXPECT_EQ(ImageEncoding(cv::Mat(2, 2, CV_16UC1)), "");
}

TEST(DdsConvertImage, RegionOfInterestIsCopiedWithPackedRows) {
  cv::Mat parent(40, 50, CV_8UC3);
  cv::randu(parent, 0, 255);
  const cv::Mat roi = parent(cv::Rect(5, 7, 20, 10));
  ASSERT_FALSE(roi.isContinuous());
  Outgoing<ros::Image> out;
  std::string error;
  ASSERT_TRUE(MakeImage(roi, 0, "f", &out, &error)) << error;
  EXPECT_EQ(out.msg().step, 60u);
  EXPECT_EQ(out.msg().data._length, 600u);
  EXPECT_NE(out.msg().data._buffer, roi.data);
  cv::Mat back;
  ASSERT_TRUE(ImageToMat(out.msg(), &back, &error)) << error;
  EXPECT_EQ(cv::norm(back, roi, cv::NORM_INF), 0);
}

TEST(DdsConvertImage, OutgoingSurvivesAMove) {
  cv::Mat image(8, 8, CV_8UC1, cv::Scalar(7));
  Outgoing<ros::Image> out;
  ASSERT_TRUE(MakeImage(image, 0, "a_frame_name_longer_than_sso_buffers", &out, nullptr));
  Outgoing<ros::Image> moved = std::move(out);
  EXPECT_EQ(View(moved.msg().header.frame_id), "a_frame_name_longer_than_sso_buffers");
  EXPECT_EQ(View(moved.msg().encoding), "mono8");
  EXPECT_EQ(out.msg().encoding, nullptr);
}

TEST(DdsConvertImage, RejectsBadImagesWithClearErrors) {
  Outgoing<ros::Image> out;
  std::string error;
  EXPECT_FALSE(MakeImage(cv::Mat(), 0, "f", &out, &error));
  EXPECT_NE(error.find("empty"), std::string::npos) << error;
  EXPECT_FALSE(MakeImage(cv::Mat(4, 4, CV_16UC1), 0, "f", &out, &error));
  EXPECT_NE(error.find("CV_16UC1"), std::string::npos) << error;

  std::vector<uint8_t> pixels(4 * 3 * 4, 0);
  ros::Image image = FloatImage(4, 3, 16, &pixels);
  cv::Mat mat;
  ASSERT_TRUE(ImageToMat(image, &mat, &error)) << error;

  image.encoding = const_cast<char*>("rgb16");
  EXPECT_FALSE(ImageToMat(image, &mat, &error));
  EXPECT_NE(error.find("unsupported encoding 'rgb16'"), std::string::npos) << error;
  image.encoding = const_cast<char*>("32FC1");
  image.step = 12;  // < 4 px × 4 bytes
  EXPECT_FALSE(ImageToMat(image, &mat, &error));
  EXPECT_NE(error.find("step 12"), std::string::npos) << error;
  image.step = 18;  // not a multiple of 4
  EXPECT_FALSE(ImageToMat(image, &mat, &error));
  image.step = 16;
  image.data._length = 47;
  EXPECT_FALSE(ImageToMat(image, &mat, &error));
  EXPECT_NE(error.find("data has 47 bytes, expected step × height = 48"), std::string::npos)
      << error;
  image.data._length = 48;
  image.width = 0;
  EXPECT_FALSE(ImageToMat(image, &mat, &error));
  EXPECT_NE(error.find("empty"), std::string::npos) << error;
}

TEST(DdsConvertImage, BigEndianFloatImagesAreSwapped) {
  const float values[2] = {1.5f, -3.25f};
  std::vector<uint8_t> bytes(8);
  for (int i = 0; i < 2; ++i) {
    uint8_t little[4];
    std::memcpy(little, &values[i], 4);
    for (int b = 0; b < 4; ++b) bytes[i * 4 + b] = little[3 - b];
  }
  ros::Image image = FloatImage(2, 1, 8, &bytes);
  image.is_bigendian = 1;
  cv::Mat mat;
  std::string error;
  ASSERT_TRUE(ImageToMat(image, &mat, &error)) << error;
  EXPECT_EQ(mat.at<float>(0, 0), 1.5f);
  EXPECT_EQ(mat.at<float>(0, 1), -3.25f);
}

// --- Stereo captures --------------------------------------------------------

TEST(DdsConvertStereo, CaptureBorrowsBothImagesAndRoundTrips) {
  cv::Mat left(32, 40, CV_8UC3), right(32, 40, CV_8UC3);
  cv::randu(left, 0, 255);
  cv::randu(right, 0, 255);
  StereoCaptureMeta meta;
  meta.session = "20240101-120000-egg";
  meta.view_index = 3;
  meta.angle_deg = 67.5;
  meta.exposure_us = 12000;
  meta.gain_db = 2.5;
  meta.left_stamp_ns = 11;
  meta.right_stamp_ns = 12;
  meta.left_frame_id = "st_left_optical";
  meta.right_frame_id = "st_right_optical";
  Outgoing<msg::StereoCapture> out;
  std::string error;
  ASSERT_TRUE(MakeStereoCapture(left, right, meta, &out, &error)) << error;
  const msg::StereoCapture& m = out.msg();
  EXPECT_EQ(m.left_data._buffer, left.data);
  EXPECT_EQ(m.right_data._buffer, right.data);
  EXPECT_EQ(View(m.encoding), "bgr8");
  EXPECT_EQ(m.width, 40u);
  EXPECT_EQ(m.height, 32u);
  EXPECT_EQ(View(m.session), meta.session);
  EXPECT_EQ(m.view_index, 3);
  EXPECT_EQ(m.angle_deg, 67.5);
  EXPECT_EQ(View(m.right_frame_id), "st_right_optical");

  cv::Mat got_left, got_right;
  ASSERT_TRUE(StereoCaptureToMats(m, &got_left, &got_right, &error)) << error;
  EXPECT_EQ(cv::norm(got_left, left, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(got_right, right, cv::NORM_INF), 0);
}

TEST(DdsConvertStereo, RejectsMismatchedOrUnsupportedImages) {
  Outgoing<msg::StereoCapture> out;
  std::string error;
  EXPECT_FALSE(MakeStereoCapture(cv::Mat(4, 4, CV_8UC1), cv::Mat(4, 5, CV_8UC1), {}, &out, &error));
  EXPECT_NE(error.find("must match"), std::string::npos) << error;
  EXPECT_FALSE(
      MakeStereoCapture(cv::Mat(4, 4, CV_32FC1), cv::Mat(4, 4, CV_32FC1), {}, &out, &error));
  EXPECT_NE(error.find("left image: unsupported pixel type"), std::string::npos) << error;

  cv::Mat image(4, 4, CV_8UC1, cv::Scalar(1));
  ASSERT_TRUE(MakeStereoCapture(image, image, {}, &out, &error)) << error;
  out.msg().right_data._length = 15;
  cv::Mat left, right;
  EXPECT_FALSE(StereoCaptureToMats(out.msg(), &left, &right, &error));
  EXPECT_NE(error.find("right: data has 15 bytes"), std::string::npos) << error;
}

// --- Disparity ----------------------------------------------------------------

DisparityMeta TestDisparityMeta() {
  return DisparityMeta{.session = "20240101-120000-egg",
                       .view_index = 2,
                       .f_px = 1400,
                       .baseline_mm = 120,
                       .cx_offset_px = -30,  // verged rig: cx_left − cx_right
                       .min_disparity = -60,
                       .max_disparity = 40,
                       .stamp_ns = 42,
                       .frame_id = "rig"};
}

TEST(DdsConvertDisparity, CraftscanMessageBorrowsAndKeepsNaN) {
  cv::Mat disparity(10, 12, CV_32FC1, cv::Scalar(5.25f));
  disparity.at<float>(3, 4) = std::numeric_limits<float>::quiet_NaN();
  Outgoing<msg::Disparity> out;
  std::string error;
  ASSERT_TRUE(MakeDisparity(disparity, TestDisparityMeta(), &out, &error)) << error;
  EXPECT_EQ(out.msg().data._buffer, disparity.ptr<float>());
  EXPECT_EQ(out.msg().cx_offset_px, -30.0f);
  cv::Mat back;
  ASSERT_TRUE(DisparityToMat(out.msg(), &back, &error)) << error;
  EXPECT_TRUE(std::isnan(back.at<float>(3, 4)));
  EXPECT_EQ(back.at<float>(9, 11), 5.25f);

  DisparityMeta bad = TestDisparityMeta();
  bad.baseline_mm = 0;
  EXPECT_FALSE(MakeDisparity(disparity, bad, &out, &error));
  EXPECT_NE(error.find("baseline_mm"), std::string::npos) << error;
  EXPECT_FALSE(MakeDisparity(cv::Mat(3, 3, CV_8UC1), TestDisparityMeta(), &out, &error));
  EXPECT_NE(error.find("unsupported pixel type"), std::string::npos) << error;
}

TEST(DdsConvertDisparity, RosDisparityImageFollowsRosConventions) {
  cv::Mat disparity(10, 12, CV_32FC1, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  disparity(cv::Rect(2, 3, 5, 4)).setTo(10.0f);  // valid block
  Outgoing<ros::DisparityImage> out;
  std::string error;
  const DisparityMeta meta = TestDisparityMeta();
  ASSERT_TRUE(MakeDisparityImage(disparity, meta, &out, &error)) << error;
  const ros::DisparityImage& m = out.msg();
  EXPECT_EQ(View(m.image.encoding), "32FC1");
  EXPECT_EQ(m.image.step, 48u);
  EXPECT_EQ(m.f, 1400.0f);
  EXPECT_FLOAT_EQ(m.t, 0.12f);         // metres
  EXPECT_EQ(m.min_disparity, -30.0f);  // −60 − (−30)
  EXPECT_EQ(m.max_disparity, 70.0f);
  EXPECT_EQ(m.valid_window.x_offset, 2u);
  EXPECT_EQ(m.valid_window.y_offset, 3u);
  EXPECT_EQ(m.valid_window.width, 5u);
  EXPECT_EQ(m.valid_window.height, 4u);
  cv::Mat values;
  ASSERT_TRUE(ImageToMat(m.image, &values, &error)) << error;
  EXPECT_EQ(values.at<float>(3, 2), 40.0f);            // 10 − (−30)
  EXPECT_LT(values.at<float>(0, 0), m.min_disparity);  // invalid
  EXPECT_EQ(View(m.header.frame_id), "rig");
}

// --- Point clouds -------------------------------------------------------------

PointCloud TestCloud(int n, bool colors, bool normals) {
  PointCloud cloud;
  cv::RNG rng(7);
  for (int i = 0; i < n; ++i) {
    cloud.points_mm.emplace_back(rng.uniform(-100.f, 100.f), rng.uniform(-100.f, 100.f),
                                 rng.uniform(200.f, 400.f));
    if (colors) cloud.colors_rgb.emplace_back(rng.uniform(0, 256), rng.uniform(0, 256), i % 256);
    if (normals) cloud.normals.emplace_back(0.f, std::sqrt(0.5f), -std::sqrt(0.5f));
  }
  return cloud;
}

TEST(DdsConvertCloud, CraftscanMessageBorrowsAndRoundTripsBitExact) {
  const PointCloud cloud = TestCloud(500, true, true);
  CloudMeta meta;
  meta.session = "sess";
  meta.view_index = 4;
  meta.kind = "view";
  meta.world_from_view = cv::Matx44d(0, -1, 0, 10, 1, 0, 0, 20, 0, 0, 1, 30, 0, 0, 0, 1);
  meta.stamp_ns = 99;
  meta.frame_id = "world";
  Outgoing<msg::PointCloud> out;
  std::string error;
  ASSERT_TRUE(MakeCloud(cloud, meta, &out, &error)) << error;
  const msg::PointCloud& m = out.msg();
  EXPECT_EQ(m.xyz._buffer, reinterpret_cast<const float*>(cloud.points_mm.data()));
  EXPECT_EQ(m.rgb._buffer, reinterpret_cast<const uint8_t*>(cloud.colors_rgb.data()));
  EXPECT_EQ(m.point_count, 500u);
  EXPECT_EQ(m.xyz._length, 1500u);
  EXPECT_EQ(m.world_from_view[3], 10.0);  // row-major

  PointCloud back;
  CloudMeta back_meta;
  ASSERT_TRUE(CloudFromMessage(m, &back, &back_meta, &error)) << error;
  ASSERT_EQ(back.size(), cloud.size());
  EXPECT_EQ(0, std::memcmp(back.points_mm.data(), cloud.points_mm.data(), 500 * 12));
  EXPECT_EQ(0, std::memcmp(back.colors_rgb.data(), cloud.colors_rgb.data(), 500 * 3));
  EXPECT_EQ(0, std::memcmp(back.normals.data(), cloud.normals.data(), 500 * 12));
  EXPECT_EQ(back_meta.kind, "view");
  EXPECT_EQ(back_meta.view_index, 4);
  EXPECT_EQ(back_meta.world_from_view, meta.world_from_view);

  out.msg().rgb._length = 7;
  EXPECT_FALSE(CloudFromMessage(out.msg(), &back, nullptr, &error));
  EXPECT_NE(error.find("rgb has 7 values, expected 1500 or none"), std::string::npos) << error;

  PointCloud invalid = cloud;
  invalid.normals.pop_back();
  EXPECT_FALSE(MakeCloud(invalid, meta, &out, &error));
  EXPECT_NE(error.find("cloud:"), std::string::npos) << error;
}

// The offset of field `name` in a PointCloud2, −1 if absent.
int FieldOffset(const ros::PointCloud2& m, std::string_view name) {
  for (uint32_t i = 0; i < m.fields._length; ++i) {
    if (View(m.fields._buffer[i].name) == name) return static_cast<int>(m.fields._buffer[i].offset);
  }
  return -1;
}

TEST(DdsConvertCloud, PointCloud2LayoutFollowsFields) {
  struct Case {
    bool colors, normals;
    uint32_t point_step;
    int rgb_offset, normal_offset;
  };
  for (const Case& c : {Case{false, false, 12, -1, -1}, Case{true, false, 16, 12, -1},
                        Case{false, true, 24, -1, 12}, Case{true, true, 28, 12, 16}}) {
    const PointCloud cloud = TestCloud(20, c.colors, c.normals);
    Outgoing<ros::PointCloud2> out;
    std::string error;
    ASSERT_TRUE(MakePointCloud2(cloud, 1'000'000'000, "world", &out, &error)) << error;
    const ros::PointCloud2& m = out.msg();
    EXPECT_EQ(m.point_step, c.point_step);
    EXPECT_EQ(m.row_step, 20 * c.point_step);
    EXPECT_EQ(m.height, 1u);
    EXPECT_EQ(m.width, 20u);
    EXPECT_FALSE(m.is_bigendian);
    EXPECT_TRUE(m.is_dense);
    EXPECT_EQ(FieldOffset(m, "x"), 0);
    EXPECT_EQ(FieldOffset(m, "y"), 4);
    EXPECT_EQ(FieldOffset(m, "z"), 8);
    EXPECT_EQ(FieldOffset(m, "rgb"), c.rgb_offset);
    EXPECT_EQ(FieldOffset(m, "normal_x"), c.normal_offset);
    for (uint32_t i = 0; i < m.fields._length; ++i) {
      EXPECT_EQ(m.fields._buffer[i].datatype, static_cast<uint8_t>(PointFieldType::kFloat32));
      EXPECT_EQ(m.fields._buffer[i].count, 1u);
    }
    const uint8_t* p5 = m.data._buffer + 5 * m.point_step;
    float z_m;
    std::memcpy(&z_m, p5 + 8, 4);
    EXPECT_FLOAT_EQ(z_m, cloud.points_mm[5][2] / 1000.0f);  // metres
    if (c.colors) {
      uint32_t rgb;
      std::memcpy(&rgb, p5 + 12, 4);
      const cv::Vec3b& col = cloud.colors_rgb[5];
      EXPECT_EQ(rgb, (uint32_t{col[0]} << 16) | (uint32_t{col[1]} << 8) | col[2]);
    }

    PointCloud back;
    ASSERT_TRUE(CloudFromPointCloud2(m, &back, &error)) << error;
    ASSERT_EQ(back.size(), cloud.size());
    EXPECT_EQ(back.HasColors(), c.colors);
    EXPECT_EQ(back.HasNormals(), c.normals);
    for (std::size_t i = 0; i < cloud.size(); ++i) {
      EXPECT_LT(cv::norm(back.points_mm[i] - cloud.points_mm[i]), 1e-4);  // mm
      if (c.colors) {
        EXPECT_EQ(back.colors_rgb[i], cloud.colors_rgb[i]);
      }
      if (c.normals) {
        EXPECT_EQ(back.normals[i], cloud.normals[i]);
      }
    }
  }
}

// A PointCloud2 as other producers make it: organised 2×2, float64 xyz with
// padding, rgba as uint32, one NaN point.
TEST(DdsConvertCloud, ReadsForeignPointCloud2Layouts) {
  constexpr uint32_t kStep = 40;  // x y z (f64) + 4 pad + rgba (u32) + 8 pad
  std::vector<uint8_t> data(4 * kStep, 0);
  for (int i = 0; i < 4; ++i) {
    const double xyz[3] = {0.001 * i, i == 2 ? std::nan("") : 0.5, 1.0};
    std::memcpy(&data[i * kStep], xyz, 24);
    const uint32_t rgba = 0xff000000u | (10u * i) << 16 | 20u << 8 | 30u;
    std::memcpy(&data[i * kStep + 28], &rgba, 4);
  }
  ros::PointField fields[4] = {};
  const char* names[4] = {"x", "y", "z", "rgba"};
  const uint32_t offsets[4] = {0, 8, 16, 28};
  for (int i = 0; i < 4; ++i) {
    fields[i].name = const_cast<char*>(names[i]);
    fields[i].offset = offsets[i];
    fields[i].datatype =
        static_cast<uint8_t>(i < 3 ? PointFieldType::kFloat64 : PointFieldType::kUint32);
    fields[i].count = 1;
  }
  ros::PointCloud2 m{};
  m.height = 2;
  m.width = 2;
  m.point_step = kStep;
  m.row_step = 2 * kStep;
  ASSERT_TRUE(Borrow(&m.fields, fields, 4));
  ASSERT_TRUE(Borrow(&m.data, data.data(), data.size()));
  PointCloud cloud;
  std::string error;
  ASSERT_TRUE(CloudFromPointCloud2(m, &cloud, &error)) << error;
  ASSERT_EQ(cloud.size(), 3u);  // the NaN point is skipped
  EXPECT_EQ(cloud.points_mm[2], cv::Vec3f(3, 500, 1000));
  EXPECT_EQ(cloud.colors_rgb[2], cv::Vec3b(30, 20, 30));
  EXPECT_FALSE(cloud.HasNormals());

  ros::PointCloud2 bad = m;
  bad.is_bigendian = true;
  EXPECT_FALSE(CloudFromPointCloud2(bad, &cloud, &error));
  EXPECT_NE(error.find("big-endian"), std::string::npos) << error;
  bad = m;
  bad.data._length -= 1;
  EXPECT_FALSE(CloudFromPointCloud2(bad, &cloud, &error));
  EXPECT_NE(error.find("expected row_step × height = 160"), std::string::npos) << error;
  bad = m;
  bad.row_step = 60;
  EXPECT_FALSE(CloudFromPointCloud2(bad, &cloud, &error));
  EXPECT_NE(error.find("row_step 60"), std::string::npos) << error;
  bad = m;
  bad.fields._length = 2;  // no z
  EXPECT_FALSE(CloudFromPointCloud2(bad, &cloud, &error));
  EXPECT_NE(error.find("only some of the fields x, y, z"), std::string::npos) << error;
  fields[3].offset = 38;  // 38 + 4 > 40
  EXPECT_FALSE(CloudFromPointCloud2(m, &cloud, &error));
  EXPECT_NE(error.find("field 'rgba'"), std::string::npos) << error;
}

// --- Calibration --------------------------------------------------------------

StereoCalibration TestCalibration(bool rational) {
  StereoCalibration c;
  c.image_size = cv::Size(1280, 1024);
  c.left.camera_matrix = cv::Matx33d(1400, 0, 650, 0, 1402, 510, 0, 0, 1);
  c.right.camera_matrix = cv::Matx33d(1395, 0, 630, 0, 1398, 515, 0, 0, 1);
  c.left.distortion = {-0.1, 0.05, 0.001, -0.002, 0.01};
  c.right.distortion = {-0.12, 0.04, 0.0, 0.001, 0.0};
  if (rational) c.left.distortion_rational = {0.1, 0.02, 0.003};
  cv::Matx33d rotation;
  cv::Rodrigues(cv::Vec3d(0, -0.12, 0), rotation);  // toed in by ~7°
  c.R = rotation;
  c.T = cv::Vec3d(-120, 0.5, 8);
  std::string error;
  EXPECT_TRUE(ComputeRectification({}, &c, &error)) << error;
  return c;
}

TEST(DdsConvertCalibration, CameraInfoCarriesRawIntrinsicsAndRectification) {
  const StereoCalibration calibration = TestCalibration(false);
  for (Side side : {Side::kLeft, Side::kRight}) {
    const bool left = side == Side::kLeft;
    Outgoing<ros::CameraInfo> out;
    std::string error;
    ASSERT_TRUE(MakeCameraInfo(calibration, side, 7, left ? "l" : "r", &out, &error)) << error;
    const ros::CameraInfo& m = out.msg();
    const CameraIntrinsics& intrinsics = left ? calibration.left : calibration.right;
    const cv::Matx34d& P = left ? calibration.P1 : calibration.P2;
    const cv::Matx33d& R = left ? calibration.R1 : calibration.R2;
    EXPECT_EQ(m.width, 1280u);
    EXPECT_EQ(m.height, 1024u);
    EXPECT_EQ(View(m.distortion_model), "plumb_bob");
    ASSERT_EQ(m.d._length, 5u);
    for (int i = 0; i < 5; ++i) EXPECT_EQ(m.d._buffer[i], intrinsics.distortion[i]);
    for (int i = 0; i < 9; ++i) {
      EXPECT_EQ(m.k[i], intrinsics.camera_matrix.val[i]);
      EXPECT_EQ(m.r[i], R.val[i]);
    }
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 3; ++col) EXPECT_EQ(m.p[row * 4 + col], P(row, col));
      EXPECT_DOUBLE_EQ(m.p[row * 4 + 3], P(row, 3) / 1000);
    }
    if (!left) {  // ROS: P(0,3) = −fx'·baseline (m)
      EXPECT_NEAR(m.p[3], -P(0, 0) * calibration.baseline_mm() / 1000, 1e-6 * P(0, 0));
    }
    EXPECT_EQ(m.binning_x, 0u);
    EXPECT_EQ(m.roi.width, 0u);
  }
  Outgoing<ros::CameraInfo> out;
  std::string error;
  ASSERT_TRUE(MakeCameraInfo(TestCalibration(true), Side::kLeft, 0, "l", &out, &error)) << error;
  EXPECT_EQ(View(out.msg().distortion_model), "rational_polynomial");
  ASSERT_EQ(out.msg().d._length, 8u);
  EXPECT_EQ(out.msg().d._buffer[5], 0.1);

  StereoCalibration invalid = TestCalibration(false);
  invalid.P1 = cv::Matx34d::zeros();
  EXPECT_FALSE(MakeCameraInfo(invalid, Side::kLeft, 0, "l", &out, &error));
  EXPECT_NE(error.find("calibration: P1"), std::string::npos) << error;
}

// --- Transforms ---------------------------------------------------------------

cv::Vec3d Apply(const cv::Matx44d& a_from_b, const cv::Vec3d& p_in_b) {
  const cv::Vec4d p = a_from_b * cv::Vec4d(p_in_b[0], p_in_b[1], p_in_b[2], 1);
  return {p[0], p[1], p[2]};
}

TEST(DdsConvertTransforms, StationTreeFollowsTheCalibrationAndRep103) {
  StereoCalibration calibration = TestCalibration(false);
  calibration.turntable.valid = true;
  calibration.turntable.direction_in_rig = cv::normalize(cv::Vec3d(0, -0.8, -0.6));
  calibration.turntable.point_in_rig_mm = {10, 40, 400};
  const StationFrames frames = FramesOf("st1");
  EXPECT_EQ(frames.base, "st1_base_link");
  EXPECT_EQ(frames.left, "st1_left_camera_optical_frame");
  EXPECT_EQ(frames.rig, "st1_rig_optical_frame");
  std::vector<FrameTransform> tree;
  std::string error;
  ASSERT_TRUE(StaticStationTransforms(calibration, frames, &tree, &error)) << error;
  ASSERT_EQ(tree.size(), 4u);
  const cv::Matx44d base_from_rig = tree[0].parent_from_child;
  const cv::Matx44d rig_from_left = tree[1].parent_from_child;
  const cv::Matx44d rig_from_right = tree[2].parent_from_child;
  const cv::Matx44d rig_from_turntable = tree[3].parent_from_child;
  EXPECT_EQ(tree[2].parent, frames.rig);
  EXPECT_EQ(tree[2].child, frames.right);
  // REP 103: the optical z (forward) is the body's x, optical x (right) −y,
  // optical y (down) −z.
  EXPECT_LT(cv::norm(Apply(base_from_rig, {0, 0, 1}) - cv::Vec3d(1, 0, 0)), 1e-12);
  EXPECT_LT(cv::norm(Apply(base_from_rig, {1, 0, 0}) - cv::Vec3d(0, -1, 0)), 1e-12);
  EXPECT_LT(cv::norm(Apply(base_from_rig, {0, 1, 0}) - cv::Vec3d(0, 0, -1)), 1e-12);
  // The raw cameras: right_from_left through the rig is the calibration's
  // R, T (mm).
  const cv::Matx44d right_from_left = InvertRigid(rig_from_right) * rig_from_left;
  for (const cv::Vec3d& p : {cv::Vec3d(0, 0, 0), cv::Vec3d(100, -50, 500)}) {
    const cv::Vec3d want = calibration.R * p + calibration.T;
    EXPECT_LT(cv::norm(Apply(right_from_left, p) - want), 1e-6) << p;
  }
  // The turntable: its origin is the axis point, its +Z the axis.
  EXPECT_LT(cv::norm(Apply(rig_from_turntable, {0, 0, 0}) - calibration.turntable.point_in_rig_mm),
            1e-9);
  EXPECT_LT(cv::norm(Apply(rig_from_turntable, {0, 0, 1}) - calibration.turntable.point_in_rig_mm -
                     calibration.turntable.direction_in_rig),
            1e-9);
  // Without an axis the turntable base is the rig frame.
  calibration.turntable.valid = false;
  ASSERT_TRUE(StaticStationTransforms(calibration, frames, &tree, &error)) << error;
  EXPECT_EQ(tree[3].parent_from_child, cv::Matx44d::eye());

  // The turntable turns right-handed about +Z.
  const FrameTransform turned = TurntableTransform(frames, CV_PI / 2);
  EXPECT_EQ(turned.parent, frames.turntable_base);
  EXPECT_EQ(turned.child, frames.turntable);
  EXPECT_LT(cv::norm(Apply(turned.parent_from_child, {1, 0, 0}) - cv::Vec3d(0, 1, 0)), 1e-12);
}

TEST(DdsConvertTransforms, TfMessageIsInMetresWithUnitQuaternions) {
  for (const cv::Vec3d& rvec :
       {cv::Vec3d(0, 0, 0), cv::Vec3d(0.3, -1.2, 2.0), cv::Vec3d(CV_PI, 0, 0),
        cv::Vec3d(0, CV_PI, 0), cv::Vec3d(0, 0, CV_PI), cv::Vec3d(2.2, 2.2, 0)}) {
    cv::Matx33d rotation;
    cv::Rodrigues(rvec, rotation);
    const cv::Vec4d q = QuaternionFromRotation(rotation);
    EXPECT_NEAR(cv::norm(q), 1, 1e-12);
    EXPECT_GE(q[3], 0);
    const cv::Matx33d back = RotationFromQuaternion(q[3], q[0], q[1], q[2]);
    EXPECT_LT(cv::norm(back - rotation, cv::NORM_INF), 1e-12) << rvec;
  }
  cv::Matx44d parent_from_child = cv::Matx44d::eye();
  parent_from_child(0, 3) = 120;  // mm
  parent_from_child(2, 3) = -5;
  Outgoing<ros::TFMessage> out;
  std::string error;
  ASSERT_TRUE(MakeTfMessage({{"a", "b", parent_from_child}}, 1'500'000'000, &out, &error)) << error;
  ASSERT_EQ(out.msg().transforms._length, 1u);
  const ros::TransformStamped& t = out.msg().transforms._buffer[0];
  EXPECT_EQ(View(t.header.frame_id), "a");
  EXPECT_EQ(View(t.child_frame_id), "b");
  EXPECT_EQ(t.header.stamp.sec, 1);
  EXPECT_EQ(t.header.stamp.nanosec, 500'000'000u);
  EXPECT_DOUBLE_EQ(t.transform.translation.x, 0.12);
  EXPECT_DOUBLE_EQ(t.transform.translation.z, -0.005);
  EXPECT_EQ(t.transform.rotation.w, 1);

  cv::Matx44d scaled = cv::Matx44d::eye();
  scaled(0, 0) = 2;
  EXPECT_FALSE(MakeTfMessage({{"a", "b", scaled}}, 0, &out, &error));
  EXPECT_NE(error.find("a → b is not rigid"), std::string::npos) << error;
  EXPECT_FALSE(MakeTfMessage({{"a", "a", cv::Matx44d::eye()}}, 0, &out, &error));
  EXPECT_NE(error.find("distinct"), std::string::npos) << error;
}

TEST(DdsRosDefinitions, ConcatenatedAsRosbag2WritesThem) {
  const std::string info = RosMessageDefinition("sensor_msgs/msg/CameraInfo");
  EXPECT_EQ(info.rfind("std_msgs/Header header\n", 0), 0u) << info;
  const std::string separator = std::string(80, '=') + "\n";
  for (const char* used :
       {"std_msgs/Header", "builtin_interfaces/Time", "sensor_msgs/RegionOfInterest"}) {
    const std::string block = separator + "MSG: " + used + "\n";
    const std::size_t at = info.find(block);
    EXPECT_NE(at, std::string::npos) << used;
    EXPECT_EQ(info.find(block, at + 1), std::string::npos) << used << " twice";
  }
  const std::string tf = RosMessageDefinition("tf2_msgs/msg/TFMessage");
  for (const char* used :
       {"geometry_msgs/TransformStamped", "std_msgs/Header", "builtin_interfaces/Time",
        "geometry_msgs/Transform", "geometry_msgs/Vector3", "geometry_msgs/Quaternion"}) {
    EXPECT_NE(tf.find(std::string("MSG: ") + used + "\n"), std::string::npos) << used;
  }
  EXPECT_EQ(RosMessageDefinition("sensor_msgs/msg/Imu"), "");
  EXPECT_EQ(RosMessageDefinition("Image"), "");
}

// --- Topics and limits --------------------------------------------------------

TEST(DdsTopics, NamesTypesAndQosFollowTheDesign) {
  EXPECT_EQ(StatusTopic("st1").name, "craftscan/st1/status");
  EXPECT_TRUE(StatusTopic("st1").qos.transient_local);
  EXPECT_EQ(StatusTopic("st1").qos.history_depth, 1);
  EXPECT_FALSE(CommandTopic("st1").qos.transient_local);
  EXPECT_TRUE(CommandTopic("st1").qos.reliable);
  EXPECT_EQ(ReplyTopic("st1").name, "craftscan/st1/reply");
  EXPECT_TRUE(ReplyTopic("st1").qos.transient_local);
  EXPECT_EQ(ProgressTopic("st1").qos.history_depth, 16);
  EXPECT_EQ(CaptureTopic("st1").qos.history_depth, 1);
  EXPECT_EQ(DisparityTopic("st1").name, "craftscan/st1/disparity");
  EXPECT_EQ(CloudTopic("st1").qos.history_depth, 2);
  EXPECT_EQ(RosCloudTopic("st1").name, "rt/craftscan/st1/cloud");
  EXPECT_TRUE(RosCloudTopic("st1").qos.xcdr1_only);
  EXPECT_EQ(RosImageTopic("st1", Side::kRight).name, "rt/craftscan/st1/right/image_raw");
  EXPECT_EQ(RosCameraInfoTopic("st1", Side::kLeft).name, "rt/craftscan/st1/left/camera_info");
  EXPECT_TRUE(RosCameraInfoTopic("st1", Side::kLeft).qos.transient_local);
  EXPECT_EQ(RosDisparityTopic("st1").name, "rt/craftscan/st1/disparity");
  // One transform tree per domain, as ROS has it; frames carry the station.
  EXPECT_EQ(RosTfTopic().name, "rt/tf");
  EXPECT_FALSE(RosTfTopic().qos.transient_local);
  EXPECT_EQ(RosTfStaticTopic().name, "rt/tf_static");
  EXPECT_TRUE(RosTfStaticTopic().qos.transient_local);
  EXPECT_TRUE(RosTfStaticTopic().qos.xcdr1_only);
  for (const TopicQos& qos : {StatusTopic("a").qos, CaptureTopic("a").qos, CloudTopic("a").qos}) {
    EXPECT_TRUE(qos.reliable);  // best-effort loses multi-MB samples
    EXPECT_FALSE(qos.xcdr1_only);
  }

  EXPECT_STREQ(MessageTraits<ros::PointCloud2>::type_name(),
               "sensor_msgs::msg::dds_::PointCloud2_");
  EXPECT_STREQ(MessageTraits<ros::Image>::type_name(), "sensor_msgs::msg::dds_::Image_");
  EXPECT_STREQ(MessageTraits<ros::CameraInfo>::type_name(), "sensor_msgs::msg::dds_::CameraInfo_");
  EXPECT_STREQ(MessageTraits<ros::DisparityImage>::type_name(),
               "stereo_msgs::msg::dds_::DisparityImage_");
  EXPECT_STREQ(MessageTraits<ros::TFMessage>::type_name(), "tf2_msgs::msg::dds_::TFMessage_");
  EXPECT_STREQ(MessageTraits<msg::StationStatus>::type_name(), "craftscan::msg::StationStatus");

  std::string why;
  EXPECT_TRUE(IsValidStationId("station_01", &why)) << why;
  EXPECT_FALSE(IsValidStationId("", &why));
  EXPECT_FALSE(IsValidStationId("1st", &why));
  EXPECT_NE(why.find("must start with a letter"), std::string::npos) << why;
  EXPECT_FALSE(IsValidStationId("a/b", &why));
  EXPECT_FALSE(IsValidStationId(std::string(65, 'a'), &why));
  TopicQos qos;
  qos.history_depth = 0;
  EXPECT_FALSE(qos.IsValid(&why));
  EXPECT_NE(why.find("history_depth"), std::string::npos) << why;
}

TEST(DdsMessages, CommandLimits) {
  Outgoing<msg::Command> command;
  command.msg().request_id = command.Keep("r1");
  command.msg().client = command.Keep("console");
  command.msg().verb = command.Keep("scan");
  const std::string arguments(kMaxCommandArgumentsBytes, ' ');
  command.msg().arguments = command.Keep(arguments);
  std::string why;
  EXPECT_TRUE(IsValidCommand(command.msg(), &why)) << why;
  const std::string too_long(kMaxCommandArgumentsBytes + 1, ' ');
  command.msg().arguments = command.Keep(too_long);
  EXPECT_FALSE(IsValidCommand(command.msg(), &why));
  EXPECT_NE(why.find("arguments is 65537 bytes, more than the 65536 allowed"), std::string::npos)
      << why;
  command.msg().arguments = nullptr;
  command.msg().verb = nullptr;
  EXPECT_FALSE(IsValidCommand(command.msg(), &why));
  EXPECT_NE(why.find("verb is empty"), std::string::npos) << why;
}

}  // namespace
}  // namespace craftscan::dds
