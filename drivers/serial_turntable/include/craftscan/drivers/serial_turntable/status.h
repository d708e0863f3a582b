// The result of every serial turntable call: a code and a message that names
// the device and the cause. No exception leaves this library's public API.
#pragma once

#include <string>
#include <string_view>

namespace craftscan::serial_turntable {

enum class StatusCode {
  kOk,
  kInvalidArgument,   // bad option or argument (NaN angle, unknown baud rate, ...)
  kWrongState,        // call not allowed in the current state (see GrblTurntable)
  kIoError,           // open/configure/read/write failed (errno text in the message)
  kDeviceLost,        // the device went away: EIO, ENXIO, hang-up (POLLHUP)
  kTimeout,           // no (complete) answer within the configured time
  kProtocolError,     // unexpected or malformed reply, wrong firmware version
  kDeviceError,       // the controller answered error:N
  kAlarm,             // the controller raised ALARM:N or reports the Alarm state
  kPositionMismatch,  // reported position differs from the commanded one
  kAborted,           // Abort() interrupted the call
};

std::string_view ToString(StatusCode code);

struct Status {
  StatusCode code = StatusCode::kOk;
  std::string message;  // empty when ok

  bool ok() const { return code == StatusCode::kOk; }
  static Status Ok() { return {}; }
};

// "<code>: <message>", for logs and test failure output.
std::string ToString(const Status& status);

}  // namespace craftscan::serial_turntable
