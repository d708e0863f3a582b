#include "craftscan/record/mcap_recorder.h"

#include <atomic>
#include <exception>
#include <functional>
#include <mutex>
#include <set>
#include <thread>

#include <spdlog/spdlog.h>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/ros2_definitions.h"
#include "craftscan/dds/topics.h"
#include "craftscan/record/mcap_writer.h"
#include "reader_loop.h"

namespace craftscan::record {
namespace {

using internal::SetError;

// rosbag2's offered_qos_profiles for a topic's QoS (what `ros2 bag play`
// offers again: transient-local matters for camera_info and /tf_static).
std::string OfferedQos(const dds::TopicQos& qos) {
  constexpr const char* kInfinite = "\n    sec: 2147483647\n    nsec: 4294967295";
  std::string yaml = "- history: 1\n  depth: " + std::to_string(qos.history_depth) +
                     "\n  reliability: " + (qos.reliable ? "1" : "2") +
                     "\n  durability: " + (qos.transient_local ? "1" : "2");
  yaml += "\n  deadline:";
  yaml += kInfinite;
  yaml += "\n  lifespan:";
  yaml += kInfinite;
  yaml += "\n  liveliness: 1\n  liveliness_lease_duration:";
  yaml += kInfinite;
  yaml += "\n  avoid_ros_namespace_conventions: false";
  return yaml;
}

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace

bool McapRecorderOptions::IsValid(std::string* why) const {
  if (!internal::CheckReaderOptions(stations, domain_id, reader_history, poll_ms, why)) {
    return false;
  }
  if (path.empty()) return SetError(why, "path: no MCAP file given");
  return true;
}

struct McapRecorder::State {
  McapRecorderOptions options;
  std::shared_ptr<dds::Participant> participant;
  std::unique_ptr<McapWriter> writer;
  std::atomic<bool> stopping{false};
  std::vector<std::thread> threads;
  std::mutex join_mutex;  // one Stop() joins and closes

  mutable std::mutex mutex;  // guards what follows
  McapSummary summary;

  void Failed(const std::string& message) {
    {
      std::lock_guard lock(mutex);
      if (summary.error.empty()) summary.error = message;
    }
    spdlog::error("mcap: {}", message);
    stopping = true;
  }

  // Takes raw samples of one topic and writes them on `channel`.
  template <typename Msg>
  void Loop(std::shared_ptr<dds::Reader<Msg>> reader, uint16_t channel, std::string ros_topic) {
    try {
      dds::RawSample raw;
      std::string error;
      internal::TakeUntilStopped(
          reader->topic_name(), options.poll_ms, stopping,
          [&](std::chrono::milliseconds timeout, std::string* why) {
            return reader->TakeRaw(timeout, &raw, nullptr, why);
          },
          [&] {
            if (!writer->WriteMessage(channel, static_cast<uint64_t>(NowNs()),
                                      static_cast<uint64_t>(raw.source_timestamp_ns),
                                      raw.cdr.data(), raw.cdr.size(), &error)) {
              Failed(error);
              return;
            }
            std::lock_guard lock(mutex);
            summary.messages[ros_topic] += 1;
            summary.total += 1;
          });
    } catch (const std::exception& e) {
      Failed(reader->topic_name() + ": " + e.what());
    }
  }
};

std::unique_ptr<McapRecorder> McapRecorder::Create(const McapRecorderOptions& options,
                                                   std::string* error) {
  if (!options.IsValid(error)) return nullptr;
  auto state = std::make_shared<State>();
  state->options = options;
  dds::ParticipantOptions participant_options;
  participant_options.domain_id = options.domain_id;
  participant_options.config = options.dds_config;
  std::string why;
  state->participant = dds::Participant::Create(participant_options, &why);
  if (!state->participant) {
    SetError(error, "DDS: " + why);
    return nullptr;
  }
  state->writer = McapWriter::Create(options.path, "ros2", "craftscan-record", &why);
  if (!state->writer) {
    SetError(error, why);
    return nullptr;
  }

  std::vector<std::function<void()>> loops;
  State* s = state.get();
  const auto add = [&]<typename Msg>(dds::TopicSpec<Msg> topic, const char* type) {
    const std::string ros_topic = topic.name.substr(2);  // "rt/x" is ROS 2's "/x"
    const uint16_t schema =
        s->writer->AddSchema(type, "ros2msg", dds::RosMessageDefinition(type), &why);
    const uint16_t channel =
        schema == 0
            ? 0
            : s->writer->AddChannel(schema, ros_topic, "cdr",
                                    {{"offered_qos_profiles", OfferedQos(topic.qos)}}, &why);
    if (channel == 0) return SetError(error, why);
    topic.qos.history_depth = options.reader_history;
    std::shared_ptr<dds::Reader<Msg>> reader =
        dds::Reader<Msg>::Create(s->participant, topic, &why);
    if (!reader) return SetError(error, "DDS: " + why);
    loops.push_back([s, reader, channel, ros_topic] { s->Loop<Msg>(reader, channel, ros_topic); });
    return true;
  };
  using dds::Side;
  for (const std::string& station : options.stations) {
    for (Side side : {Side::kLeft, Side::kRight}) {
      if (!add(dds::RosCameraInfoTopic(station, side), "sensor_msgs/msg/CameraInfo") ||
          !add(dds::RosImageTopic(station, side), "sensor_msgs/msg/Image")) {
        return nullptr;
      }
    }
    if (!add(dds::RosDisparityTopic(station), "stereo_msgs/msg/DisparityImage") ||
        !add(dds::RosCloudTopic(station), "sensor_msgs/msg/PointCloud2")) {
      return nullptr;
    }
  }
  if (!add(dds::RosTfStaticTopic(), "tf2_msgs/msg/TFMessage") ||
      !add(dds::RosTfTopic(), "tf2_msgs/msg/TFMessage")) {
    return nullptr;
  }
  for (auto& loop : loops) state->threads.emplace_back(std::move(loop));
  return std::unique_ptr<McapRecorder>(new McapRecorder(std::move(state)));
}

McapRecorder::McapRecorder(std::shared_ptr<State> state) : state_(std::move(state)) {}

McapRecorder::~McapRecorder() {
  std::string ignored;
  Stop(&ignored);
}

bool McapRecorder::Failed() const {
  std::lock_guard lock(state_->mutex);
  return !state_->summary.error.empty();
}

bool McapRecorder::Stop(std::string* error) {
  state_->stopping = true;
  std::lock_guard lock(state_->join_mutex);
  for (std::thread& thread : state_->threads) {
    if (thread.joinable()) thread.join();
  }
  std::string why;
  if (!state_->writer->Close(&why)) state_->Failed(why);
  std::lock_guard summary_lock(state_->mutex);
  if (!state_->summary.error.empty()) return SetError(error, state_->summary.error);
  return true;
}

McapSummary McapRecorder::Summary() const {
  std::lock_guard lock(state_->mutex);
  return state_->summary;
}

}  // namespace craftscan::record
