// What craftscan-record's two recorders (recorder.cc: the archive;
// mcap_recorder.cc: MCAP) share: checking the stations and reader options,
// and the loop of a reader thread. Not installed.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <spdlog/spdlog.h>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

namespace craftscan::record::internal {

inline constexpr int32_t kMaxReaderHistory = 64;  // 64 unread 8 MB captures = 512 MB at most

inline bool SetError(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

// Stations (≥ 1, valid, distinct), domain, reader_history 1..64 and
// poll_ms 10..1000; false with *why (may be null) naming the first wrong one.
inline bool CheckReaderOptions(const std::vector<std::string>& stations, uint32_t domain_id,
                               int32_t reader_history, int32_t poll_ms, std::string* why) {
  if (stations.empty()) return SetError(why, "stations: at least one station is needed");
  std::set<std::string> seen;
  for (const std::string& station : stations) {
    std::string reason;
    if (!dds::IsValidStationId(station, &reason)) return SetError(why, "stations: " + reason);
    if (!seen.insert(station).second) {
      return SetError(why, "stations: '" + station + "' is given twice");
    }
  }
  if (domain_id > dds::kMaxDomainId) {
    return SetError(why, "domain_id " + std::to_string(domain_id) + " is above " +
                             std::to_string(dds::kMaxDomainId));
  }
  if (reader_history < 1 || reader_history > kMaxReaderHistory) {
    return SetError(why, "reader_history must be 1.." + std::to_string(kMaxReaderHistory));
  }
  if (poll_ms < 10 || poll_ms > 1000) return SetError(why, "poll_ms must be 10..1000");
  return true;
}

// A reader thread's loop: take(timeout, &error) (a dds::TakeStatus) until
// `stopping`, handle() after each sample taken; a DDS error is logged once
// per topic and followed by a pause of poll_ms.
template <typename Take, typename Handle>
void TakeUntilStopped(const std::string& topic, int32_t poll_ms, const std::atomic<bool>& stopping,
                      Take take, Handle handle) {
  std::string error;
  bool error_logged = false;
  while (!stopping) {
    switch (take(std::chrono::milliseconds(poll_ms), &error)) {
      case dds::TakeStatus::kOk:
        handle();
        break;
      case dds::TakeStatus::kTimeout:
        break;
      case dds::TakeStatus::kError:
        if (!error_logged) {
          spdlog::warn("{}: {} (further errors of this topic not logged)", topic, error);
          error_logged = true;
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(poll_ms));
        break;
    }
  }
}

}  // namespace craftscan::record::internal
