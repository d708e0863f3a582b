#include "adapter.h"

#include <atomic>
#include <charconv>
#include <cmath>
#include <exception>
#include <memory>
#include <mutex>
#include <string_view>
#include <system_error>
#include <utility>

namespace craftscan::serial_turntable {
namespace {

using drivers::DeviceEvent;
using drivers::DeviceEventInfo;
using drivers::DriverStatus;
using drivers::TurntableState;
using Code = drivers::StatusCode;

constexpr std::string_view kDeviceName = "serial_turntable/turntable";

template <typename T>
bool ParseNumber(const std::string& text, T* value) {
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, *value);
  return ec == std::errc() && ptr == end && !text.empty();
}

bool ParseInt(const std::string& key, const std::string& text, int min, int* value,
              std::string* why) {
  int v = 0;
  if (!ParseNumber(text, &v) || v < min) {
    *why = "config key '" + key + "': '" + text + "' is not an integer >= " + std::to_string(min);
    return false;
  }
  *value = v;
  return true;
}

bool ParseMs(const std::string& key, const std::string& text, int min,
             std::chrono::milliseconds* value, std::string* why) {
  int v = 0;
  if (!ParseInt(key, text, min, &v, why)) return false;
  *value = std::chrono::milliseconds(v);
  return true;
}

bool ParsePositive(const std::string& key, const std::string& text, double* value,
                   std::string* why) {
  double v = 0;
  if (!ParseNumber(text, &v) || !std::isfinite(v) || v <= 0) {
    *why = "config key '" + key + "': '" + text + "' is not a number > 0";
    return false;
  }
  *value = v;
  return true;
}

TurntableState ToApiState(GrblTurntable::State state) {
  switch (state) {
    case GrblTurntable::State::kClosed:
      return TurntableState::kClosed;
    case GrblTurntable::State::kUnhomed:
      return TurntableState::kUnhomed;
    case GrblTurntable::State::kReady:
      return TurntableState::kReady;
    case GrblTurntable::State::kMoving:
      return TurntableState::kMoving;
    case GrblTurntable::State::kFault:
    case GrblTurntable::State::kDeviceLost:
      return TurntableState::kFault;
  }
  return TurntableState::kFault;
}

class SerialTurntable final : public drivers::Turntable {
 public:
  SerialTurntable(GrblTurntableOptions options, drivers::HostServices host)
      : table_(std::move(options)), host_(std::move(host)) {}

  ~SerialTurntable() override { Close(); }

  drivers::TurntableStatus Status() const noexcept override {
    drivers::TurntableStatus status;
    const GrblTurntable::State state = table_.state();
    status.state = ToApiState(state);
    status.homed = state == GrblTurntable::State::kReady || state == GrblTurntable::State::kMoving;
    status.angle_deg = status.homed ? angle_deg_.load() : 0.0;
    if (status.state == TurntableState::kFault) {
      std::lock_guard lock(mutex_);
      status.fault_reason = fault_reason_.empty() ? "fault" : fault_reason_;
    }
    return status;
  }

  DriverStatus Open() noexcept override {
    std::lock_guard call(call_mutex_);
    const TurntableState state = ToApiState(table_.state());
    if (state != TurntableState::kClosed) {
      return drivers::TurntableWrongState("Open", state, "Closed");
    }
    const DriverStatus status = Finish(table_.Connect());
    if (status.ok()) Event(DeviceEvent::kConnected, "connected on " + table_.options().port_path);
    return status;
  }

  DriverStatus Home(std::chrono::milliseconds timeout) noexcept override {
    if (timeout.count() <= 0) return BadTimeout("Home", timeout);
    std::lock_guard call(call_mutex_);
    if (table_.state() == GrblTurntable::State::kDeviceLost) {
      const DriverStatus reconnected = Finish(table_.Reconnect());
      if (!reconnected.ok()) return reconnected;
      Event(DeviceEvent::kReconnected, "reconnected on " + table_.options().port_path);
    }
    const TurntableState state = ToApiState(table_.state());
    if (state != TurntableState::kUnhomed && state != TurntableState::kReady &&
        state != TurntableState::kFault) {
      return drivers::TurntableWrongState("Home", state, "Unhomed, Ready or Fault");
    }
    return Finish(table_.Home(timeout));
  }

  DriverStatus MoveTo(double angle_deg, std::chrono::milliseconds timeout) noexcept override {
    if (timeout.count() <= 0) return BadTimeout("MoveTo", timeout);
    std::lock_guard call(call_mutex_);
    const TurntableState state = ToApiState(table_.state());
    if (state != TurntableState::kReady) {
      return drivers::TurntableWrongState(
          "MoveTo", state, state == TurntableState::kUnhomed ? "Ready (Home() first)" : "Ready");
    }
    return Finish(table_.MoveTo(angle_deg, timeout));
  }

  DriverStatus Abort() noexcept override {
    // Not serialised with the driving calls: it must reach a blocked MoveTo.
    const GrblTurntable::State state = table_.state();
    if (state == GrblTurntable::State::kClosed) {
      return drivers::TurntableWrongState("Abort", TurntableState::kClosed,
                                          "Unhomed, Ready, Moving or Fault");
    }
    if (state != GrblTurntable::State::kMoving) return DriverStatus::Ok();  // nothing to stop
    try {
      return ToDriverStatus(table_.Abort());
    } catch (const std::exception& e) {
      return DriverStatus::Error(Code::kIoError, std::string("Abort: ") + e.what());
    }
  }

  DriverStatus Close() noexcept override {
    if (table_.state() == GrblTurntable::State::kMoving) Abort();  // unblock the move first
    std::lock_guard call(call_mutex_);
    table_.Close();
    std::lock_guard lock(mutex_);
    fault_reason_.clear();
    return DriverStatus::Ok();
  }

 private:
  static DriverStatus BadTimeout(std::string_view call, std::chrono::milliseconds timeout) {
    return DriverStatus::Error(Code::kInvalidArgument, std::string(call) +
                                                           ": timeout must be > 0 ms, got " +
                                                           std::to_string(timeout.count()) + " ms");
  }

  // Converts the result of a driving call and records the angle, the fault
  // reason and a device loss. Called with call_mutex_ held.
  DriverStatus Finish(const serial_turntable::Status& result) noexcept {
    try {
      const GrblTurntable::State state = table_.state();
      // Ready after a move, a homing or a feed-hold abort: the angle it is at.
      if (state == GrblTurntable::State::kReady) angle_deg_ = table_.angle_deg();
      {
        std::lock_guard lock(mutex_);
        if (state == GrblTurntable::State::kFault || state == GrblTurntable::State::kDeviceLost) {
          if (!result.ok()) {
            // "device lost: " unless the code already says it (a hang-up).
            const bool say_lost = state == GrblTurntable::State::kDeviceLost &&
                                  result.code != StatusCode::kDeviceLost;
            fault_reason_ = (say_lost ? "device lost: " : "") + std::string(ToString(result.code)) +
                            ": " + result.message;
          }
        } else {
          fault_reason_.clear();
        }
      }
      if (state == GrblTurntable::State::kDeviceLost && !result.ok() && !lost_reported_) {
        lost_reported_ = true;
        Event(DeviceEvent::kLost, result.message);
      } else if (state != GrblTurntable::State::kDeviceLost) {
        lost_reported_ = false;
      }
      return ToDriverStatus(result);
    } catch (const std::exception& e) {
      return DriverStatus::Error(Code::kFault, e.what());
    }
  }

  void Event(DeviceEvent event, std::string message) noexcept {
    try {
      DeviceEventInfo info;
      info.device = std::string(kDeviceName);
      info.event = event;
      info.message = std::move(message);
      if (host_.events) host_.events(info);
      if (host_.log) {
        host_.log(
            event == DeviceEvent::kLost ? drivers::LogLevel::kWarning : drivers::LogLevel::kInfo,
            info.device + ": " + std::string(drivers::ToString(event)) + ": " + info.message);
      }
    } catch (...) {
      // A failing host callback must not break the driver.
    }
  }

  GrblTurntable table_;
  drivers::HostServices host_;
  std::mutex call_mutex_;     // Open/Home/MoveTo/Close, one at a time
  mutable std::mutex mutex_;  // fault_reason_
  std::string fault_reason_;
  std::atomic<double> angle_deg_{0.0};
  bool lost_reported_ = false;  // call_mutex_
};

class SerialTurntableInstance final : public drivers::DriverInstance {
 public:
  SerialTurntableInstance(GrblTurntableOptions options, drivers::HostServices host)
      : options_(std::move(options)), host_(std::move(host)) {}

  std::unique_ptr<drivers::StereoCamera> CreateCamera(DriverStatus* status) noexcept override {
    if (status) {
      *status = DriverStatus::Error(Code::kUnsupported,
                                    "CreateCamera: the serial_turntable driver provides a "
                                    "turntable only, no camera");
    }
    return nullptr;
  }

  std::unique_ptr<drivers::Turntable> CreateTurntable(DriverStatus* status) noexcept override {
    try {
      auto turntable = std::make_unique<SerialTurntable>(options_, host_);
      if (status) *status = DriverStatus::Ok();
      return turntable;
    } catch (const std::exception& e) {
      if (status) *status = DriverStatus::Error(Code::kFault, e.what());
      return nullptr;
    }
  }

 private:
  GrblTurntableOptions options_;
  drivers::HostServices host_;
};

}  // namespace

bool SerialTurntableOptionsFromConfig(const drivers::DriverConfig& config,
                                      GrblTurntableOptions* options, std::string* why) {
  GrblTurntableOptions o;
  o.abort_mode = GrblTurntableOptions::AbortMode::kFeedHold;  // the plugin's default
  bool have_port = false;
  for (const auto& [key, value] : config) {
    bool ok = true;
    if (key == "port") {
      if (value.empty()) {
        *why = "config key 'port' is empty (the serial device path, e.g. /dev/ttyUSB0)";
        return false;
      }
      o.port_path = value;
      have_port = true;
    } else if (key == "baud") {
      ok = ParseInt(key, value, 1, &o.baud, why);
    } else if (key == "feed_deg_min") {
      ok = ParsePositive(key, value, &o.feed_deg_per_min, why);
    } else if (key == "homing") {
      if (value == "true") {
        o.homing_enabled = true;
      } else if (value == "false") {
        o.homing_enabled = false;
      } else {
        *why = "config key 'homing': '" + value + "' is not true or false";
        return false;
      }
    } else if (key == "settle_ms") {
      ok = ParseMs(key, value, 0, &o.settle_time, why);
    } else if (key == "position_tolerance_deg") {
      ok = ParsePositive(key, value, &o.position_tolerance_deg, why);
    } else if (key == "banner_timeout_ms") {
      ok = ParseMs(key, value, 1, &o.banner_timeout, why);
    } else if (key == "command_timeout_ms") {
      ok = ParseMs(key, value, 1, &o.command_timeout, why);
    } else if (key == "homing_timeout_ms") {
      ok = ParseMs(key, value, 1, &o.homing_timeout, why);
    } else if (key == "move_timeout_margin_ms") {
      ok = ParseMs(key, value, 0, &o.move_timeout_margin, why);
    } else if (key == "move_timeout_factor") {
      ok = ParsePositive(key, value, &o.move_timeout_factor, why);
    } else if (key == "status_poll_ms") {
      ok = ParseMs(key, value, 1, &o.status_poll_interval, why);
    } else if (key == "timeouts_until_lost") {
      ok = ParseInt(key, value, 1, &o.timeouts_until_lost, why);
    } else if (key == "abort") {
      if (value == "feed_hold") {
        o.abort_mode = GrblTurntableOptions::AbortMode::kFeedHold;
      } else if (value == "reset") {
        o.abort_mode = GrblTurntableOptions::AbortMode::kReset;
      } else {
        *why = "config key 'abort': '" + value + "' is not feed_hold or reset";
        return false;
      }
    } else if (key == "hold_timeout_ms") {
      ok = ParseMs(key, value, 1, &o.hold_timeout, why);
    } else {
      *why = "unknown config key '" + key + "'";
      return false;
    }
    if (!ok) return false;
  }
  if (!have_port) {
    *why = "missing config key 'port' (the serial device path, e.g. /dev/ttyUSB0)";
    return false;
  }
  std::string invalid;
  if (!o.IsValid(&invalid)) {
    *why = "invalid config: " + invalid;
    return false;
  }
  *options = std::move(o);
  return true;
}

DriverStatus ToDriverStatus(const Status& status) {
  const auto keep = [&](Code code) { return DriverStatus::Error(code, status.message); };
  const auto tagged = [&](Code code) {
    return DriverStatus::Error(code, std::string(ToString(status.code)) + ": " + status.message);
  };
  switch (status.code) {
    case StatusCode::kOk:
      return DriverStatus::Ok();
    case StatusCode::kInvalidArgument:
      return keep(Code::kInvalidArgument);
    case StatusCode::kWrongState:
      return keep(Code::kWrongState);
    case StatusCode::kIoError:
      return keep(Code::kIoError);
    case StatusCode::kDeviceLost:
      return keep(Code::kDeviceLost);
    case StatusCode::kTimeout:
      return keep(Code::kTimeout);
    case StatusCode::kAborted:
      return keep(Code::kAborted);
    case StatusCode::kProtocolError:
      return tagged(Code::kIoError);
    case StatusCode::kDeviceError:
    case StatusCode::kAlarm:
    case StatusCode::kPositionMismatch:
      return tagged(Code::kFault);
  }
  return tagged(Code::kFault);
}

drivers::DriverInstance* CreateSerialTurntableInstance(const drivers::DriverConfig& config,
                                                       const drivers::HostServices& host,
                                                       DriverStatus* status) noexcept {
  try {
    GrblTurntableOptions options;
    std::string why;
    if (!SerialTurntableOptionsFromConfig(config, &options, &why)) {
      *status = DriverStatus::Error(Code::kInvalidArgument, why);
      return nullptr;
    }
    *status = DriverStatus::Ok();
    return new SerialTurntableInstance(std::move(options), host.WithDefaults());
  } catch (const std::exception& e) {
    *status = DriverStatus::Error(Code::kFault, e.what());
    return nullptr;
  }
}

}  // namespace craftscan::serial_turntable
