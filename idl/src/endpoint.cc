// WriterCore / ReaderCore: DDS topic, writer/reader, QoS, waitsets.
#include "craftscan/dds/endpoint.h"

#include <dds/dds.h>
#include <dds/ddsi/ddsi_serdata.h>

#include <functional>
#include <string>

namespace craftscan::dds::internal {
namespace {

using Clock = std::chrono::steady_clock;

void SetError(std::string* error, std::string message) {
  if (error) *error = std::move(message);
}

std::string DdsError(dds_return_t rc) { return dds_strretcode(rc); }

bool IsValidTopicName(const std::string& name, std::string* why) {
  if (name.empty()) {
    *why = "topic name is empty";
    return false;
  }
  if (name.front() == '/' || name.back() == '/') {
    *why = "topic name '" + name + "' starts or ends with '/'";
    return false;
  }
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '/';
    if (!ok) {
      *why = "topic name '" + name + "' has a character other than [A-Za-z0-9_/]";
      return false;
    }
  }
  return true;
}

// Owns a dds_qos_t.
struct QosDeleter {
  void operator()(dds_qos_t* qos) const { dds_delete_qos(qos); }
};
using QosPtr = std::unique_ptr<dds_qos_t, QosDeleter>;

QosPtr MakeQos(const TopicQos& topic_qos) {
  QosPtr qos(dds_create_qos());
  dds_qset_reliability(qos.get(),
                       topic_qos.reliable ? DDS_RELIABILITY_RELIABLE : DDS_RELIABILITY_BEST_EFFORT,
                       DDS_MSECS(topic_qos.max_blocking_ms));
  dds_qset_durability(qos.get(), topic_qos.transient_local ? DDS_DURABILITY_TRANSIENT_LOCAL
                                                           : DDS_DURABILITY_VOLATILE);
  dds_qset_history(qos.get(), DDS_HISTORY_KEEP_LAST, topic_qos.history_depth);
  if (!topic_qos.partition.empty()) dds_qset_partition1(qos.get(), topic_qos.partition.c_str());
  if (!topic_qos.autodispose) dds_qset_writer_data_lifecycle(qos.get(), false);
  if (topic_qos.liveliness_lease_ms > 0) {
    dds_qset_liveliness(qos.get(), DDS_LIVELINESS_MANUAL_BY_TOPIC,
                        DDS_MSECS(topic_qos.liveliness_lease_ms));
  }
  if (topic_qos.xcdr1_only) {
    dds_data_representation_id_t xcdr1 = DDS_DATA_REPRESENTATION_XCDR1;
    dds_qset_data_representation(qos.get(), 1, &xcdr1);
  }
  return qos;
}

// Checks the inputs shared by writers and readers and creates the topic
// (default topic QoS: the endpoints carry theirs, so two endpoints with
// different QoS can share a topic in one participant).
dds_entity_t CreateTopic(const Participant* participant, const dds_topic_descriptor_t* descriptor,
                         const std::string& topic_name, const TopicQos& qos, std::string* error) {
  std::string why;
  if (participant == nullptr) why = "no participant";
  if (why.empty()) IsValidTopicName(topic_name, &why);
  if (why.empty() && !qos.IsValid(&why)) why = "QoS: " + why;
  if (!why.empty()) {
    SetError(error, "topic '" + topic_name + "': " + why);
    return 0;
  }
  const dds_entity_t topic =
      dds_create_topic(participant->handle(), descriptor, topic_name.c_str(), nullptr, nullptr);
  if (topic < 0) {
    SetError(error, "topic '" + topic_name + "' (" + descriptor->m_typename +
                        "): cannot create it: " + DdsError(topic));
    return 0;
  }
  return topic;
}

// Creates a waitset attached to `entity`'s status condition for `status_mask`.
dds_entity_t CreateStatusWaitset(dds_entity_t participant, dds_entity_t entity,
                                 uint32_t status_mask) {
  if (dds_set_status_mask(entity, status_mask) < 0) return -1;
  const dds_entity_t waitset = dds_create_waitset(participant);
  if (waitset < 0) return waitset;
  if (dds_waitset_attach(waitset, entity, entity) < 0) {
    dds_delete(waitset);
    return -1;
  }
  return waitset;
}

// What a writer and a reader both have: the topic, the endpoint itself and a
// waitset on its matched status. Entities not created stay 0.
struct Entities {
  dds_entity_t topic = 0, endpoint = 0, match_waitset = 0;
};

bool CreateEntities(const Participant* participant, const dds_topic_descriptor_t* descriptor,
                    const std::string& topic_name, const TopicQos& qos, bool writer,
                    Entities* entities, std::string* error) {
  entities->topic = CreateTopic(participant, descriptor, topic_name, qos, error);
  if (entities->topic <= 0) {
    entities->topic = 0;
    return false;
  }
  const char* what = writer ? "writer" : "reader";
  const dds_entity_t endpoint =
      writer
          ? dds_create_writer(participant->handle(), entities->topic, MakeQos(qos).get(), nullptr)
          : dds_create_reader(participant->handle(), entities->topic, MakeQos(qos).get(), nullptr);
  if (endpoint < 0) {
    SetError(error,
             "topic '" + topic_name + "': cannot create a " + what + ": " + DdsError(endpoint));
    return false;
  }
  entities->endpoint = endpoint;
  const dds_entity_t waitset = CreateStatusWaitset(
      participant->handle(), endpoint,
      writer ? DDS_PUBLICATION_MATCHED_STATUS : DDS_SUBSCRIPTION_MATCHED_STATUS);
  if (waitset < 0) {
    SetError(error, "topic '" + topic_name + "': cannot create the " + what + "'s waitset");
    return false;
  }
  entities->match_waitset = waitset;
  return true;
}

// Waits on `waitset` until count() ≥ target or the timeout passes.
bool WaitForCount(dds_entity_t waitset, const std::function<int()>& count, int target,
                  std::chrono::milliseconds timeout) {
  const Clock::time_point deadline = Clock::now() + timeout;
  for (;;) {
    const int current = count();
    if (current < 0) return false;
    if (current >= target) return true;
    const auto remaining = deadline - Clock::now();
    if (remaining <= Clock::duration::zero()) return false;
    const dds_return_t rc =
        dds_waitset_wait(waitset, nullptr, 0,
                         std::chrono::duration_cast<std::chrono::nanoseconds>(remaining).count());
    if (rc < 0) return false;
  }
}

}  // namespace

// --- WriterCore ---------------------------------------------------------------

std::unique_ptr<WriterCore> WriterCore::Create(std::shared_ptr<Participant> participant,
                                               const dds_topic_descriptor_t* descriptor,
                                               const std::string& topic_name, const TopicQos& qos,
                                               std::string* error) {
  std::unique_ptr<WriterCore> core(new WriterCore());
  Entities entities;
  const bool ok =
      CreateEntities(participant.get(), descriptor, topic_name, qos, true, &entities, error);
  // Whatever was created is deleted by the destructor if !ok.
  core->topic_ = entities.topic;
  core->writer_ = entities.endpoint;
  core->match_waitset_ = entities.match_waitset;
  if (!ok) return nullptr;
  core->participant_ = std::move(participant);
  core->topic_name_ = topic_name;
  return core;
}

WriterCore::~WriterCore() {
  if (match_waitset_ > 0) dds_delete(match_waitset_);
  if (writer_ > 0) dds_delete(writer_);
  if (topic_ > 0) dds_delete(topic_);
}

bool WriterCore::Write(const void* sample, std::string* error) {
  const dds_return_t rc = dds_write(writer_, sample);
  if (rc == DDS_RETCODE_OK) return true;
  if (rc == DDS_RETCODE_TIMEOUT) {
    SetError(error, "write on '" + topic_name_ +
                        "' timed out: readers did not acknowledge earlier samples in time");
  } else {
    SetError(error, "write on '" + topic_name_ + "' failed: " + DdsError(rc));
  }
  return false;
}

bool WriterCore::Dispose(const void* sample, std::string* error) {
  const dds_return_t rc = dds_dispose(writer_, sample);
  if (rc == DDS_RETCODE_OK) return true;
  SetError(error, "dispose on '" + topic_name_ + "' failed: " + DdsError(rc));
  return false;
}

bool WriterCore::WaitForAcks(std::chrono::milliseconds timeout, std::string* error) {
  const dds_return_t rc = dds_wait_for_acks(
      writer_, std::chrono::duration_cast<std::chrono::nanoseconds>(timeout).count());
  if (rc == DDS_RETCODE_OK) return true;
  SetError(error, "'" + topic_name_ + "': " +
                      (rc == DDS_RETCODE_TIMEOUT
                           ? std::string("readers did not acknowledge in time")
                           : "waiting for acknowledgements failed: " + DdsError(rc)));
  return false;
}

int WriterCore::MatchedReaders() const {
  dds_publication_matched_status_t status;
  if (dds_get_publication_matched_status(writer_, &status) < 0) return -1;
  return static_cast<int>(status.current_count);
}

bool WriterCore::WaitForReaders(int count, std::chrono::milliseconds timeout) const {
  return WaitForCount(
      match_waitset_, [this] { return MatchedReaders(); }, count, timeout);
}

// --- ReaderCore ---------------------------------------------------------------

std::unique_ptr<ReaderCore> ReaderCore::Create(std::shared_ptr<Participant> participant,
                                               const dds_topic_descriptor_t* descriptor,
                                               const std::string& topic_name, const TopicQos& qos,
                                               std::string* error) {
  std::unique_ptr<ReaderCore> core(new ReaderCore());
  Entities entities;
  const bool ok =
      CreateEntities(participant.get(), descriptor, topic_name, qos, false, &entities, error);
  // Whatever was created is deleted by the destructor on failure.
  core->topic_ = entities.topic;
  core->reader_ = entities.endpoint;
  core->match_waitset_ = entities.match_waitset;
  if (!ok) return nullptr;
  core->read_condition_ = dds_create_readcondition(core->reader_, DDS_ANY_STATE);
  const dds_entity_t waitset = dds_create_waitset(participant->handle());
  if (waitset > 0) core->data_waitset_ = waitset;
  if (core->read_condition_ < 0 || waitset < 0 ||
      dds_waitset_attach(waitset, core->read_condition_, core->reader_) < 0) {
    SetError(error, "topic '" + topic_name + "': cannot create the reader's data waitset");
    return nullptr;
  }
  core->participant_ = std::move(participant);
  core->topic_name_ = topic_name;
  return core;
}

ReaderCore::~ReaderCore() {
  if (match_waitset_ > 0) dds_delete(match_waitset_);
  if (data_waitset_ > 0) dds_delete(data_waitset_);
  if (reader_ > 0) dds_delete(reader_);  // also deletes the read condition
  if (topic_ > 0) dds_delete(topic_);
}

TakeStatus ReaderCore::TakeWhenReady(std::chrono::nanoseconds timeout, std::string* error,
                                     const std::function<int32_t(bool*)>& take_one) {
  const Clock::time_point deadline = Clock::now() + timeout;
  for (;;) {
    bool valid = false;
    const dds_return_t n = take_one(&valid);
    if (n < 0) {
      SetError(error, "take on '" + topic_name_ + "' failed: " + DdsError(n));
      return TakeStatus::kError;
    }
    if (n > 0 && valid) return TakeStatus::kOk;
    if (n > 0) continue;  // no data (a writer went away): look again
    const auto remaining = deadline - Clock::now();
    if (remaining <= Clock::duration::zero()) return TakeStatus::kTimeout;
    const dds_return_t rc =
        dds_waitset_wait(data_waitset_, nullptr, 0,
                         std::chrono::duration_cast<std::chrono::nanoseconds>(remaining).count());
    if (rc < 0) {
      SetError(error, "waiting on '" + topic_name_ + "' failed: " + DdsError(rc));
      return TakeStatus::kError;
    }
  }
}

TakeStatus ReaderCore::Take(void* sample, std::chrono::nanoseconds timeout, std::string* error) {
  return TakeWhenReady(timeout, error, [&](bool* valid) {
    // A non-null buffer: Cyclone deserialises into our sample (reusing its
    // buffers) instead of lending one of its own.
    void* buffers[1] = {sample};
    dds_sample_info_t info;
    const dds_return_t n = dds_take(read_condition_, buffers, &info, 1, 1);
    *valid = n > 0 && info.valid_data;
    return n;
  });
}

TakeStatus ReaderCore::TakeWithInfo(void* sample, SampleState* state,
                                    std::chrono::nanoseconds timeout, std::string* error) {
  return TakeWhenReady(timeout, error, [&](bool* valid) {
    void* buffers[1] = {sample};
    dds_sample_info_t info;
    const dds_return_t n = dds_take(read_condition_, buffers, &info, 1, 1);
    *valid = n > 0;  // samples without data count: they carry the instance's end
    if (n > 0) {
      state->valid_data = info.valid_data;
      state->instance = info.instance_state == DDS_IST_ALIVE ? InstanceState::kAlive
                        : info.instance_state == DDS_IST_NOT_ALIVE_DISPOSED
                            ? InstanceState::kDisposed
                            : InstanceState::kNoWriters;
      state->source_timestamp_ns = info.source_timestamp;
    }
    return n;
  });
}

TakeStatus ReaderCore::TakeRaw(RawSample* raw, void* decoded, std::chrono::nanoseconds timeout,
                               std::string* error) {
  bool decode_failed = false;
  const TakeStatus status = TakeWhenReady(timeout, error, [&](bool* valid) {
    struct ddsi_serdata* serdata = nullptr;
    dds_sample_info_t info;
    const dds_return_t n = dds_takecdr(reader_, &serdata, 1, &info, DDS_ANY_STATE);
    *valid = n > 0 && info.valid_data;
    if (*valid) {
      // The serialised form starts with the 4-byte encapsulation header
      // (e.g. 00 01 00 00: CDR, little endian), as ROS tools expect it.
      raw->cdr.resize(ddsi_serdata_size(serdata));
      ddsi_serdata_to_ser(serdata, 0, raw->cdr.size(), raw->cdr.data());
      raw->source_timestamp_ns = info.source_timestamp;
      if (decoded != nullptr) {
        decode_failed = !ddsi_serdata_to_sample(serdata, decoded, nullptr, nullptr);
      }
    }
    if (n > 0) ddsi_serdata_unref(serdata);
    return n;
  });
  if (status == TakeStatus::kOk && decode_failed) {
    SetError(error, "take on '" + topic_name_ + "': the sample does not deserialise");
    return TakeStatus::kError;
  }
  return status;
}

int ReaderCore::MatchedWriters() const {
  dds_subscription_matched_status_t status;
  if (dds_get_subscription_matched_status(reader_, &status) < 0) return -1;
  return static_cast<int>(status.current_count);
}

bool ReaderCore::WaitForWriters(int count, std::chrono::milliseconds timeout) const {
  return WaitForCount(
      match_waitset_, [this] { return MatchedWriters(); }, count, timeout);
}

}  // namespace craftscan::dds::internal
