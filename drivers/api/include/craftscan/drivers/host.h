// What the host gives a driver: configuration and services (logger, clock,
// sleep, device events). Drivers use only these for time and waiting, so
// tests can run them on a fake clock.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <string_view>

namespace craftscan::drivers {

// Driver configuration: string keys and values (the daemon's config file
// section for the device, already parsed). Each driver documents its keys and
// rejects unknown ones with kInvalidArgument naming the key.
using DriverConfig = std::map<std::string, std::string>;

enum class LogLevel { kDebug, kInfo, kWarning, kError };
std::string_view ToString(LogLevel level);

// Device connection events reported to the host (see reconnect.h).
enum class DeviceEvent {
  kConnected,    // Open() succeeded
  kLost,         // the driver detected the loss of the device
  kReconnected,  // a reconnect attempt succeeded; settings were re-applied
  kGaveUp,       // every reconnect attempt of the policy failed
};
std::string_view ToString(DeviceEvent event);

struct DeviceEventInfo {
  std::string device;  // e.g. "sim/camera"
  DeviceEvent event = DeviceEvent::kConnected;
  int attempt = 0;  // reconnect attempt number (1…) for kReconnected/kGaveUp, else 0
  std::string message;
};

// Services the host passes to a driver. Every member may be empty; use
// WithDefaults() to fill the empty ones. The functions may be called from any
// driver thread, so they must be thread-safe.
struct HostServices {
  std::function<void(LogLevel level, std::string_view message)> log;  // empty: discard
  std::function<std::int64_t()> now_ns;  // monotonic clock (ns); empty: std::chrono::steady_clock
  std::function<void(std::int64_t duration_ns)> sleep_ns;    // empty: std::this_thread::sleep_for
  std::function<void(const DeviceEventInfo& event)> events;  // empty: discard

  // A copy with every empty member replaced by its default.
  HostServices WithDefaults() const;
};

}  // namespace craftscan::drivers
