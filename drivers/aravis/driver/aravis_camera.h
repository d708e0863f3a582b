// The Aravis stereo camera driver (GigE Vision and USB3 Vision): two cameras
// triggered together and paired, behind drivers::StereoCamera. Implementation
// header of craftscan-driver-aravis.so; tests use it through the static
// library craftscan_aravis_driver.
//
// Config keys (DriverConfig; unknown keys are refused with kInvalidArgument
// naming the key):
//   left, right          required. Which camera: an IPv4 address (opened
//                        directly), or a device id ("Aravis-Fake-GV01"), serial
//                        number, physical id (MAC) or discovered address as
//                        Aravis lists them (arv_get_device_id, _serial_nbr,
//                        _physical_id, _address; one discovery, ~1 s); failing
//                        those, Aravis's own lookup (GigE user-defined name,
//                        "<vendor>-<serial>"). Two devices matching: refused.
//   packet_size          GVSP packet size (bytes, 220..65000; GigE only;
//                        default: keep the camera's)
//   buffers              stream buffers per camera (1..64, default 4)
//   frame_rate_hz        AcquisitionFrameRate (Hz, > 0; default: keep). Open
//                        checks the camera has it (else kUnsupported) and
//                        that the value is within its bounds (else
//                        kInvalidArgument naming the bounds).
//   camera_pixel_format  the format on the wire: auto (default) or a GenICam
//                        name (Mono8, Mono10, Mono12, Mono16, RGB8, BGR8,
//                        BayerRG8/BG8/GB8/GR8) both cameras must offer.
//                        Conversions to the API's mono8/bgr8 and refusals:
//                        pixel_conversion.h. auto picks per camera and per
//                        Configure: no conversion first.
//   trigger              software (default: Capture() fires TriggerSoftware
//                        on both) or hardware (TriggerMode On with
//                        trigger_source; Capture() waits for the pair the
//                        next pulse exposes)
//   trigger_source       hardware only: TriggerSource entry (default Line0);
//                        Open refuses one the camera does not offer, naming
//                        those it does
//   trigger_activation   hardware only: TriggerActivation entry (default
//                        RisingEdge where the camera has the feature)
//   pairing              frame_id (default) or timestamp (pairing.h)
//   pair_tolerance_us    timestamp pairing: the largest |left − right| device
//                        timestamp difference of a pair (µs, default 1000)
//   pair_retries         software trigger: how often a refused pair is
//                        re-triggered before Capture fails with kIoError
//                        (0..100, default 2). Refused: timestamps outside the
//                        tolerance, or frame ids out of step with no partner
//                        frame within 100 ms (a missed or spurious frame on
//                        one side; the counts then restart). A stale frame
//                        (older id) is dropped and its partner awaited.
//   usb_hotplug          auto (default: follow USB3 Vision cameras with a
//                        libusb hot-plug monitor), on (follow both cameras by
//                        serial whatever their transport; tests, whose fakes
//                        are GigE), off
//   reconnect_attempts   ReconnectPolicy::max_attempts (1..1000, default 5)
//   reconnect_delay_ms   ReconnectPolicy::initial_delay (0..60000, default 200)
//
// StereoFrame: timestamps are the host clock (HostServices::now_ns) when the
// software trigger was sent, or (hardware trigger) when the frame's leader
// arrived; frame ids count triggers (software) or the camera's frames
// (hardware) per camera from 0 after Open, so gaps are lost frames. Capture
// timeouts are real time (network I/O), not the host clock. Frames queued
// before a Capture() are dropped: a capture shows the scene after the call.
//
// info(): model and sensor size are read from the cameras at Open(); before
// the first Open they are empty.
//
// Loss: Aravis's control-lost signal, a failed control transaction, a
// capture timeout after which the camera no longer answers a register read,
// or (hot-plug) the USB departure of a camera's serial moves to Lost
// (kDeviceLost, DeviceEvent::kLost; a departure is reported at once when no
// call is in progress). Control calls on a dead GigE camera take Aravis's
// GVCP timeout (~2.5 s): detecting a loss in Capture() takes that long, and
// releasing a dead camera's objects (Close(), or the first Reconnect()
// attempt while it is still gone) ~7.5 s (stream and device finalizers).
// Reconnect() drops every ArvCamera/ArvStream and makes new ones (stopping
// any acquisition the camera still runs for the old connection); an attempt
// while a followed camera is unplugged fails at once, and its re-arrival
// ends the current back-off delay (ReconnectWake).
//
// Thread safety: as drivers::StereoCamera; the accessors below too.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "craftscan/drivers/plugin.h"
#include "craftscan/drivers/usb_hotplug.h"

namespace craftscan::aravis {

struct StreamStatistics {
  std::uint64_t completed = 0, failures = 0, underruns = 0;  // arv_stream_get_statistics
  std::uint64_t resent = 0, missing = 0;                     // arv_gv_stream_get_statistics
};

struct PairingStatistics {
  std::uint64_t pairs = 0;    // pairs delivered since Open
  std::uint64_t refused = 0;  // pairs re-triggered for their timestamps
  std::uint64_t dropped = 0;  // frames dropped waiting for their partner
  std::int64_t max_difference_ns =
      0;  // largest |left − right| device timestamp of a delivered pair
};

// How a camera of the pair was found (after Open; empty before).
struct CameraIdentity {
  std::string opened_as;     // what arv_camera_new was given: address or device id
  std::string serial;        // the camera's serial number
  std::string transport;     // "GigE Vision" or "USB3 Vision"
  std::string pixel_format;  // camera format in use after Configure ("Mono8"), else ""
};

class AravisStereoCamera : public drivers::StereoCamera {
 public:
  // Statistics of the current stream of each camera (or of the last one,
  // after Stop/loss); zeros before the first Start.
  virtual StreamStatistics Statistics(bool left) const noexcept = 0;
  virtual PairingStatistics Pairing() const noexcept = 0;
  virtual CameraIdentity Identity(bool left) const noexcept = 0;
  // True while a USB hot-plug monitor follows the cameras (Open..Close).
  virtual bool FollowsUsbHotplug() const noexcept = 0;
};

// Where USB hot-plug events come from; empty: libusb (MakeLibusbEventSource).
using UsbSourceFactory = std::function<std::unique_ptr<drivers::UsbEventSource>()>;

// Checks the config; null with the status set on failure.
std::unique_ptr<AravisStereoCamera> CreateAravisCamera(const drivers::DriverConfig& config,
                                                       const drivers::HostServices& host,
                                                       drivers::DriverStatus* status,
                                                       UsbSourceFactory usb_source = {}) noexcept;

// The plugin's factory (libusb hot-plug source).
drivers::DriverInstance* CreateAravisInstance(const drivers::DriverConfig& config,
                                              const drivers::HostServices& host,
                                              drivers::DriverStatus* status) noexcept;

}  // namespace craftscan::aravis
