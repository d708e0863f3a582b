// Records the ROS 2 topics of one or more stations into one MCAP file
// (craftscan-record --mcap), the format rosbag2 and Foxglove open:
//
//   rt/craftscan/<station>/left/image_raw, right/image_raw   sensor_msgs/msg/Image
//   rt/craftscan/<station>/left/camera_info, right/...       sensor_msgs/msg/CameraInfo
//   rt/craftscan/<station>/disparity                         stereo_msgs/msg/DisparityImage
//   rt/craftscan/<station>/cloud                             sensor_msgs/msg/PointCloud2
//   rt/tf, rt/tf_static                                      tf2_msgs/msg/TFMessage
//
// Profile "ros2"; one channel per topic named as ROS 2 names it
// ("/craftscan/<station>/left/image_raw", "/tf"), message encoding "cdr"
// (each sample's bytes exactly as they came off the wire: encapsulation
// header and CDR body), schema encoding "ros2msg" with the full message
// definition (dds::RosMessageDefinition); channel metadata as rosbag2 writes
// it (offered_qos_profiles). Log time: when the recorder took the sample;
// publish time: the writer's source timestamp.
//
// One reader thread per topic; a reader keeps `reader_history` samples not
// yet written (then DDS drops the oldest: the station is never slowed).
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace craftscan::record {

struct McapRecorderOptions {
  std::vector<std::string> stations;  // valid, distinct station ids, ≥ 1
  uint32_t domain_id = 0;
  // Cyclone configuration; empty = CYCLONEDDS_URI (or, when the domain is
  // already joined in this process, that participant's configuration).
  std::string dds_config;
  std::string path;            // the MCAP file (created or truncated)
  int32_t reader_history = 8;  // 1..64
  int32_t poll_ms = 200;       // 10..1000

  bool IsValid(std::string* why) const;
};

struct McapSummary {
  std::map<std::string, uint64_t> messages;  // per ROS 2 topic name
  uint64_t total = 0;
  std::string error;  // the first write error, "" if none
};

class McapRecorder {
 public:
  // Creates the file (header, schemas, channels), the readers and their
  // threads. Null with *error (may be null) for invalid options, a file or
  // DDS failure.
  static std::unique_ptr<McapRecorder> Create(const McapRecorderOptions& options,
                                              std::string* error);
  ~McapRecorder();  // Stop()
  McapRecorder(const McapRecorder&) = delete;
  McapRecorder& operator=(const McapRecorder&) = delete;

  // True once a write failed (the recording then stops taking samples).
  bool Failed() const;
  // Joins the threads and finishes the file (summary, footer). False with
  // *error when that or an earlier write failed. Idempotent. Thread-safe.
  bool Stop(std::string* error);
  McapSummary Summary() const;  // thread-safe, any time

  struct State;  // implementation (mcap_recorder.cc)

 private:
  explicit McapRecorder(std::shared_ptr<State> state);
  std::shared_ptr<State> state_;
};

}  // namespace craftscan::record
