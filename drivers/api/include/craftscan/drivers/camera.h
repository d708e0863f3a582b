// StereoCamera: a synchronised camera pair delivering StereoFrames.
//
// State machine (checked at every call; a call in another state returns
// kWrongState and changes nothing):
//
//            Open()         Configure()              Start()
//   Closed ─────────► Open ───────────► Configured ─────────► Streaming ──┐
//     ▲                                  │  ▲    ▲ ◄─────────  │  ▲      │ Capture()
//     │ Close()                          └──┘    │   Stop()    │  └──────┘
//     │ from any state            Configure()    │             │
//     │                           (again)        │ Reconnect() │ device gone
//     │                                          │ (state      │ (any call)
//     │                                          │ before the  ▼
//     │                                          └─ loss) ─── Lost
//
// - Open: Closed → Open. Connects to the device; reports DeviceEvent::kConnected.
// - Configure(settings): Open|Configured → Configured. Not while Streaming
//   (Stop first). Invalid settings: kInvalidArgument, state unchanged.
// - Start: Configured → Streaming.  Stop: Streaming → Configured.
// - Capture(timeout): Streaming only. kTimeout leaves the state unchanged.
// - Any call that finds the device gone returns kDeviceLost, moves to Lost and
//   reports DeviceEvent::kLost; in Lost every call but state(), Close() and
//   Reconnect() returns kDeviceLost.
// - Reconnect: Lost only. Tries to reconnect following the driver's
//   ReconnectPolicy (reconnect.h), re-applies the last settings and restarts
//   streaming if it was streaming; kOk returns to the state before the loss.
//   If every attempt fails: kDeviceLost, still Lost (the host may retry).
// - Close: from any state to Closed; releases the device.
//
// Thread safety: every method may be called from any thread; a driver
// serialises calls internally. No method throws (noexcept across plugins).
#pragma once

#include <chrono>
#include <cstdint>
#include <string>
#include <string_view>

#include <opencv2/core.hpp>

#include "craftscan/drivers/status.h"

namespace craftscan::drivers {

enum class CameraState { kClosed, kOpen, kConfigured, kStreaming, kLost };
std::string_view ToString(CameraState state);  // "Closed", "Open", ...

enum class PixelFormat { kBgr8, kMono8 };       // cv::Mat CV_8UC3 (BGR) or CV_8UC1
std::string_view ToString(PixelFormat format);  // "bgr8", "mono8"
bool PixelFormatFromString(std::string_view text, PixelFormat* format);

// Settings applied to both cameras of the pair.
struct CameraSettings {
  double exposure_us = 10000;  // exposure time (µs), > 0
  double gain_db = 0;          // analogue gain (dB), ≥ 0
  PixelFormat pixel_format = PixelFormat::kBgr8;
  // Region of interest in sensor pixels; an empty rect means the full sensor.
  // Must lie inside the sensor (the driver checks; kInvalidArgument if not).
  cv::Rect roi;

  bool IsValid(std::string* why) const;  // device-independent checks; names the field
  bool operator==(const CameraSettings&) const = default;
};

// One image of a pair.
struct CameraImage {
  cv::Mat image;                  // CV_8UC3 BGR or CV_8UC1, size of the ROI
  std::int64_t timestamp_ns = 0;  // exposure start on the host's clock (HostServices::now_ns)
  std::uint64_t frame_id = 0;     // counts up per camera from 0 after Open; gaps = dropped frames
};

struct StereoFrame {
  CameraImage left, right;
  // A station with a pattern projector: the left camera's image of the same
  // view with the projector off (same size and format as left.image), for
  // the model's colours; the pair shows the pattern, for matching. Empty
  // without a projector.
  cv::Mat texture_left;
  CameraSettings settings;  // the settings in force when the pair was exposed
};

// Fixed facts about the pair.
struct CameraInfo {
  std::string model;     // e.g. "sim stereo pair"
  cv::Size sensor_size;  // full-sensor image size (px) of each camera
};

class StereoCamera {
 public:
  virtual ~StereoCamera() = default;

  virtual CameraState state() const noexcept = 0;
  virtual CameraInfo info() const noexcept = 0;

  virtual DriverStatus Open() noexcept = 0;
  virtual DriverStatus Configure(const CameraSettings& settings) noexcept = 0;
  virtual DriverStatus Start() noexcept = 0;
  // Waits at most `timeout` for the next pair; on kOk fills *frame.
  virtual DriverStatus Capture(std::chrono::milliseconds timeout, StereoFrame* frame) noexcept = 0;
  virtual DriverStatus Stop() noexcept = 0;
  virtual DriverStatus Reconnect() noexcept = 0;
  virtual DriverStatus Close() noexcept = 0;
};

// The standard wrong-state error: "<call>: camera is <state>, needs <needed>".
DriverStatus CameraWrongState(std::string_view call, CameraState state, std::string_view needed);

}  // namespace craftscan::drivers
