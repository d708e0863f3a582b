// A fake host for driver tests: a manual clock that sleeps advance (no real
// waiting), and recorders for log lines, sleeps and device events.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "craftscan/drivers/host.h"

namespace craftscan::drivers::test {

class FakeHost {
 public:
  // HostServices bound to this object (which must outlive them).
  HostServices services() {
    HostServices host;
    host.log = [this](LogLevel level, std::string_view message) {
      std::lock_guard lock(mutex_);
      log_.push_back(std::string(ToString(level)) + ": " + std::string(message));
    };
    host.now_ns = [this] { return now_ns_.load(); };
    host.sleep_ns = [this](std::int64_t ns) {
      std::function<void()> hook;
      {
        std::lock_guard lock(mutex_);
        sleeps_.push_back(ns);
        hook = on_sleep_;
      }
      now_ns_ += ns;
      if (hook) hook();
    };
    host.events = [this](const DeviceEventInfo& event) {
      std::lock_guard lock(mutex_);
      events_.push_back(event);
    };
    return host;
  }

  std::int64_t now_ns() const { return now_ns_.load(); }
  void Advance(std::int64_t ns) { now_ns_ += ns; }
  // Called after every sleep (on the sleeping thread), e.g. to Abort a move.
  void OnSleep(std::function<void()> hook) {
    std::lock_guard lock(mutex_);
    on_sleep_ = std::move(hook);
  }
  std::vector<std::int64_t> sleeps() const {
    std::lock_guard lock(mutex_);
    return sleeps_;
  }
  std::vector<DeviceEventInfo> events() const {
    std::lock_guard lock(mutex_);
    return events_;
  }
  std::vector<DeviceEvent> event_kinds() const {
    std::vector<DeviceEvent> kinds;
    for (const auto& e : events()) kinds.push_back(e.event);
    return kinds;
  }
  std::vector<std::string> log() const {
    std::lock_guard lock(mutex_);
    return log_;
  }

 private:
  std::atomic<std::int64_t> now_ns_{1'000'000'000};
  mutable std::mutex mutex_;
  std::vector<std::int64_t> sleeps_;
  std::vector<DeviceEventInfo> events_;
  std::vector<std::string> log_;
  std::function<void()> on_sleep_;
};

}  // namespace craftscan::drivers::test
