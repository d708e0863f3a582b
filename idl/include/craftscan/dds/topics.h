// Topic names and QoS of one station (DESIGN.md, "DDS interface"): each
// function returns the name, the message type (as the template argument) and
// the QoS, so a Writer and a Reader made from the same function always match.
//
//   craftscan/<station>/status      StationStatus  reliable, transient-local, keep-last 1
//   craftscan/<station>/command     Command        reliable, volatile, keep-last 16
//   craftscan/<station>/reply       Reply          reliable, volatile, keep-last 16
//   craftscan/<station>/progress    JobProgress    reliable, volatile, keep-last 16
//   craftscan/<station>/capture     StereoCapture  reliable, volatile, keep-last 1
//   craftscan/<station>/disparity   Disparity      reliable, volatile, keep-last 1
//   craftscan/<station>/cloud       PointCloud     reliable, volatile, keep-last 2
//   craftscan/<station>/file        SessionFile    reliable, volatile, keep-last 64
//   craftscan/<station>/preview     Preview        reliable, volatile, keep-last 1
//   rt/craftscan/<station>/left/image_raw, right/image_raw   Image_      reliable, keep-last 1
//   rt/craftscan/<station>/left/camera_info, right/...       CameraInfo_ reliable,
//                                                            transient-local, keep-last 1
//                                                            (one per image, same stamp)
//   rt/craftscan/<station>/disparity                         DisparityImage_ reliable, keep-last 1
//   rt/craftscan/<station>/cloud                             PointCloud2_ reliable, keep-last 1
//   rt/tf_static                    TFMessage_  reliable, transient-local, keep-last 1
//   rt/tf                           TFMessage_  reliable, volatile, keep-last 100
//
// The rt/ topics are what ROS 2 (rmw_cyclonedds) calls /craftscan/<station>/...;
// they are XCDR1 only. /tf and /tf_static are shared by every station of a
// domain, as ROS has one transform tree: the frames are named per station
// instead (convert.h, StationFrames). A reliable writer also serves best-effort readers
// (ROS's sensor-data QoS), and a transient-local one serves volatile readers.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "craftscan/dds/messages.h"

namespace craftscan::dds {

// The file-transfer message (craftscan.idl SessionFile), declared here with
// its topic rather than in messages.h.
namespace msg {
using SessionFile = craftscan_msg_SessionFile;
}  // namespace msg
template <>
struct MessageTraits<msg::SessionFile> {
  static const dds_topic_descriptor_t* descriptor() { return &craftscan_msg_SessionFile_desc; }
  static const char* type_name() { return craftscan_msg_SessionFile_desc.m_typename; }
};

// SessionFile chunks carry at most this many bytes of data.
inline constexpr std::size_t kMaxFileChunkBytes = std::size_t{4} << 20;
// History of the file topic (samples): a reader's application may fall
// this many chunks behind what its DDS threads received before the oldest
// is overwritten; receivers see such a gap in the offsets and fail the
// transfer rather than write a damaged file. A reader holds that much
// (64 MiB in the default 1 MiB chunks) only while its application stops
// taking and the network keeps delivering; the sender waits for
// acknowledgements every 8 MiB.
inline constexpr int32_t kFileTopicDepth = 64;

struct TopicQos {
  bool reliable = true;
  bool transient_local = false;  // late joiners get the last history_depth samples
  int32_t history_depth = 1;     // keep-last N (≥ 1)
  bool xcdr1_only = false;       // data representation XCDR1 (ROS 2); else Cyclone's default
  // How long a reliable Write may block when the writer's unacknowledged data
  // is above Cyclone's WhcHigh (readers lagging), ms (≥ 0).
  int32_t max_blocking_ms = 1000;
  // The DDS partition of the writer's publisher / reader's subscriber; ""
  // is the default partition. A writer and a reader match only in the same
  // partition (the site topics, site.h, keep sites apart this way).
  std::string partition;
  // Liveliness: 0 = automatic, never lost while the participant lives.
  // Otherwise manual-by-topic with this lease (ms): the writer is alive
  // while it writes (or asserts) at least once a lease; after that a reader
  // sees its instances NOT_ALIVE_NO_WRITERS. Writer and reader must agree
  // (a reader's lease ≥ the writer's).
  int32_t liveliness_lease_ms = 0;
  // A writer that unregisters an instance (or whose liveliness lapses)
  // disposes it too (DDS's default); false: readers see kNoWriters then, and
  // only an explicit Dispose disposes.
  bool autodispose = true;

  bool IsValid(std::string* why) const;
};

// A topic: its name, its QoS, and (as Msg) its type.
template <typename Msg>
struct TopicSpec {
  std::string name;
  TopicQos qos;
};

enum class Side { kLeft, kRight };
std::string_view ToString(Side side);  // "left", "right"

// A station id as used in topic names: 1..64 characters, [A-Za-z0-9_],
// starting with a letter (what ROS 2 allows in a name token). False with
// *why (may be null) otherwise. The topic functions below do not check; a
// Writer/Reader on a malformed name fails to be created.
bool IsValidStationId(std::string_view station, std::string* why);

TopicSpec<msg::StationStatus> StatusTopic(std::string_view station);
TopicSpec<msg::Command> CommandTopic(std::string_view station);
TopicSpec<msg::Reply> ReplyTopic(std::string_view station);
TopicSpec<msg::JobProgress> ProgressTopic(std::string_view station);
TopicSpec<msg::StereoCapture> CaptureTopic(std::string_view station);
TopicSpec<msg::Disparity> DisparityTopic(std::string_view station);
TopicSpec<msg::PointCloud> CloudTopic(std::string_view station);
TopicSpec<msg::SessionFile> FileTopic(std::string_view station);
TopicSpec<msg::Preview> PreviewTopic(std::string_view station);

TopicSpec<ros::Image> RosImageTopic(std::string_view station, Side side);
TopicSpec<ros::CameraInfo> RosCameraInfoTopic(std::string_view station, Side side);
TopicSpec<ros::DisparityImage> RosDisparityTopic(std::string_view station);
TopicSpec<ros::PointCloud2> RosCloudTopic(std::string_view station);
TopicSpec<ros::TFMessage> RosTfTopic();
TopicSpec<ros::TFMessage> RosTfStaticTopic();

}  // namespace craftscan::dds
