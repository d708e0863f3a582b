// USB hot-plug monitoring for USB3 Vision cameras.
//
// A UsbHotplugMonitor follows arrival and departure events from a
// UsbEventSource, keeps the set of USB3 Vision devices present (by serial
// number) and tells a listener, so that a driver whose camera was unplugged
// (DeviceEvent::kLost) can wait for the same serial to come back and
// reconnect without restarting the daemon.
//
//   auto source = MakeLibusbEventSource();         // or a fake in tests
//   UsbHotplugMonitor monitor(std::move(source), [](const UsbDeviceEvent& e) { ... });
//   DriverStatus s = monitor.Start();
//   ...
//   if (monitor.WaitForArrival("SN1234", 10s)) camera->Reconnect();
//
// The real source is libusb's hot-plug API (libusb_hotplug_register_callback)
// served by one event thread. Build machines and CI have no USB bus, so the
// monitor's logic is tested through an injected source (FakeUsbEventSource
// in the tests); the libusb source is only checked to start or refuse
// cleanly and to stop promptly.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "craftscan/drivers/status.h"

namespace craftscan::drivers {

struct UsbDeviceEvent {
  enum class Kind { kArrived, kLeft };
  Kind kind = Kind::kArrived;
  std::uint16_t vendor_id = 0;
  std::uint16_t product_id = 0;
  std::uint8_t bus = 0;
  std::uint8_t address = 0;
  // Serial number string; may be empty when the device could not be opened
  // (then departures are matched by bus and address).
  std::string serial;
  // The device has a USB3 Vision control interface (class 0xEF, subclass
  // 0x05, protocol 0x00).
  bool is_usb3_vision = false;
};

// Where events come from. Start() begins delivering events to `sink` (from
// any thread, one at a time) and returns an error when the source cannot run
// (no hot-plug support, no USB access). Stop() blocks until no further
// event will be delivered; it may be called more than once.
class UsbEventSource {
 public:
  virtual ~UsbEventSource() = default;
  virtual DriverStatus Start(std::function<void(const UsbDeviceEvent&)> sink) = 0;
  virtual void Stop() = 0;
};

// libusb's hot-plug API with its own event thread (1 s poll slices, so Stop
// returns within about a second). Devices present at Start are reported as
// arrivals. Start fails with kUnsupported when libusb cannot initialise or
// lacks hot-plug support on this platform.
std::unique_ptr<UsbEventSource> MakeLibusbEventSource();

// Thread-safe. The listener is called on the source's thread, outside the
// monitor's lock, once per change of the set of present USB3 Vision
// devices (repeated arrivals and departures of unknown devices are
// dropped; other USB devices are ignored).
class UsbHotplugMonitor {
 public:
  using Listener = std::function<void(const UsbDeviceEvent&)>;
  UsbHotplugMonitor(std::unique_ptr<UsbEventSource> source, Listener listener);
  ~UsbHotplugMonitor();  // stops the source
  UsbHotplugMonitor(const UsbHotplugMonitor&) = delete;
  UsbHotplugMonitor& operator=(const UsbHotplugMonitor&) = delete;

  DriverStatus Start();
  void Stop();

  // Serial numbers of the USB3 Vision devices present now.
  std::vector<std::string> Present() const;
  bool IsPresent(const std::string& serial) const;
  // Blocks until a device with `serial` is present (returns true at once if
  // it is) or the timeout passes (false) or Stop() is called (false).
  bool WaitForArrival(const std::string& serial, std::chrono::milliseconds timeout);

 private:
  void OnEvent(const UsbDeviceEvent& event);

  std::unique_ptr<UsbEventSource> source_;
  Listener listener_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::pair<int, int>, std::string> by_port_;  // (bus, address) → serial
  std::set<std::string> present_;
  bool stopped_ = false;
  bool started_ = false;
};

}  // namespace craftscan::drivers
