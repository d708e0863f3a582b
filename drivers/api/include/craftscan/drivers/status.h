// DriverStatus: the result of every driver call. Drivers report failures as
// status codes with a message; no exception crosses a driver boundary
// (DESIGN.md "Drivers", "Errors").
#pragma once

#include <string>
#include <string_view>

namespace craftscan::drivers {

enum class StatusCode {
  kOk,
  kWrongState,       // the call is not allowed in the device's current state
  kTimeout,          // the device did not answer or finish in time
  kDeviceLost,       // the device is gone; Reconnect() may bring it back
  kInvalidArgument,  // a bad setting, config key or argument (the message names it)
  kIoError,          // a transport error (serial, network, file)
  kFault,            // the device reports a fault (turntable alarm, limit switch)
  kUnsupported,      // the driver or device cannot do this
  kAborted,          // the operation was cancelled by Abort()
};
std::string_view ToString(StatusCode code);  // "ok", "wrong_state", "timeout", ...

struct DriverStatus {
  StatusCode code = StatusCode::kOk;
  std::string message;  // empty for kOk; otherwise says what failed and why

  bool ok() const { return code == StatusCode::kOk; }
  static DriverStatus Ok() { return {}; }
  static DriverStatus Error(StatusCode code, std::string message) {
    return {code, std::move(message)};
  }
  // "wrong_state: Capture: camera is Configured, needs Streaming".
  std::string ToString() const;
};

}  // namespace craftscan::drivers
