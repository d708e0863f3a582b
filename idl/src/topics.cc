// Topic names and QoS per station (DESIGN.md's DDS table).
#include "craftscan/dds/topics.h"

#include <string>

namespace craftscan::dds {
namespace {

constexpr int32_t kControlDepth = 16;  // commands, replies, progress: a burst is not lost
constexpr int32_t kTfDepth = 100;      // as tf2_ros's TransformListener

std::string Name(std::string_view station, std::string_view leaf) {
  std::string name = "craftscan/";
  name.append(station).append("/").append(leaf);
  return name;
}

std::string RosName(std::string_view station, std::string_view leaf) {
  return "rt/" + Name(station, leaf);
}

TopicQos Qos(int32_t depth, bool transient_local) {
  TopicQos qos;
  qos.reliable = true;
  qos.history_depth = depth;
  qos.transient_local = transient_local;
  return qos;
}

TopicQos RosQos(bool transient_local) {
  TopicQos qos = Qos(1, transient_local);
  qos.xcdr1_only = true;
  return qos;
}

}  // namespace

bool TopicQos::IsValid(std::string* why) const {
  if (history_depth < 1) {
    if (why) *why = "history_depth must be ≥ 1, got " + std::to_string(history_depth);
    return false;
  }
  if (max_blocking_ms < 0) {
    if (why) *why = "max_blocking_ms must be ≥ 0, got " + std::to_string(max_blocking_ms);
    return false;
  }
  if (liveliness_lease_ms < 0) {
    if (why) *why = "liveliness_lease_ms must be ≥ 0, got " + std::to_string(liveliness_lease_ms);
    return false;
  }
  if (partition.size() > 64) {
    if (why) *why = "partition longer than 64 characters";
    return false;
  }
  return true;
}

std::string_view ToString(Side side) { return side == Side::kLeft ? "left" : "right"; }

bool IsValidStationId(std::string_view station, std::string* why) {
  auto fail = [&](const std::string& message) {
    if (why) *why = "station id '" + std::string(station) + "': " + message;
    return false;
  };
  if (station.empty()) return fail("is empty");
  if (station.size() > 64) return fail("longer than 64 characters");
  const auto is_letter = [](char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z'); };
  if (!is_letter(station.front())) return fail("must start with a letter");
  for (char c : station) {
    if (!is_letter(c) && !(c >= '0' && c <= '9') && c != '_') {
      return fail("only letters, digits and '_' are allowed");
    }
  }
  return true;
}

TopicSpec<msg::StationStatus> StatusTopic(std::string_view station) {
  return {Name(station, "status"), Qos(1, true)};
}
TopicSpec<msg::Command> CommandTopic(std::string_view station) {
  return {Name(station, "command"), Qos(kControlDepth, false)};
}
TopicSpec<msg::Reply> ReplyTopic(std::string_view station) {
  // Transient-local: matching is discovered on each side separately, so a
  // client may see the daemon's reply writer (and send its command) before
  // that writer has seen the client's reader; a volatile reply written in
  // that gap was lost and the client waited out its timeout (seen under CI
  // load). The last kControlDepth replies reach a reader when it matches;
  // clients keep only the replies to their own request ids.
  return {Name(station, "reply"), Qos(kControlDepth, true)};
}
TopicSpec<msg::JobProgress> ProgressTopic(std::string_view station) {
  return {Name(station, "progress"), Qos(kControlDepth, false)};
}
TopicSpec<msg::StereoCapture> CaptureTopic(std::string_view station) {
  return {Name(station, "capture"), Qos(1, false)};
}
TopicSpec<msg::Disparity> DisparityTopic(std::string_view station) {
  return {Name(station, "disparity"), Qos(1, false)};
}
TopicSpec<msg::PointCloud> CloudTopic(std::string_view station) {
  // Two: the last view's cloud and the fused one may be in flight together.
  return {Name(station, "cloud"), Qos(2, false)};
}

TopicSpec<msg::SessionFile> FileTopic(std::string_view station) {
  return {Name(station, "file"), Qos(kFileTopicDepth, false)};
}

TopicSpec<msg::Preview> PreviewTopic(std::string_view station) {
  // The newest frame only: a slow reader skips frames rather than lagging.
  return {Name(station, "preview"), Qos(1, false)};
}

TopicSpec<ros::Image> RosImageTopic(std::string_view station, Side side) {
  return {RosName(station, std::string(ToString(side)) + "/image_raw"), RosQos(false)};
}
TopicSpec<ros::CameraInfo> RosCameraInfoTopic(std::string_view station, Side side) {
  // One with every image (same stamp), as image_proc, stereo_image_proc and
  // rviz2 pair them; transient-local so a tool started while the station is
  // idle still learns the intrinsics from the last one.
  return {RosName(station, std::string(ToString(side)) + "/camera_info"), RosQos(true)};
}
TopicSpec<ros::DisparityImage> RosDisparityTopic(std::string_view station) {
  return {RosName(station, "disparity"), RosQos(false)};
}
TopicSpec<ros::PointCloud2> RosCloudTopic(std::string_view station) {
  return {RosName(station, "cloud"), RosQos(false)};
}

TopicSpec<ros::TFMessage> RosTfTopic() {
  // tf2's TransformListener subscribes with depth 100; a view's transforms
  // are one sample, so 1 would do, but a late reader gets nothing anyway.
  TopicQos qos = RosQos(false);
  qos.history_depth = kTfDepth;
  return {"rt/tf", qos};
}
TopicSpec<ros::TFMessage> RosTfStaticTopic() {
  // As tf2's StaticTransformBroadcaster: reliable, transient-local,
  // keep-last 1 holding every static transform of the writer.
  return {"rt/tf_static", RosQos(true)};
}

}  // namespace craftscan::dds
