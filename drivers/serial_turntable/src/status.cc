#include "craftscan/drivers/serial_turntable/status.h"

namespace craftscan::serial_turntable {

std::string_view ToString(StatusCode code) {
  switch (code) {
    case StatusCode::kOk:
      return "ok";
    case StatusCode::kInvalidArgument:
      return "invalid argument";
    case StatusCode::kWrongState:
      return "wrong state";
    case StatusCode::kIoError:
      return "I/O error";
    case StatusCode::kDeviceLost:
      return "device lost";
    case StatusCode::kTimeout:
      return "timeout";
    case StatusCode::kProtocolError:
      return "protocol error";
    case StatusCode::kDeviceError:
      return "device error";
    case StatusCode::kAlarm:
      return "alarm";
    case StatusCode::kPositionMismatch:
      return "position mismatch";
    case StatusCode::kAborted:
      return "aborted";
  }
  return "unknown";
}

std::string ToString(const Status& status) {
  std::string out(ToString(status.code));
  if (!status.message.empty()) out += ": " + status.message;
  return out;
}

}  // namespace craftscan::serial_turntable
