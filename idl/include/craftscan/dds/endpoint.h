// Typed DDS writers and readers for one topic (a TopicSpec from topics.h).
//
//   auto participant = Participant::Create({.domain_id = 0}, &error);
//   auto writer = Writer<msg::StationStatus>::Create(participant, StatusTopic("st1"), &error);
//   Outgoing<msg::StationStatus> status;
//   status.msg().station = status.Keep("st1");
//   writer->Write(status.msg(), &error);
//
//   auto reader = Reader<msg::StationStatus>::Create(participant, StatusTopic("st1"), &error);
//   Sample<msg::StationStatus> sample;
//   if (reader->Take(std::chrono::milliseconds(500), &sample, &error) == TakeStatus::kOk) ...
//
// Writers and readers keep their Participant alive. Creating one fails
// (null, *error says why) for an invalid QoS or topic name, or when Cyclone
// refuses an entity. A writer and a reader of the same name but different
// types (or incompatible QoS) are both created but never match.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "craftscan/dds/messages.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

namespace craftscan::dds {

enum class TakeStatus {
  kOk,       // a sample was taken
  kTimeout,  // none arrived within the timeout
  kError,    // DDS reported an error (*error says which)
};

// A sample as it travelled: its serialised form (the 4-byte encapsulation
// header, then the CDR body) and the writer's timestamp.
struct RawSample {
  std::vector<uint8_t> cdr;
  int64_t source_timestamp_ns = 0;  // ns since the Unix epoch
};

// A keyed topic's instance as a taken sample left it (DDS instance states).
enum class InstanceState {
  kAlive,      // some writer has it and has not disposed it
  kDisposed,   // a writer disposed it (the thing it stands for ended)
  kNoWriters,  // no live writer has it: each unregistered, died, was cut off or
               // let its liveliness lease lapse
};
struct SampleState {
  bool valid_data = false;  // false: only the key fields are set (an instance state change)
  InstanceState instance = InstanceState::kAlive;
  int64_t source_timestamp_ns = 0;
};

namespace internal {

// The untyped parts of Writer/Reader (descriptor + void* samples).
class WriterCore {
 public:
  static std::unique_ptr<WriterCore> Create(std::shared_ptr<Participant> participant,
                                            const dds_topic_descriptor_t* descriptor,
                                            const std::string& topic_name, const TopicQos& qos,
                                            std::string* error);
  ~WriterCore();
  WriterCore(const WriterCore&) = delete;
  WriterCore& operator=(const WriterCore&) = delete;

  bool Write(const void* sample, std::string* error);
  bool Dispose(const void* sample, std::string* error);
  bool WaitForAcks(std::chrono::milliseconds timeout, std::string* error);
  int MatchedReaders() const;
  bool WaitForReaders(int count, std::chrono::milliseconds timeout) const;
  const std::string& topic_name() const { return topic_name_; }

 private:
  WriterCore() = default;
  std::shared_ptr<Participant> participant_;
  std::string topic_name_;
  int32_t topic_ = 0, writer_ = 0, match_waitset_ = 0;
};

class ReaderCore {
 public:
  static std::unique_ptr<ReaderCore> Create(std::shared_ptr<Participant> participant,
                                            const dds_topic_descriptor_t* descriptor,
                                            const std::string& topic_name, const TopicQos& qos,
                                            std::string* error);
  ~ReaderCore();
  ReaderCore(const ReaderCore&) = delete;
  ReaderCore& operator=(const ReaderCore&) = delete;

  TakeStatus Take(void* sample, std::chrono::nanoseconds timeout, std::string* error);
  TakeStatus TakeWithInfo(void* sample, SampleState* state, std::chrono::nanoseconds timeout,
                          std::string* error);
  // `decoded` (may be null): a sample of the reader's type to deserialise into.
  TakeStatus TakeRaw(RawSample* raw, void* decoded, std::chrono::nanoseconds timeout,
                     std::string* error);
  int MatchedWriters() const;
  bool WaitForWriters(int count, std::chrono::milliseconds timeout) const;
  const std::string& topic_name() const { return topic_name_; }

 private:
  ReaderCore() = default;
  // Calls take_one (returns dds_take's count or error, sets *valid) until
  // it takes a sample with data, waiting on the data waitset up to timeout.
  TakeStatus TakeWhenReady(std::chrono::nanoseconds timeout, std::string* error,
                           const std::function<int32_t(bool*)>& take_one);
  std::shared_ptr<Participant> participant_;
  std::string topic_name_;
  int32_t topic_ = 0, reader_ = 0, read_condition_ = 0, data_waitset_ = 0, match_waitset_ = 0;
};

}  // namespace internal

template <typename Msg>
class Writer {
 public:
  // Creates a writer on `topic` in `participant` (not null).
  static std::unique_ptr<Writer> Create(std::shared_ptr<Participant> participant,
                                        const TopicSpec<Msg>& topic, std::string* error) {
    auto core = internal::WriterCore::Create(
        std::move(participant), MessageTraits<Msg>::descriptor(), topic.name, topic.qos, error);
    if (!core) return nullptr;
    return std::unique_ptr<Writer>(new Writer(std::move(core)));
  }

  // Publishes `message`, which is serialised during the call (buffers it
  // borrows may change once this returns). On a reliable topic it may block
  // up to qos.max_blocking_ms while readers catch up; then false with a
  // timeout error and the sample not sent. Thread-safe.
  bool Write(const Msg& message, std::string* error) { return core_->Write(&message, error); }

  // Disposes the instance with `message`'s key (keyed topics): readers see
  // it kDisposed.
  bool Dispose(const Msg& message, std::string* error) { return core_->Dispose(&message, error); }

  // Waits until every matched reliable reader has acknowledged everything
  // written so far (e.g. before exiting: deleting a writer waits for acks only
  // up to Cyclone's WriterLingerDuration, 1 s). False with *error on timeout.
  // Thread-safe.
  bool WaitForAcks(std::chrono::milliseconds timeout, std::string* error) {
    return core_->WaitForAcks(timeout, error);
  }

  // Readers currently matched (−1 on error). Thread-safe.
  int MatchedReaders() const { return core_->MatchedReaders(); }
  // Waits until at least `count` readers are matched; false on timeout.
  // One waiting thread per writer at a time.
  bool WaitForReaders(int count, std::chrono::milliseconds timeout) const {
    return core_->WaitForReaders(count, timeout);
  }
  const std::string& topic_name() const { return core_->topic_name(); }

 private:
  explicit Writer(std::unique_ptr<internal::WriterCore> core) : core_(std::move(core)) {}
  std::unique_ptr<internal::WriterCore> core_;
};

template <typename Msg>
class Reader {
 public:
  // Creates a reader on `topic` in `participant` (not null). On a
  // transient-local topic it receives the writers' retained samples.
  static std::unique_ptr<Reader> Create(std::shared_ptr<Participant> participant,
                                        const TopicSpec<Msg>& topic, std::string* error) {
    auto core = internal::ReaderCore::Create(
        std::move(participant), MessageTraits<Msg>::descriptor(), topic.name, topic.qos, error);
    if (!core) return nullptr;
    return std::unique_ptr<Reader>(new Reader(std::move(core)));
  }

  // Takes the oldest unread sample into *sample (replacing its contents,
  // reusing its buffers), waiting up to `timeout` (0: just poll) for one to
  // arrive. On kTimeout or kError *sample holds no new message. Samples
  // without data (a writer going away) are skipped. One thread per reader at
  // a time.
  TakeStatus Take(std::chrono::nanoseconds timeout, Sample<Msg>* sample, std::string* error) {
    return core_->Take(sample->mutable_storage(), timeout, error);
  }

  // As Take, but also returns samples without data, which a keyed topic's
  // reader gets when an instance is disposed or loses its last live writer:
  // *state says which (only the key fields of *sample are then set).
  TakeStatus TakeWithInfo(std::chrono::nanoseconds timeout, Sample<Msg>* sample, SampleState* state,
                          std::string* error) {
    return core_->TakeWithInfo(sample->mutable_storage(), state, timeout, error);
  }

  // As Take, but keeps the sample as it was on the wire: *raw gets its
  // serialised bytes (what a ROS 2 tool or a recording stores) and, when
  // `decoded` is not null, *decoded the same sample deserialised. Same
  // threading rules as Take.
  TakeStatus TakeRaw(std::chrono::nanoseconds timeout, RawSample* raw, Sample<Msg>* decoded,
                     std::string* error) {
    return core_->TakeRaw(raw, decoded ? decoded->mutable_storage() : nullptr, timeout, error);
  }

  // Writers currently matched (−1 on error). Thread-safe.
  int MatchedWriters() const { return core_->MatchedWriters(); }
  // Waits until at least `count` writers are matched; false on timeout.
  // One waiting thread per reader at a time.
  bool WaitForWriters(int count, std::chrono::milliseconds timeout) const {
    return core_->WaitForWriters(count, timeout);
  }
  const std::string& topic_name() const { return core_->topic_name(); }

 private:
  explicit Reader(std::unique_ptr<internal::ReaderCore> core) : core_(std::move(core)) {}
  std::unique_ptr<internal::ReaderCore> core_;
};

}  // namespace craftscan::dds
