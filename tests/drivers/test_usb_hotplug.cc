// USB3 Vision hot-plug monitoring. These machines have no USB bus, so the
// monitor's logic is driven by an injected event source (FakeUsbEventSource);
// the libusb source is only checked to start or refuse cleanly and to stop
// promptly.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <thread>

#include "craftscan/drivers/usb_hotplug.h"
#include "fake_usb_source.h"

namespace craftscan::drivers {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

using test::FakeUsbEventSource;

UsbDeviceEvent Arrived(std::string serial, std::uint8_t address, bool u3v = true) {
  return test::UsbArrived(std::move(serial), address, u3v);
}
UsbDeviceEvent Left(std::uint8_t address) { return test::UsbLeft(address); }

struct Recorder {
  std::vector<std::pair<UsbDeviceEvent::Kind, std::string>> events;
  UsbHotplugMonitor::Listener Listener() {
    return [this](const UsbDeviceEvent& e) { events.emplace_back(e.kind, e.serial); };
  }
};

TEST(UsbHotplug, ArrivalAndDepartureOfUsb3VisionCamerasAreReported) {
  auto source = std::make_unique<FakeUsbEventSource>();
  FakeUsbEventSource* fake = source.get();
  Recorder rec;
  UsbHotplugMonitor monitor(std::move(source), rec.Listener());
  ASSERT_TRUE(monitor.Start().ok());
  fake->Emit(Arrived("LEFT01", 5));
  fake->Emit(Arrived("RIGHT02", 6));
  fake->Emit(Arrived("", 7, /*u3v=*/false));  // a keyboard: ignored
  fake->Emit(Arrived("LEFT01", 5));           // repeated: dropped
  EXPECT_TRUE(monitor.IsPresent("LEFT01"));
  EXPECT_TRUE(monitor.IsPresent("RIGHT02"));
  EXPECT_EQ(monitor.Present().size(), 2u);
  fake->Emit(Left(7));  // the keyboard leaves: not ours
  fake->Emit(Left(5));  // the left camera is unplugged (departures carry no serial)
  EXPECT_FALSE(monitor.IsPresent("LEFT01"));
  fake->Emit(Left(5));  // twice: dropped
  ASSERT_EQ(rec.events.size(), 3u);
  EXPECT_EQ(rec.events[0], std::make_pair(UsbDeviceEvent::Kind::kArrived, std::string("LEFT01")));
  EXPECT_EQ(rec.events[1], std::make_pair(UsbDeviceEvent::Kind::kArrived, std::string("RIGHT02")));
  EXPECT_EQ(rec.events[2], std::make_pair(UsbDeviceEvent::Kind::kLeft, std::string("LEFT01")));
  // Re-plugged on another address: reported again.
  fake->Emit(Arrived("LEFT01", 9));
  EXPECT_TRUE(monitor.IsPresent("LEFT01"));
  ASSERT_EQ(rec.events.size(), 4u);
  EXPECT_EQ(rec.events[3].first, UsbDeviceEvent::Kind::kArrived);
}

TEST(UsbHotplug, DeviceWithoutSerialIsTrackedByPort) {
  auto source = std::make_unique<FakeUsbEventSource>();
  FakeUsbEventSource* fake = source.get();
  Recorder rec;
  UsbHotplugMonitor monitor(std::move(source), rec.Listener());
  ASSERT_TRUE(monitor.Start().ok());
  fake->Emit(Arrived("", 4));
  EXPECT_TRUE(monitor.IsPresent("usb:2:4"));
  fake->Emit(Left(4));
  EXPECT_TRUE(monitor.Present().empty());
  ASSERT_EQ(rec.events.size(), 2u);
  EXPECT_EQ(rec.events[1].second, "usb:2:4");
}

TEST(UsbHotplug, WaitForArrivalWakesWhenTheCameraIsReplugged) {
  auto source = std::make_unique<FakeUsbEventSource>();
  FakeUsbEventSource* fake = source.get();
  UsbHotplugMonitor monitor(std::move(source), nullptr);
  ASSERT_TRUE(monitor.Start().ok());
  // Absent: times out after about the timeout.
  auto t0 = Clock::now();
  EXPECT_FALSE(monitor.WaitForArrival("CAM7", 50ms));
  const auto waited = Clock::now() - t0;
  EXPECT_GE(waited, 45ms);
  EXPECT_LT(waited, 1s);
  // Plugged in from another thread while we wait.
  std::thread plug([&] {
    std::this_thread::sleep_for(30ms);
    fake->Emit(Arrived("CAM7", 3));
  });
  t0 = Clock::now();
  EXPECT_TRUE(monitor.WaitForArrival("CAM7", 5s));
  EXPECT_LT(Clock::now() - t0, 2s);
  plug.join();
  // Present: returns at once.
  EXPECT_TRUE(monitor.WaitForArrival("CAM7", 0ms));
}

TEST(UsbHotplug, StopWakesWaitersAndStopsTheSource) {
  auto source = std::make_unique<FakeUsbEventSource>();
  FakeUsbEventSource* fake = source.get();
  UsbHotplugMonitor monitor(std::move(source), nullptr);
  ASSERT_TRUE(monitor.Start().ok());
  EXPECT_EQ(monitor.Start().code, StatusCode::kWrongState);
  std::thread stopper([&] {
    std::this_thread::sleep_for(30ms);
    monitor.Stop();
  });
  const auto t0 = Clock::now();
  EXPECT_FALSE(monitor.WaitForArrival("NEVER", 10s));
  EXPECT_LT(Clock::now() - t0, 2s);
  stopper.join();
  EXPECT_EQ(fake->stops.load(), 1);
  monitor.Stop();  // idempotent
  EXPECT_EQ(fake->stops.load(), 1);
}

TEST(UsbHotplug, SourceThatCannotStartIsAClearError) {
  auto source = std::make_unique<FakeUsbEventSource>();
  source->fail_start = true;
  UsbHotplugMonitor monitor(std::move(source), nullptr);
  const DriverStatus s = monitor.Start();
  EXPECT_EQ(s.code, StatusCode::kUnsupported);
  EXPECT_NE(s.message.find("no USB"), std::string::npos);
  UsbHotplugMonitor none(nullptr, nullptr);
  EXPECT_EQ(none.Start().code, StatusCode::kInvalidArgument);
}

// The real libusb source on a machine without a USB bus (or without USB
// access in a container): it either starts (and reports nothing or the
// host's devices) or refuses with kUnsupported; either way Stop returns
// within its 1 s poll slice.
TEST(UsbHotplug, LibusbSourceStartsOrRefusesCleanly) {
  std::atomic<int> events{0};
  UsbHotplugMonitor monitor(MakeLibusbEventSource(), [&](const UsbDeviceEvent&) { ++events; });
  const DriverStatus s = monitor.Start();
  if (!s.ok()) {
    EXPECT_EQ(s.code, StatusCode::kUnsupported) << s.ToString();
    EXPECT_NE(s.message.find("USB hot-plug"), std::string::npos) << s.message;
    return;
  }
  std::this_thread::sleep_for(50ms);
  const auto t0 = Clock::now();
  monitor.Stop();
  EXPECT_LT(Clock::now() - t0, 3s);
  std::printf("libusb hot-plug source ran; %d USB3 Vision arrivals seen\n", events.load());
}

}  // namespace
}  // namespace craftscan::drivers
