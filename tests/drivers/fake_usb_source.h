// A fake USB event source for tests: these machines have no USB bus, so the
// hot-plug logic (UsbHotplugMonitor and the drivers using it) is driven by
// events the test emits. Emit() delivers on the calling thread.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <utility>

#include "craftscan/drivers/usb_hotplug.h"

namespace craftscan::drivers::test {

class FakeUsbEventSource : public UsbEventSource {
 public:
  DriverStatus Start(std::function<void(const UsbDeviceEvent&)> sink) override {
    if (fail_start) return DriverStatus::Error(StatusCode::kUnsupported, "fake: no USB");
    std::lock_guard lock(mutex_);
    sink_ = std::move(sink);
    ++starts;
    return DriverStatus::Ok();
  }
  void Stop() override {
    std::lock_guard lock(mutex_);
    sink_ = nullptr;
    ++stops;
  }
  // Delivers `event` now (nothing when not started).
  void Emit(const UsbDeviceEvent& event) {
    std::function<void(const UsbDeviceEvent&)> sink;
    {
      std::lock_guard lock(mutex_);
      sink = sink_;
    }
    if (sink) sink(event);
  }
  bool started() {
    std::lock_guard lock(mutex_);
    return static_cast<bool>(sink_);
  }

  bool fail_start = false;
  std::atomic<int> starts{0}, stops{0};

 private:
  std::mutex mutex_;
  std::function<void(const UsbDeviceEvent&)> sink_;
};

// A USB3 Vision camera (or, with u3v false, another device) arriving on bus 2.
inline UsbDeviceEvent UsbArrived(std::string serial, std::uint8_t address, bool u3v = true) {
  UsbDeviceEvent e;
  e.kind = UsbDeviceEvent::Kind::kArrived;
  e.vendor_id = 0x2676;
  e.product_id = 0xba02;
  e.bus = 2;
  e.address = address;
  e.serial = std::move(serial);
  e.is_usb3_vision = u3v;
  return e;
}

// The device at bus 2 / `address` leaving (departures carry no serial).
inline UsbDeviceEvent UsbLeft(std::uint8_t address) {
  UsbDeviceEvent e;
  e.kind = UsbDeviceEvent::Kind::kLeft;
  e.bus = 2;
  e.address = address;
  return e;
}

}  // namespace craftscan::drivers::test
