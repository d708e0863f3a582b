// Options of the sim driver plugin (craftscan-driver-sim.so): a stereo
// camera pair and a turntable sharing one sim::Scene, so a capture after a
// move shows the object turned.
//
// Config keys (all optional; unknown keys are refused, naming the key):
//   object                  carved_box | egg | embroidery | none   (carved_box)
//   image_size              WxH, px; the default rig scaled to it     (1280x1024)
//   seed                    scene textures and sensor noise           (1)
//   threads                 render threads, 1…256                     (1)
//   turntable_speed_deg_s   0 = moves are instantaneous, else deg/s   (0)
// Fault knobs:
//   drop_frame_every N      frame ids that are multiples of N (N ≥ 2) are
//                           dropped: Capture returns the next id     (0 = off)
//   stall_ms T              each Capture takes T ms; over its timeout it
//                           returns kTimeout                          (0)
//   disconnect_after N      after N frames per connection, captures return
//                           kDeviceLost until Reconnect()             (0 = off)
//   reconnect_failures K    the first K reconnect attempts after each
//                           loss fail                                  (0)
//   turntable_alarm 0|1     every MoveTo fails with kFault (ALARM)     (0)
//   turntable_stall 0|1     moves never arrive: MoveTo times out       (0)
//   reconnect_attempts, reconnect_delay_ms, reconnect_max_delay_ms:
//                           the ReconnectPolicy (5, 200, 5000)
//
// Images: the render of frame id i uses SimStation::Render(scene, i), so a
// capture can be reproduced exactly from SimRigOptions/SimSceneOptions.
// Exposure: the rig's linear exposure is exposure_us / 10000 · 10^(gain_db / 20)
// (10 ms at 0 dB = the renderer's default exposure 1.0); it must be ≤ 100.
#pragma once

#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/host.h"
#include "craftscan/drivers/reconnect.h"
#include "craftscan/sim/station.h"

namespace craftscan::sim {

struct SimDriverOptions {
  ObjectType object = ObjectType::kCarvedBox;
  cv::Size image_size{1280, 1024};  // px
  std::uint64_t seed = 1;
  int threads = 1;
  double turntable_speed_deg_s = 0;  // 0 = instantaneous
  int drop_frame_every = 0;          // 0 = off, else ≥ 2
  int stall_ms = 0;                  // ≥ 0
  int disconnect_after = 0;          // frames; 0 = off
  int reconnect_failures = 0;        // ≥ 0
  bool turntable_alarm = false;
  bool turntable_stall = false;
  drivers::ReconnectPolicy reconnect;

  bool IsValid(std::string* why) const;  // names the offending key
};

// Parses and validates a driver config; false with *why naming the key.
bool SimDriverOptionsFromConfig(const drivers::DriverConfig& config, SimDriverOptions* options,
                                std::string* why);

// The rig the driver renders with (the default rig scaled to image_size,
// exposure from the camera settings) and the scene it shares.
RigOptions SimRigOptions(const SimDriverOptions& options,
                         const drivers::CameraSettings& settings = {});
SceneOptions SimSceneOptions(const SimDriverOptions& options);
double SimExposure(const drivers::CameraSettings& settings);  // the rig's linear exposure

}  // namespace craftscan::sim
