// The DDS message types and the memory rules around them.
//
// The types are the C structs idlc generates from idl/craftscan.idl and
// idl/ros2/*.idl (strings are char*, sequences are {_maximum, _length,
// _buffer, _release}); this header gives them short C++ names, the traits the
// typed Writer/Reader need, and two owners:
//  - Sample<Msg>: a received message; owns what Cyclone allocated for it.
//  - Outgoing<Msg>: a message being built for writing; owns the strings and
//    buffers made for it and borrows the big arrays it points at.
// The generated structs are the wire contract shared with the daemon's peers,
// so they appear in this library's API; DDS entities and QoS do not.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <deque>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "craftscan.h"
#include "ros2/builtin_interfaces.h"
#include "ros2/geometry_msgs.h"
#include "ros2/sensor_msgs.h"
#include "ros2/std_msgs.h"
#include "ros2/stereo_msgs.h"
#include "ros2/tf2_msgs.h"

namespace craftscan::dds {

// craftscan's own types (module craftscan::msg).
namespace msg {
using DeviceStatus = craftscan_msg_DeviceStatus;
using StationStatus = craftscan_msg_StationStatus;
using Command = craftscan_msg_Command;
using Reply = craftscan_msg_Reply;
using JobProgress = craftscan_msg_JobProgress;
using StereoCapture = craftscan_msg_StereoCapture;
using Disparity = craftscan_msg_Disparity;
using PointCloud = craftscan_msg_PointCloud;
using Preview = craftscan_msg_Preview;
}  // namespace msg

// ROS 2-compatible types (type names "sensor_msgs::msg::dds_::Image_", ...).
namespace ros {
using Time = builtin_interfaces_msg_dds__Time_;
using Header = std_msgs_msg_dds__Header_;
using Image = sensor_msgs_msg_dds__Image_;
using RegionOfInterest = sensor_msgs_msg_dds__RegionOfInterest_;
using CameraInfo = sensor_msgs_msg_dds__CameraInfo_;
using PointField = sensor_msgs_msg_dds__PointField_;
using PointCloud2 = sensor_msgs_msg_dds__PointCloud2_;
using DisparityImage = stereo_msgs_msg_dds__DisparityImage_;
using TransformStamped = geometry_msgs_msg_dds__TransformStamped_;
using TFMessage = tf2_msgs_msg_dds__TFMessage_;
}  // namespace ros

// Limits on unbounded strings (the IDL leaves them unbounded because
// Cyclone's C mapping stores a bounded string inline at its full bound).
inline constexpr std::size_t kMaxShortStringBytes = 256;             // ids, names, verbs
inline constexpr std::size_t kMaxCommandArgumentsBytes = 64 * 1024;  // Command.arguments
inline constexpr std::size_t kMaxReplyResultBytes = 1024 * 1024;     // Reply.result

// Checks a Command against the limits above: request_id, client and verb
// non-empty and at most kMaxShortStringBytes, token at most
// kMaxShortStringBytes, arguments at most kMaxCommandArgumentsBytes (JSON
// syntax is not checked here). False with *why (may be null) naming the
// field. Null strings count as empty. Thread-safe.
bool IsValidCommand(const msg::Command& command, std::string* why);

// Type name as registered with DDS for Msg, e.g.
// "sensor_msgs::msg::dds_::PointCloud2_".
template <typename Msg>
struct MessageTraits;

#define CRAFTSCAN_DDS_MESSAGE_TRAITS(Type)                                     \
  template <>                                                                  \
  struct MessageTraits<Type> {                                                 \
    static const dds_topic_descriptor_t* descriptor() { return &Type##_desc; } \
    static const char* type_name() { return Type##_desc.m_typename; }          \
  }
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_StationStatus);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_Command);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_Reply);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_JobProgress);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_StereoCapture);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_Disparity);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_PointCloud);
CRAFTSCAN_DDS_MESSAGE_TRAITS(craftscan_msg_Preview);
CRAFTSCAN_DDS_MESSAGE_TRAITS(sensor_msgs_msg_dds__Image_);
CRAFTSCAN_DDS_MESSAGE_TRAITS(sensor_msgs_msg_dds__CameraInfo_);
CRAFTSCAN_DDS_MESSAGE_TRAITS(sensor_msgs_msg_dds__PointCloud2_);
CRAFTSCAN_DDS_MESSAGE_TRAITS(stereo_msgs_msg_dds__DisparityImage_);
CRAFTSCAN_DDS_MESSAGE_TRAITS(tf2_msgs_msg_dds__TFMessage_);
#undef CRAFTSCAN_DDS_MESSAGE_TRAITS

namespace internal {
// dds_sample_free(sample, descriptor, DDS_FREE_CONTENTS), then zeroes it.
void FreeSampleContents(void* sample, const dds_topic_descriptor_t* descriptor);
}  // namespace internal

// A received message (filled by Reader<Msg>::Take). Owns the strings and
// sequence buffers Cyclone allocated and frees them on destruction or
// Reset(). Read-only to the user: a later Take into the same Sample reuses
// its buffers (no new allocation for a same-sized cloud). Move-only; a
// moved-from Sample is empty (all fields zero). Not thread-safe.
template <typename Msg>
class Sample {
 public:
  Sample() { std::memset(&msg_, 0, sizeof(Msg)); }
  ~Sample() { Reset(); }
  Sample(Sample&& other) noexcept {
    std::memcpy(&msg_, &other.msg_, sizeof(Msg));
    std::memset(&other.msg_, 0, sizeof(Msg));
  }
  Sample& operator=(Sample&& other) noexcept {
    if (this != &other) {
      Reset();
      std::memcpy(&msg_, &other.msg_, sizeof(Msg));
      std::memset(&other.msg_, 0, sizeof(Msg));
    }
    return *this;
  }
  Sample(const Sample&) = delete;
  Sample& operator=(const Sample&) = delete;

  const Msg& operator*() const { return msg_; }
  const Msg* operator->() const { return &msg_; }
  const Msg& get() const { return msg_; }

  // Frees the contents; the sample is all zero afterwards.
  void Reset() { internal::FreeSampleContents(&msg_, MessageTraits<Msg>::descriptor()); }

  // For Reader<Msg> only: the memory Cyclone deserialises into.
  Msg* mutable_storage() { return &msg_; }

 private:
  static_assert(std::is_trivially_copyable_v<Msg>, "generated DDS types are plain C structs");
  Msg msg_;
};

// Storage for the strings and buffers an Outgoing message points at.
class MessageStorage {
 public:
  MessageStorage() = default;
  MessageStorage(MessageStorage&&) noexcept = default;
  MessageStorage& operator=(MessageStorage&&) noexcept = default;
  MessageStorage(const MessageStorage&) = delete;
  MessageStorage& operator=(const MessageStorage&) = delete;

  // Stores a copy of `text` and returns it NUL-terminated, as the char*
  // string fields of the generated structs want it. Valid while this object
  // lives (moving it keeps the pointer valid).
  char* Keep(std::string_view text);

  // Takes ownership of `buffer` and returns its data (null when empty), valid
  // while this object lives (moving it keeps the pointer valid).
  template <typename T>
  T* Keep(std::vector<T> buffer) {
    auto owned = std::make_shared<std::vector<T>>(std::move(buffer));
    T* data = owned->data();
    keep_alive_.push_back(std::move(owned));
    return data;
  }

  // Keeps `object` alive as long as this storage (e.g. a cloned cv::Mat whose
  // pixels a sequence points at).
  void KeepAlive(std::shared_ptr<const void> object) { keep_alive_.push_back(std::move(object)); }

 private:
  std::deque<std::string> strings_;  // a deque never moves its elements
  std::vector<std::shared_ptr<const void>> keep_alive_;
};

// A message being built for Writer<Msg>::Write: the struct (zero-initialised:
// null strings are written as "", empty sequences as empty) plus the storage
// for what it points at. Big arrays are usually borrowed from the caller's
// data (see the conversions in convert.h): such data must stay alive and
// unchanged until the message has been written; Write serialises during the
// call, so the data may change right after it returns. Move-only. Not
// thread-safe.
template <typename Msg>
class Outgoing : public MessageStorage {
 public:
  Outgoing() { std::memset(&msg_, 0, sizeof(Msg)); }
  // The storage moves with the message, so its pointers stay valid; the
  // moved-from message is all zero.
  Outgoing(Outgoing&& other) noexcept : MessageStorage(std::move(other)) {
    std::memcpy(&msg_, &other.msg_, sizeof(Msg));
    std::memset(&other.msg_, 0, sizeof(Msg));
  }
  Outgoing& operator=(Outgoing&& other) noexcept {
    if (this != &other) {
      MessageStorage::operator=(std::move(other));
      std::memcpy(&msg_, &other.msg_, sizeof(Msg));
      std::memset(&other.msg_, 0, sizeof(Msg));
    }
    return *this;
  }

  Msg& msg() { return msg_; }
  const Msg& msg() const { return msg_; }

 private:
  static_assert(std::is_trivially_copyable_v<Msg>, "generated DDS types are plain C structs");
  Msg msg_;
};

// Points a generated sequence (e.g. dds_sequence_float) at `count` elements
// of `data` without copying; the sequence does not own them (_release =
// false), so freeing the message leaves them alone. False (sequence
// untouched) when count exceeds the 2^32 − 1 elements a sequence can hold.
template <typename Sequence, typename T>
bool Borrow(Sequence* sequence, const T* data, std::size_t count) {
  using Element = std::remove_pointer_t<decltype(sequence->_buffer)>;
  static_assert(std::is_same_v<Element, std::remove_cv_t<T>>,
                "sequence element type and data type differ");
  if (count > std::numeric_limits<uint32_t>::max()) return false;
  sequence->_buffer = const_cast<Element*>(data);
  sequence->_length = static_cast<uint32_t>(count);
  sequence->_maximum = static_cast<uint32_t>(count);
  sequence->_release = false;
  return true;
}

// The string of a received message, "" for null.
inline std::string_view View(const char* text) { return text ? std::string_view(text) : ""; }

}  // namespace craftscan::dds
