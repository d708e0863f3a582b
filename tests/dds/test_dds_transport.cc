// Real Cyclone DDS over loopback with the shipped systemd/cyclonedds.xml
// (plus LoopbackOnlyConfigXml): large samples cross to another process
// (craftscan_dds_peer echoes them back) bit-exactly, a ROS-style subscriber
// decodes the ROS messages, the status topic serves late joiners, and takes
// time out instead of hanging.
//
// No cross-talk with tests running in parallel: each process picks a random
// domain id, traffic stays on loopback, and every test uses its own station.
#include <gtest/gtest.h>

#include <dds/dds.h>
#include <dds/ddsi/ddsi_serdata.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"
#include "dds_test_util.h"
#include "mat_util.h"
#include "process_util.h"
#include "test_paths.h"

namespace craftscan::dds {
namespace {

using std::chrono::milliseconds;
constexpr milliseconds kTimeout{20000};  // generous: the machine is shared

using ::craftscan::testing::BitExact;
using ::craftscan::testing::ChildProcess;
using ::craftscan::testing::MakeTestParticipant;
using ::craftscan::testing::ProcessDomainId;
using ::craftscan::testing::TestDdsConfig;
using ::craftscan::testing::UniqueStation;

// craftscan_dds_peer in echo mode, killed if still running when destroyed.
class Peer {
 public:
  Peer(const std::string& station, const std::string& mode, int count) {
    const std::vector<std::string> args = {::craftscan::testing::DdsPeerPath(),
                                           "--domain",
                                           std::to_string(ProcessDomainId()),
                                           "--config",
                                           TestDdsConfig(),
                                           "--station",
                                           station,
                                           "--mode",
                                           mode,
                                           "--count",
                                           std::to_string(count),
                                           "--timeout-ms",
                                           std::to_string(kTimeout.count())};
    ::craftscan::testing::Spawn(args, {}, &child_);
  }
  bool started() const { return child_.started(); }

  // The exit code, or −1 if it did not exit within `timeout` (then killed).
  int Wait(milliseconds timeout) { return child_.Wait(timeout); }

 private:
  ChildProcess child_;
};

// A writer on topic(station) and a reader on topic(station + "_echo"), the
// topic the peer writes its echoes to.
template <typename Msg>
struct EchoLoop {
  std::unique_ptr<Writer<Msg>> writer;
  std::unique_ptr<Reader<Msg>> echo;
};

template <typename Msg>
::testing::AssertionResult MakeEchoLoop(const std::shared_ptr<Participant>& participant,
                                        TopicSpec<Msg> (*topic)(std::string_view),
                                        const std::string& station, EchoLoop<Msg>* loop) {
  if (!participant) return ::testing::AssertionFailure() << "no participant";
  std::string error;
  loop->writer = Writer<Msg>::Create(participant, topic(station), &error);
  if (loop->writer) loop->echo = Reader<Msg>::Create(participant, topic(station + "_echo"), &error);
  if (!loop->writer || !loop->echo) return ::testing::AssertionFailure() << error;
  return ::testing::AssertionSuccess();
}

TEST(DdsTransport, StereoCapturesCrossToAnotherProcessBitExact) {
  const std::string station = UniqueStation("t");
  EchoLoop<msg::StereoCapture> loop;
  ASSERT_TRUE(MakeEchoLoop(MakeTestParticipant(), &CaptureTopic, station, &loop));
  Peer peer(station, "capture", 2);
  ASSERT_TRUE(peer.started());
  ASSERT_TRUE(loop.writer->WaitForReaders(1, kTimeout));
  std::string error;

  cv::RNG rng(1234);
  for (int type : {CV_8UC1, CV_8UC3}) {
    cv::Mat left(1024, 1280, type), right(1024, 1280, type);
    rng.fill(left, cv::RNG::UNIFORM, 0, 256);
    rng.fill(right, cv::RNG::UNIFORM, 0, 256);
    StereoCaptureMeta meta;
    meta.session = "20240611-101500-carved_egg";
    meta.view_index = type == CV_8UC1 ? 0 : 17;
    meta.angle_deg = 22.5;
    meta.exposure_us = 8000.5;
    meta.gain_db = 1.25;
    meta.left_stamp_ns = 1'718'100'000'000'000'001;
    meta.right_stamp_ns = 1'718'100'000'000'000'002;
    meta.left_frame_id = station + "_left_optical";
    meta.right_frame_id = station + "_right_optical";
    Outgoing<msg::StereoCapture> out;
    ASSERT_TRUE(MakeStereoCapture(left, right, meta, &out, &error)) << error;
    ASSERT_TRUE(loop.writer->Write(out.msg(), &error)) << error;

    Sample<msg::StereoCapture> got;
    ASSERT_EQ(loop.echo->Take(kTimeout, &got, &error), TakeStatus::kOk) << error;
    cv::Mat got_left, got_right;
    ASSERT_TRUE(StereoCaptureToMats(*got, &got_left, &got_right, &error)) << error;
    EXPECT_TRUE(BitExact(got_left, left));
    EXPECT_TRUE(BitExact(got_right, right));
    EXPECT_EQ(View(got->encoding), type == CV_8UC1 ? "mono8" : "bgr8");
    EXPECT_EQ(View(got->session), meta.session);
    EXPECT_EQ(got->view_index, meta.view_index);
    EXPECT_EQ(got->angle_deg, meta.angle_deg);
    EXPECT_EQ(got->exposure_us, meta.exposure_us);
    EXPECT_EQ(got->gain_db, meta.gain_db);
    EXPECT_EQ(got->left_stamp_ns, meta.left_stamp_ns);
    EXPECT_EQ(got->right_stamp_ns, meta.right_stamp_ns);
    EXPECT_EQ(View(got->right_frame_id), meta.right_frame_id);
  }
  EXPECT_EQ(peer.Wait(kTimeout), 0);
}

TEST(DdsTransport, MillionPointCloudCrossesToAnotherProcessBitExact) {
  const std::string station = UniqueStation("t");
  EchoLoop<msg::PointCloud> loop;
  ASSERT_TRUE(MakeEchoLoop(MakeTestParticipant(), &CloudTopic, station, &loop));
  Peer peer(station, "cloud", 1);
  ASSERT_TRUE(peer.started());

  constexpr int kPoints = 1'000'000;
  PointCloud cloud;
  cloud.points_mm.resize(kPoints);
  cloud.normals.resize(kPoints);
  cloud.colors_rgb.resize(kPoints);
  std::mt19937 random(99);
  std::uniform_real_distribution<float> coordinate(-250.f, 250.f);
  for (int i = 0; i < kPoints; ++i) {
    cloud.points_mm[i] = cv::Vec3f(coordinate(random), coordinate(random), coordinate(random));
    cloud.normals[i] = cv::normalize(cv::Vec3f(coordinate(random), coordinate(random), 1.f));
    const uint32_t bits = static_cast<uint32_t>(random());
    cloud.colors_rgb[i] = cv::Vec3b(bits & 255, (bits >> 8) & 255, (bits >> 16) & 255);
  }
  // Bit patterns that a lossy path would change.
  cloud.points_mm[10][0] = std::numeric_limits<float>::quiet_NaN();
  cloud.points_mm[11][1] = -0.0f;
  cloud.points_mm[12][2] = std::numeric_limits<float>::infinity();
  cloud.points_mm[13][0] = std::numeric_limits<float>::denorm_min();

  CloudMeta meta;
  meta.session = "20240611-101500-carved_egg";
  meta.view_index = -1;
  meta.kind = "fused";
  meta.world_from_view = cv::Matx44d(1, 0, 0, 0.5, 0, 1, 0, -2, 0, 0, 1, 3.25, 0, 0, 0, 1);
  meta.stamp_ns = 1'718'100'000'123'456'789;
  meta.frame_id = station + "_world";
  Outgoing<msg::PointCloud> out;
  std::string error;
  ASSERT_TRUE(MakeCloud(cloud, meta, &out, &error)) << error;
  ASSERT_TRUE(loop.writer->WaitForReaders(1, kTimeout));
  ASSERT_TRUE(loop.writer->Write(out.msg(), &error)) << error;

  Sample<msg::PointCloud> got;
  ASSERT_EQ(loop.echo->Take(kTimeout, &got, &error), TakeStatus::kOk) << error;
  PointCloud back;
  CloudMeta back_meta;
  ASSERT_TRUE(CloudFromMessage(*got, &back, &back_meta, &error)) << error;
  ASSERT_EQ(back.size(), static_cast<std::size_t>(kPoints));
  ASSERT_EQ(back.normals.size(), static_cast<std::size_t>(kPoints));
  ASSERT_EQ(back.colors_rgb.size(), static_cast<std::size_t>(kPoints));
  EXPECT_EQ(0, std::memcmp(back.points_mm.data(), cloud.points_mm.data(), kPoints * 12));
  EXPECT_EQ(0, std::memcmp(back.normals.data(), cloud.normals.data(), kPoints * 12));
  EXPECT_EQ(0, std::memcmp(back.colors_rgb.data(), cloud.colors_rgb.data(), kPoints * 3));
  EXPECT_EQ(back_meta.session, meta.session);
  EXPECT_EQ(back_meta.view_index, -1);
  EXPECT_EQ(back_meta.kind, "fused");
  EXPECT_EQ(back_meta.world_from_view, meta.world_from_view);
  EXPECT_EQ(back_meta.stamp_ns, meta.stamp_ns);
  EXPECT_EQ(back_meta.frame_id, meta.frame_id);
  EXPECT_EQ(peer.Wait(kTimeout), 0);
}

TEST(DdsTransport, LateJoinerGetsTheLastStatus) {
  auto participant = MakeTestParticipant();
  ASSERT_TRUE(participant);
  const std::string station = UniqueStation("t");
  std::string error;
  auto writer = Writer<msg::StationStatus>::Create(participant, StatusTopic(station), &error);
  ASSERT_TRUE(writer) << error;

  Outgoing<msg::StationStatus> starting;
  starting.msg().station = starting.Keep(station);
  starting.msg().state = starting.Keep("starting");
  ASSERT_TRUE(writer->Write(starting.msg(), &error)) << error;

  Outgoing<msg::StationStatus> idle;
  msg::StationStatus& status = idle.msg();
  status.station = idle.Keep(station);
  status.state = idle.Keep("idle");
  std::vector<msg::DeviceStatus> devices(2);
  devices[0] = {idle.Keep("left"), idle.Keep("camera"), idle.Keep("streaming"), idle.Keep("")};
  devices[1] = {idle.Keep("turntable"), idle.Keep("turntable"), idle.Keep("fault"),
                idle.Keep("ALARM:1 hard limit")};
  ASSERT_TRUE(Borrow(&status.devices, devices.data(), devices.size()));
  status.job_id = idle.Keep("job-7");
  status.job_verb = idle.Keep("scan");
  status.job_state = idle.Keep("done");
  status.progress = 1.0;
  status.stamp_ns = 123456789;
  status.calibration_id = idle.Keep("calib-2024-06-01");
  ASSERT_TRUE(writer->Write(status, &error)) << error;

  // Only now does anyone subscribe: the peer process, a late joiner.
  auto echo =
      Reader<msg::StationStatus>::Create(participant, StatusTopic(station + "_echo"), &error);
  ASSERT_TRUE(echo) << error;
  Peer peer(station, "status", 1);
  ASSERT_TRUE(peer.started());

  Sample<msg::StationStatus> got;
  ASSERT_EQ(echo->Take(kTimeout, &got, &error), TakeStatus::kOk) << error;
  EXPECT_EQ(View(got->state), "idle");  // the last status, not the first
  ASSERT_EQ(got->devices._length, 2u);
  EXPECT_EQ(View(got->devices._buffer[1].name), "turntable");
  EXPECT_EQ(View(got->devices._buffer[1].message), "ALARM:1 hard limit");
  EXPECT_EQ(View(got->devices._buffer[0].state), "streaming");
  EXPECT_EQ(View(got->job_id), "job-7");
  EXPECT_EQ(got->progress, 1.0);
  EXPECT_EQ(got->stamp_ns, 123456789);
  EXPECT_EQ(View(got->calibration_id), "calib-2024-06-01");
  EXPECT_EQ(View(got->last_error), "");  // null on the writer's side
  EXPECT_EQ(peer.Wait(kTimeout), 0);
}

// --- ROS 2 compatibility ----------------------------------------------------

// Reads XCDR1 (plain CDR) little-endian data as rmw_cyclonedds would.
class CdrReader {
 public:
  CdrReader(const uint8_t* data, std::size_t size) : data_(data), size_(size) {}
  bool ok() const { return ok_; }
  uint32_t U32() {
    uint32_t value = 0;
    Read(&value, 4, 4);
    return value;
  }
  int32_t I32() {
    int32_t value = 0;
    Read(&value, 4, 4);
    return value;
  }
  uint8_t U8() {
    uint8_t value = 0;
    Read(&value, 1, 1);
    return value;
  }
  std::string String() {
    const uint32_t length = U32();  // including the NUL
    if (length == 0 || pos_ + length > size_) {
      ok_ = false;
      return "";
    }
    std::string text(reinterpret_cast<const char*>(data_ + pos_), length - 1);
    pos_ += length;
    return text;
  }
  std::vector<uint8_t> Bytes() {
    const uint32_t length = U32();
    std::vector<uint8_t> bytes(length);
    Read(bytes.data(), length, 1);
    return bytes;
  }
  std::size_t remaining() const { return size_ - pos_; }

 private:
  void Read(void* out, std::size_t bytes, std::size_t align) {
    pos_ = (pos_ + align - 1) / align * align;
    if (pos_ + bytes > size_) {
      ok_ = false;
      return;
    }
    std::memcpy(out, data_ + pos_, bytes);
    pos_ += bytes;
  }
  const uint8_t* data_;
  std::size_t size_;
  std::size_t pos_ = 0;
  bool ok_ = true;
};

// A raw Cyclone reader that takes serialised samples, as a subscriber
// written against the ROS type names would see them.
class RawReader {
 public:
  RawReader(const Participant& participant, const dds_topic_descriptor_t* descriptor,
            const std::string& topic_name) {
    topic_ =
        dds_create_topic(participant.handle(), descriptor, topic_name.c_str(), nullptr, nullptr);
    dds_qos_t* qos = dds_create_qos();
    dds_qset_reliability(qos, DDS_RELIABILITY_RELIABLE, DDS_SECS(1));
    if (topic_ > 0) reader_ = dds_create_reader(participant.handle(), topic_, qos, nullptr);
    dds_delete_qos(qos);
  }
  ~RawReader() {
    if (reader_ > 0) dds_delete(reader_);
    if (topic_ > 0) dds_delete(topic_);
  }
  bool ok() const { return topic_ > 0 && reader_ > 0; }
  std::string type_name() const {
    char name[128] = "";
    return dds_get_type_name(topic_, name, sizeof name) >= 0 ? name : "";
  }

  // The serialised sample (4-byte encapsulation header + payload), or empty.
  std::vector<uint8_t> TakeSerialized(milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline) {
      ddsi_serdata* serdata = nullptr;
      dds_sample_info_t info;
      if (dds_takecdr(reader_, &serdata, 1, &info, DDS_ANY_STATE) == 1) {
        std::vector<uint8_t> bytes(ddsi_serdata_size(serdata));
        ddsi_serdata_to_ser(serdata, 0, bytes.size(), bytes.data());
        ddsi_serdata_unref(serdata);
        if (info.valid_data) return bytes;
      }
      std::this_thread::sleep_for(milliseconds(5));
    }
    return {};
  }

 private:
  dds_entity_t topic_ = 0, reader_ = 0;
};

TEST(DdsRos, ImageIsPlainCdrInRosLayout) {
  auto participant = MakeTestParticipant();
  ASSERT_TRUE(participant);
  const std::string station = UniqueStation("t");
  const TopicSpec<ros::Image> topic = RosImageTopic(station, Side::kLeft);
  RawReader raw(*participant, &sensor_msgs_msg_dds__Image__desc, topic.name);
  ASSERT_TRUE(raw.ok());
  EXPECT_EQ(raw.type_name(), "sensor_msgs::msg::dds_::Image_");

  std::string error;
  auto writer = Writer<ros::Image>::Create(participant, topic, &error);
  ASSERT_TRUE(writer) << error;
  ASSERT_TRUE(writer->WaitForReaders(1, kTimeout));
  cv::Mat image(3, 5, CV_8UC3);
  cv::randu(image, 0, 255);
  Outgoing<ros::Image> out;
  ASSERT_TRUE(MakeImage(image, 1'500'000'000'250'000'000, "cam_l", &out, &error)) << error;
  ASSERT_TRUE(writer->Write(out.msg(), &error)) << error;

  const std::vector<uint8_t> bytes = raw.TakeSerialized(kTimeout);
  ASSERT_GE(bytes.size(), 4u);
  EXPECT_EQ(bytes[0], 0x00);  // CDR_LE: XCDR1, little endian (ROS 2)
  EXPECT_EQ(bytes[1], 0x01);
  CdrReader cdr(bytes.data() + 4, bytes.size() - 4);
  EXPECT_EQ(cdr.I32(), 1'500'000'000);  // header.stamp.sec
  EXPECT_EQ(cdr.U32(), 250'000'000u);   // header.stamp.nanosec
  EXPECT_EQ(cdr.String(), "cam_l");     // header.frame_id
  EXPECT_EQ(cdr.U32(), 3u);             // height
  EXPECT_EQ(cdr.U32(), 5u);             // width
  EXPECT_EQ(cdr.String(), "bgr8");      // encoding
  EXPECT_EQ(cdr.U8(), 0);               // is_bigendian
  EXPECT_EQ(cdr.U32(), 15u);            // step
  const std::vector<uint8_t> data = cdr.Bytes();
  EXPECT_TRUE(cdr.ok());
  ASSERT_EQ(data.size(), 45u);
  EXPECT_EQ(0, std::memcmp(data.data(), image.data, 45));
  EXPECT_LT(cdr.remaining(), 4u);  // nothing but padding follows
}

// The daemon may write a reply before its writer has discovered the
// client's reader (each side discovers the other on its own): the reply must
// still arrive once the reader matches.
TEST(DdsTransport, AReplyWrittenBeforeTheReaderMatchedStillReachesIt) {
  auto participant = MakeTestParticipant();
  ASSERT_TRUE(participant);
  const TopicSpec<msg::Reply> topic = ReplyTopic(UniqueStation("t"));
  std::string error;
  auto writer = Writer<msg::Reply>::Create(participant, topic, &error);
  ASSERT_TRUE(writer) << error;
  Outgoing<msg::Reply> reply;
  reply.msg().request_id = reply.Keep("early-1");
  reply.msg().code_name = reply.Keep("ok");
  ASSERT_TRUE(writer->Write(reply.msg(), &error)) << error;

  auto reader = Reader<msg::Reply>::Create(participant, topic, &error);
  ASSERT_TRUE(reader) << error;
  Sample<msg::Reply> sample;
  ASSERT_EQ(reader->Take(kTimeout, &sample, &error), TakeStatus::kOk) << error;
  EXPECT_EQ(View(sample->request_id), "early-1");
  EXPECT_EQ(View(sample->code_name), "ok");
}

// craftscan's own types are @appendable: XCDR2 with a delimiter header, so
// fields can be appended later without breaking older peers.
TEST(DdsTransport, OwnTypesAreAppendableXcdr2) {
  auto participant = MakeTestParticipant();
  ASSERT_TRUE(participant);
  const TopicSpec<msg::Reply> topic = ReplyTopic(UniqueStation("t"));
  RawReader raw(*participant, &craftscan_msg_Reply_desc, topic.name);
  ASSERT_TRUE(raw.ok());
  std::string error;
  auto writer = Writer<msg::Reply>::Create(participant, topic, &error);
  ASSERT_TRUE(writer) << error;
  ASSERT_TRUE(writer->WaitForReaders(1, kTimeout));
  Outgoing<msg::Reply> reply;
  reply.msg().request_id = reply.Keep("r1");
  reply.msg().code_name = reply.Keep("ok");
  ASSERT_TRUE(writer->Write(reply.msg(), &error)) << error;
  const std::vector<uint8_t> bytes = raw.TakeSerialized(kTimeout);
  ASSERT_GE(bytes.size(), 8u);
  EXPECT_EQ(bytes[0], 0x00);
  EXPECT_EQ(bytes[1], 0x09);  // D_CDR2_LE: delimited XCDR2, little endian
  uint32_t delimiter;
  std::memcpy(&delimiter, bytes.data() + 4, 4);
  EXPECT_LE(delimiter, bytes.size() - 8);  // the DHEADER: payload bytes that follow
}

TEST(DdsRos, RosSubscriberDecodesCloudCameraInfoAndDisparity) {
  auto publisher = MakeTestParticipant();
  ASSERT_TRUE(publisher);
  // A second participant in the same domain stands for the ROS node.
  ParticipantOptions join;
  join.domain_id = ProcessDomainId();
  std::string error;
  auto subscriber = Participant::Create(join, &error);
  ASSERT_TRUE(subscriber) << error;
  const std::string station = UniqueStation("t");

  // CameraInfo first, before anyone subscribes: transient-local.
  StereoCalibration calibration;
  calibration.image_size = cv::Size(1280, 1024);
  calibration.left.camera_matrix = cv::Matx33d(1400, 0, 640, 0, 1400, 512, 0, 0, 1);
  calibration.right.camera_matrix = calibration.left.camera_matrix;
  calibration.T = cv::Vec3d(-100, 0, 0);
  ASSERT_TRUE(ComputeRectification({}, &calibration, &error)) << error;
  auto info_writer =
      Writer<ros::CameraInfo>::Create(publisher, RosCameraInfoTopic(station, Side::kRight), &error);
  ASSERT_TRUE(info_writer) << error;
  Outgoing<ros::CameraInfo> info;
  ASSERT_TRUE(MakeCameraInfo(calibration, Side::kRight, 5, "right_optical", &info, &error))
      << error;
  ASSERT_TRUE(info_writer->Write(info.msg(), &error)) << error;

  auto info_reader = Reader<ros::CameraInfo>::Create(
      subscriber, RosCameraInfoTopic(station, Side::kRight), &error);
  ASSERT_TRUE(info_reader) << error;
  Sample<ros::CameraInfo> got_info;
  ASSERT_EQ(info_reader->Take(kTimeout, &got_info, &error), TakeStatus::kOk) << error;
  EXPECT_EQ(got_info->width, 1280u);
  EXPECT_EQ(View(got_info->distortion_model), "plumb_bob");
  EXPECT_EQ(got_info->d._length, 5u);
  EXPECT_EQ(got_info->k[0], 1400.0);
  EXPECT_NEAR(got_info->p[3], -calibration.P2(0, 0) * 0.1, 1e-9);  // −f·B, B = 0.1 m
  EXPECT_EQ(View(got_info->header.frame_id), "right_optical");

  // PointCloud2.
  auto cloud_reader = Reader<ros::PointCloud2>::Create(subscriber, RosCloudTopic(station), &error);
  ASSERT_TRUE(cloud_reader) << error;
  auto cloud_writer = Writer<ros::PointCloud2>::Create(publisher, RosCloudTopic(station), &error);
  ASSERT_TRUE(cloud_writer) << error;
  PointCloud cloud;
  for (int i = 0; i < 1000; ++i) {
    cloud.points_mm.emplace_back(i * 0.5f, -i * 0.25f, 300.f + i);
    cloud.colors_rgb.emplace_back(i % 256, (3 * i) % 256, 255 - i % 256);
    cloud.normals.emplace_back(0.f, 0.f, 1.f);
  }
  Outgoing<ros::PointCloud2> cloud_out;
  ASSERT_TRUE(MakePointCloud2(cloud, 2'000'000'001, "world", &cloud_out, &error)) << error;
  ASSERT_TRUE(cloud_writer->WaitForReaders(1, kTimeout));
  ASSERT_TRUE(cloud_writer->Write(cloud_out.msg(), &error)) << error;
  Sample<ros::PointCloud2> got_cloud;
  ASSERT_EQ(cloud_reader->Take(kTimeout, &got_cloud, &error), TakeStatus::kOk) << error;
  const ros::PointCloud2& m = *got_cloud;
  EXPECT_EQ(m.header.stamp.sec, 2);
  EXPECT_EQ(m.header.stamp.nanosec, 1u);
  EXPECT_EQ(m.height, 1u);
  EXPECT_EQ(m.width, 1000u);
  EXPECT_FALSE(m.is_bigendian);
  EXPECT_EQ(m.point_step, 28u);
  EXPECT_EQ(m.row_step, 28000u);
  ASSERT_EQ(m.data._length, 28000u);
  const char* expected_names[] = {"x", "y", "z", "rgb", "normal_x", "normal_y", "normal_z"};
  ASSERT_EQ(m.fields._length, 7u);
  for (uint32_t f = 0; f < 7; ++f) {
    EXPECT_EQ(View(m.fields._buffer[f].name), expected_names[f]);
    EXPECT_EQ(m.fields._buffer[f].offset, 4 * f);
    EXPECT_EQ(m.fields._buffer[f].datatype, 7);  // FLOAT32
    EXPECT_EQ(m.fields._buffer[f].count, 1u);
  }
  for (int i : {0, 1, 500, 999}) {
    const uint8_t* point = m.data._buffer + i * m.point_step;
    float xyz[3], normal[3];
    uint32_t rgb;
    std::memcpy(xyz, point, 12);
    std::memcpy(&rgb, point + 12, 4);
    std::memcpy(normal, point + 16, 12);
    EXPECT_FLOAT_EQ(xyz[0], cloud.points_mm[i][0] / 1000);
    EXPECT_FLOAT_EQ(xyz[2], cloud.points_mm[i][2] / 1000);
    EXPECT_EQ((rgb >> 16) & 255, cloud.colors_rgb[i][0]);
    EXPECT_EQ((rgb >> 8) & 255, cloud.colors_rgb[i][1]);
    EXPECT_EQ(rgb & 255, cloud.colors_rgb[i][2]);
    EXPECT_EQ(normal[2], 1.0f);
  }

  // DisparityImage.
  auto disparity_reader =
      Reader<ros::DisparityImage>::Create(subscriber, RosDisparityTopic(station), &error);
  ASSERT_TRUE(disparity_reader) << error;
  auto disparity_writer =
      Writer<ros::DisparityImage>::Create(publisher, RosDisparityTopic(station), &error);
  ASSERT_TRUE(disparity_writer) << error;
  cv::Mat disparity(24, 32, CV_32FC1, cv::Scalar(12.5f));
  disparity.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  DisparityMeta meta;
  meta.f_px = 1400;
  meta.baseline_mm = 100;
  meta.cx_offset_px = 2;
  meta.min_disparity = 0;
  meta.max_disparity = 64;
  meta.frame_id = "left_rect";
  Outgoing<ros::DisparityImage> disparity_out;
  ASSERT_TRUE(MakeDisparityImage(disparity, meta, &disparity_out, &error)) << error;
  ASSERT_TRUE(disparity_writer->WaitForReaders(1, kTimeout));
  ASSERT_TRUE(disparity_writer->Write(disparity_out.msg(), &error)) << error;
  Sample<ros::DisparityImage> got_disparity;
  ASSERT_EQ(disparity_reader->Take(kTimeout, &got_disparity, &error), TakeStatus::kOk) << error;
  EXPECT_EQ(View(got_disparity->image.encoding), "32FC1");
  EXPECT_EQ(got_disparity->image.step, 128u);
  EXPECT_EQ(got_disparity->image.is_bigendian, 0);
  EXPECT_FLOAT_EQ(got_disparity->t, 0.1f);
  EXPECT_EQ(got_disparity->f, 1400.0f);
  EXPECT_EQ(got_disparity->min_disparity, -2.0f);
  cv::Mat values;
  ASSERT_TRUE(ImageToMat(got_disparity->image, &values, &error)) << error;
  EXPECT_EQ(values.at<float>(5, 5), 10.5f);
  EXPECT_LT(values.at<float>(0, 0), got_disparity->min_disparity);
  EXPECT_EQ(View(got_disparity->header.frame_id), "left_rect");
  // Destruction in reverse order: the subscriber (which joined the
  // publisher's domain) goes before the publisher.
}

// --- Timeouts and errors ------------------------------------------------------

TEST(DdsTransport, TakeTimesOutWhenNothingIsPublished) {
  auto participant = MakeTestParticipant();
  ASSERT_TRUE(participant);
  std::string error;
  auto reader = Reader<msg::Reply>::Create(participant, ReplyTopic(UniqueStation("t")), &error);
  ASSERT_TRUE(reader) << error;
  Sample<msg::Reply> sample;
  const auto start = std::chrono::steady_clock::now();
  EXPECT_EQ(reader->Take(milliseconds(300), &sample, &error), TakeStatus::kTimeout);
  // It waited (not an immediate return), and returned (not a hang: the test
  // would not get here).
  EXPECT_GE(std::chrono::steady_clock::now() - start, milliseconds(290));
  EXPECT_EQ(reader->Take(milliseconds(0), &sample, &error), TakeStatus::kTimeout);
  EXPECT_EQ(reader->MatchedWriters(), 0);
}

TEST(DdsTransport, BadOptionsGiveClearErrors) {
  std::string error;
  ParticipantOptions options;
  options.domain_id = 231;
  EXPECT_EQ(Participant::Create(options, &error), nullptr);
  EXPECT_NE(error.find("domain_id 231 is above 230"), std::string::npos) << error;

  options.domain_id = ProcessDomainId();
  options.config = ConfigFileUri("/nonexistent/cyclonedds.xml") + "," + LoopbackOnlyConfigXml();
  EXPECT_EQ(Participant::Create(options, &error), nullptr);
  EXPECT_NE(error.find("'/nonexistent/cyclonedds.xml' does not exist"), std::string::npos) << error;

  options.config = TestDdsConfig();
  auto first = Participant::Create(options, &error);
  ASSERT_TRUE(first) << error;
  EXPECT_EQ(Participant::Create(options, &error), nullptr);
  EXPECT_NE(error.find("already exists in this process"), std::string::npos) << error;

  auto writer = Writer<msg::Command>::Create(first, CommandTopic("bad station"), &error);
  EXPECT_EQ(writer, nullptr);
  EXPECT_NE(error.find("character other than"), std::string::npos) << error;
  TopicSpec<msg::Command> bad_qos = CommandTopic("ok");
  bad_qos.qos.history_depth = 0;
  EXPECT_EQ(Writer<msg::Command>::Create(first, bad_qos, &error), nullptr);
  EXPECT_NE(error.find("history_depth"), std::string::npos) << error;
  first.reset();

  options.config =
      "<CycloneDDS><Domain><General><NoSuchSetting>1</NoSuchSetting></General>"
      "</Domain></CycloneDDS>";
  EXPECT_EQ(Participant::Create(options, &error), nullptr);
  EXPECT_NE(error.find("rejected the configuration"), std::string::npos) << error;
}

}  // namespace
}  // namespace craftscan::dds
