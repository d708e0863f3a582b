// String conversions, defaults and checks of the driver API types.
#include <chrono>
#include <string>
#include <thread>

#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/host.h"
#include "craftscan/drivers/status.h"
#include "craftscan/drivers/turntable.h"

namespace craftscan::drivers {

std::string_view ToString(StatusCode code) {
  switch (code) {
    case StatusCode::kOk:
      return "ok";
    case StatusCode::kWrongState:
      return "wrong_state";
    case StatusCode::kTimeout:
      return "timeout";
    case StatusCode::kDeviceLost:
      return "device_lost";
    case StatusCode::kInvalidArgument:
      return "invalid_argument";
    case StatusCode::kIoError:
      return "io_error";
    case StatusCode::kFault:
      return "fault";
    case StatusCode::kUnsupported:
      return "unsupported";
    case StatusCode::kAborted:
      return "aborted";
  }
  return "unknown";
}

std::string DriverStatus::ToString() const {
  std::string text(drivers::ToString(code));
  if (!message.empty()) text += ": " + message;
  return text;
}

std::string_view ToString(LogLevel level) {
  switch (level) {
    case LogLevel::kDebug:
      return "debug";
    case LogLevel::kInfo:
      return "info";
    case LogLevel::kWarning:
      return "warning";
    case LogLevel::kError:
      return "error";
  }
  return "unknown";
}

std::string_view ToString(DeviceEvent event) {
  switch (event) {
    case DeviceEvent::kConnected:
      return "connected";
    case DeviceEvent::kLost:
      return "lost";
    case DeviceEvent::kReconnected:
      return "reconnected";
    case DeviceEvent::kGaveUp:
      return "gave_up";
  }
  return "unknown";
}

HostServices HostServices::WithDefaults() const {
  HostServices host = *this;
  if (!host.log) host.log = [](LogLevel, std::string_view) {};
  if (!host.now_ns) {
    host.now_ns = [] {
      return std::chrono::duration_cast<std::chrono::nanoseconds>(
                 std::chrono::steady_clock::now().time_since_epoch())
          .count();
    };
  }
  if (!host.sleep_ns) {
    host.sleep_ns = [](std::int64_t ns) {
      if (ns > 0) std::this_thread::sleep_for(std::chrono::nanoseconds(ns));
    };
  }
  if (!host.events) host.events = [](const DeviceEventInfo&) {};
  return host;
}

std::string_view ToString(CameraState state) {
  switch (state) {
    case CameraState::kClosed:
      return "Closed";
    case CameraState::kOpen:
      return "Open";
    case CameraState::kConfigured:
      return "Configured";
    case CameraState::kStreaming:
      return "Streaming";
    case CameraState::kLost:
      return "Lost";
  }
  return "unknown";
}

std::string_view ToString(PixelFormat format) {
  switch (format) {
    case PixelFormat::kBgr8:
      return "bgr8";
    case PixelFormat::kMono8:
      return "mono8";
  }
  return "unknown";
}

bool PixelFormatFromString(std::string_view text, PixelFormat* format) {
  for (PixelFormat f : {PixelFormat::kBgr8, PixelFormat::kMono8}) {
    if (text == ToString(f)) {
      *format = f;
      return true;
    }
  }
  return false;
}

namespace {
bool Fail(std::string* why, const char* message) {
  if (why) *why = message;
  return false;
}
}  // namespace

bool CameraSettings::IsValid(std::string* why) const {
  if (!(exposure_us > 0 && exposure_us <= 1e7)) {
    return Fail(why, "exposure_us must be in (0, 1e7] µs");
  }
  if (!(gain_db >= 0 && gain_db <= 48)) return Fail(why, "gain_db must be in [0, 48] dB");
  if (pixel_format != PixelFormat::kBgr8 && pixel_format != PixelFormat::kMono8) {
    return Fail(why, "pixel_format must be bgr8 or mono8");
  }
  if (roi.x < 0 || roi.y < 0 || roi.width < 0 || roi.height < 0) {
    return Fail(why, "roi must have non-negative origin and size");
  }
  if ((roi.width == 0) != (roi.height == 0)) {
    return Fail(why, "roi must be empty (full sensor) or have both width and height > 0");
  }
  return true;
}

DriverStatus CameraWrongState(std::string_view call, CameraState state, std::string_view needed) {
  return DriverStatus::Error(StatusCode::kWrongState, std::string(call) + ": camera is " +
                                                          std::string(ToString(state)) +
                                                          ", needs " + std::string(needed));
}

std::string_view ToString(TurntableState state) {
  switch (state) {
    case TurntableState::kClosed:
      return "Closed";
    case TurntableState::kUnhomed:
      return "Unhomed";
    case TurntableState::kReady:
      return "Ready";
    case TurntableState::kMoving:
      return "Moving";
    case TurntableState::kFault:
      return "Fault";
  }
  return "unknown";
}

DriverStatus TurntableWrongState(std::string_view call, TurntableState state,
                                 std::string_view needed) {
  return DriverStatus::Error(StatusCode::kWrongState, std::string(call) + ": turntable is " +
                                                          std::string(ToString(state)) +
                                                          ", needs " + std::string(needed));
}

}  // namespace craftscan::drivers
