// The recorder behind craftscan-record: subscribes to the capture, cloud and
// disparity topics of one or more stations (DESIGN.md "DDS interface") and
// stores every sample it takes in an Archive. Malformed samples (sizes that
// do not match their data, bad names) are logged and skipped.
//
// One reader thread per station and topic. A reader keeps up to
// `reader_history` samples that the recorder has not yet taken; when the
// disk falls further behind the station than that, the oldest unread sample
// of that topic is dropped by DDS (the station is never slowed down).
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/record/archive.h"

namespace craftscan::record {

// What to record.
// kModels: each session's mesh.glb, fetched from the station (`get`, which
// needs `token`) when its fused cloud is published (the model is durable by
// then); a session without one (no mesh) is logged and skipped.
enum class RecordKind { kCaptures, kClouds, kDisparity, kModels };
std::string_view ToString(RecordKind kind);  // "captures", "clouds", "disparity", "models"
// Parses one of the names above; false for anything else.
bool RecordKindFromString(std::string_view text, RecordKind* kind);

struct RecorderOptions {
  std::vector<std::string> stations;  // station ids (valid, distinct, ≥ 1)
  uint32_t domain_id = 0;             // DDS domain, 0..230
  // Cyclone configuration (XML, file or list; see dds::ParticipantOptions);
  // empty = CYCLONEDDS_URI or Cyclone's defaults.
  std::string dds_config;
  std::vector<RecordKind> what = {RecordKind::kClouds, RecordKind::kCaptures};  // ≥ 1, distinct
  uint64_t max_items = 0;      // stop after this many stored items (a capture = 1); 0 = no limit
  int32_t reader_history = 8;  // unread samples kept per topic, 1..64
  int32_t poll_ms = 200;       // how often reader threads look at the stop flag, ms, 10..1000
  // For kModels: a token the station's tokens file lists (observer is
  // enough); required with kModels.
  std::string token;

  // False with *why (may be null) naming the first field that is wrong.
  bool IsValid(std::string* why) const;
};

// What one station's samples became.
struct StationStats {
  std::string station;
  uint64_t files = 0;  // data files stored
  uint64_t bytes = 0;
  uint64_t captures = 0, clouds = 0, disparities = 0, models = 0;  // items stored
  uint64_t malformed = 0;  // samples skipped: inconsistent sizes or data
  uint64_t refused = 0;    // samples skipped: bad session name or view index
  uint64_t too_large = 0;  // items larger than the limit (rotate policy)
  uint64_t failed = 0;     // items not stored for an I/O error
};

enum class StopReason {
  kNone,          // still running
  kRequested,     // Stop() (signal, --duration)
  kCountReached,  // max_items stored
  kLimitReached,  // the archive is full (LimitPolicy::kStop)
  kError,         // an I/O error; RecorderSummary::message says which
};
std::string_view ToString(StopReason reason);

struct RecorderSummary {
  std::vector<StationStats> stations;  // in the order of RecorderOptions::stations
  uint64_t items = 0;                  // items stored, all stations
  uint64_t rotated_files = 0;          // oldest files deleted to stay under the limit
  uint64_t rotated_bytes = 0;
  ArchiveTotals archive;  // what the archive holds now
  StopReason reason = StopReason::kNone;
  std::string message;  // details of the reason
};

class Recorder {
 public:
  // Joins the domain, creates the readers (so samples published after this
  // returns are seen once discovery has matched them) and starts the reader
  // threads. `archive` must not be null. Null with *error (may be null) for
  // invalid options or a DDS failure. The caller blocks SIGINT/SIGTERM
  // first if it handles them in one thread (the threads inherit the mask).
  static std::unique_ptr<Recorder> Create(const RecorderOptions& options,
                                          std::shared_ptr<Archive> archive, std::string* error);
  ~Recorder();  // Stop()
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  // Waits up to `timeout` for the recorder to finish on its own (count,
  // limit or error). True once it has. Thread-safe.
  bool WaitUntilDone(std::chrono::milliseconds timeout);

  // Stops taking samples and joins the threads; an item being stored is
  // completed first. `message` explains a kRequested stop (e.g. "SIGTERM").
  // Idempotent; keeps the first reason. Thread-safe.
  void Stop(const std::string& message = "stop requested");

  RecorderSummary Summary() const;  // thread-safe, any time

  struct State;  // implementation (recorder.cc)

 private:
  explicit Recorder(std::shared_ptr<State> state);
  std::shared_ptr<State> state_;
};

}  // namespace craftscan::record
