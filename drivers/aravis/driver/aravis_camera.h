// The Aravis (GigE Vision) stereo camera driver: two cameras opened by device
// id or IP address, both software-triggered per Capture() and paired.
//
// Config keys (DriverConfig; unknown keys are rejected with kInvalidArgument):
//   left, right          device id ("<vendor>-<serial>", serial, ...) or IP
//                        address of each camera (required; arv_camera_new)
//   packet_size          GVSP packet size in bytes (optional; default: keep the
//                        camera's value)
//   buffers              stream buffers per camera (optional, 1..64, default 4)
//   reconnect_attempts   ReconnectPolicy::max_attempts (optional, default 5)
//   reconnect_delay_ms   ReconnectPolicy::initial_delay (optional, default 200)
//
// Only PixelFormat::kMono8 is supported (Configure gives kUnsupported
// otherwise). Gain is passed to arv_camera_set_gain (dB on cameras with a
// float Gain; cameras with only GainRaw, like Aravis's fake, get the raw
// value). StereoFrame timestamps are the host clock (HostServices::now_ns)
// when each trigger was sent; frame ids count triggers per camera from 0
// after Open (gaps = frames lost).
//
// Loss: an Aravis "control-lost" signal, or a failed control transaction, or
// a capture timeout after which the camera no longer answers a register read,
// moves to Lost (kDeviceLost). A capture timeout with a responsive camera is
// kTimeout. Note the liveness check and every control call on a dead camera
// take Aravis's GVCP timeout (~2.5 s) on top of the caller's timeout.
// Reconnect() drops the old ArvCamera/ArvStream objects and creates new ones.
#pragma once

#include <cstdint>
#include <memory>

#include "craftscan/drivers/plugin.h"

namespace craftscan::aravis {

struct StreamStatistics {
  std::uint64_t completed = 0, failures = 0, underruns = 0;  // arv_stream_get_statistics
  std::uint64_t resent = 0, missing = 0;                     // arv_gv_stream_get_statistics
};

class AravisStereoCamera : public drivers::StereoCamera {
 public:
  // Statistics of the current stream of each camera (or of the last one,
  // after Stop/loss); zeros before the first Start.
  virtual StreamStatistics Statistics(bool left) const noexcept = 0;
};

// Checks the config; null with the status set on failure.
std::unique_ptr<AravisStereoCamera> CreateAravisCamera(const drivers::DriverConfig& config,
                                                       const drivers::HostServices& host,
                                                       drivers::DriverStatus* status) noexcept;

drivers::DriverInstance* CreateAravisInstance(const drivers::DriverConfig& config,
                                              const drivers::HostServices& host,
                                              drivers::DriverStatus* status) noexcept;

}  // namespace craftscan::aravis
