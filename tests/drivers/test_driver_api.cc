// Driver API: status strings, settings checks, the reconnect back-off
// schedule and the order of device events, on a fake clock (no real sleeps).
#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <vector>

#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/reconnect.h"
#include "craftscan/drivers/status.h"
#include "craftscan/drivers/turntable.h"
#include "fake_host.h"

namespace craftscan::drivers {
namespace {

using std::chrono::milliseconds;
using test::FakeHost;

constexpr std::int64_t kMs = 1'000'000;

TEST(DriverStatus, ToStringNamesCodeAndMessage) {
  EXPECT_EQ(DriverStatus::Ok().ToString(), "ok");
  EXPECT_TRUE(DriverStatus::Ok().ok());
  const DriverStatus status = CameraWrongState("Capture", CameraState::kConfigured, "Streaming");
  EXPECT_FALSE(status.ok());
  EXPECT_EQ(status.ToString(), "wrong_state: Capture: camera is Configured, needs Streaming");
  EXPECT_EQ(TurntableWrongState("MoveTo", TurntableState::kUnhomed, "Ready").message,
            "MoveTo: turntable is Unhomed, needs Ready");
  EXPECT_EQ(ToString(StatusCode::kDeviceLost), "device_lost");
  EXPECT_EQ(ToString(DeviceEvent::kGaveUp), "gave_up");
}

TEST(CameraSettings, Validity) {
  std::string why;
  EXPECT_TRUE(CameraSettings{}.IsValid(&why)) << why;
  CameraSettings s;
  s.exposure_us = 0;
  EXPECT_FALSE(s.IsValid(&why));
  EXPECT_NE(why.find("exposure_us"), std::string::npos);
  s = {};
  s.gain_db = -1;
  EXPECT_FALSE(s.IsValid(&why));
  EXPECT_NE(why.find("gain_db"), std::string::npos);
  s = {};
  s.roi = cv::Rect(0, 0, 10, 0);
  EXPECT_FALSE(s.IsValid(&why));
  EXPECT_NE(why.find("roi"), std::string::npos);
  PixelFormat format;
  ASSERT_TRUE(PixelFormatFromString("mono8", &format));
  EXPECT_EQ(format, PixelFormat::kMono8);
  EXPECT_FALSE(PixelFormatFromString("rgb16", &format));
}

TEST(ReconnectPolicy, BackOffDoublesUpToTheCap) {
  ReconnectPolicy policy;
  policy.max_attempts = 7;
  policy.initial_delay = milliseconds(100);
  policy.multiplier = 2;
  policy.max_delay = milliseconds(1000);
  ASSERT_TRUE(policy.IsValid(nullptr));
  const std::vector<int> expected_ms = {100, 200, 400, 800, 1000, 1000, 1000};
  for (int i = 1; i <= 7; ++i) EXPECT_EQ(policy.DelayBefore(i).count(), expected_ms[i - 1]) << i;
  EXPECT_EQ(policy.DelayBefore(1000).count(), 1000);  // saturates, no overflow
}

TEST(ReconnectPolicy, RejectsBadFields) {
  std::string why;
  ReconnectPolicy p;
  p.max_attempts = 0;
  EXPECT_FALSE(p.IsValid(&why));
  EXPECT_NE(why.find("max_attempts"), std::string::npos);
  p = {};
  p.multiplier = 0.5;
  EXPECT_FALSE(p.IsValid(&why));
  EXPECT_NE(why.find("multiplier"), std::string::npos);
  p = {};
  p.max_delay = milliseconds(10);
  EXPECT_FALSE(p.IsValid(&why));
  EXPECT_NE(why.find("max_delay"), std::string::npos);
}

ReconnectPolicy FastPolicy() {
  ReconnectPolicy policy;
  policy.max_attempts = 4;
  policy.initial_delay = milliseconds(50);
  policy.multiplier = 3;
  policy.max_delay = milliseconds(400);
  return policy;
}

TEST(Reconnector, SucceedsOnThirdAttemptAfterTheScheduledDelays) {
  FakeHost fake;
  Reconnector reconnector(FastPolicy(), fake.services(), "test/cam");
  reconnector.ReportConnected();
  reconnector.ReportLost("cable pulled");
  const std::int64_t start = fake.now_ns();
  std::vector<std::int64_t> attempt_times;
  const DriverStatus status = reconnector.Run([&] {
    attempt_times.push_back(fake.now_ns() - start);
    return attempt_times.size() < 3 ? DriverStatus::Error(StatusCode::kDeviceLost, "still gone")
                                    : DriverStatus::Ok();
  });
  EXPECT_TRUE(status.ok()) << status.ToString();
  // Delays 50, 150, 400 (cap) ms before the attempts: attempts at 50, 200, 600 ms.
  EXPECT_EQ(attempt_times, (std::vector<std::int64_t>{50 * kMs, 200 * kMs, 600 * kMs}));
  EXPECT_EQ(fake.sleeps(), (std::vector<std::int64_t>{50 * kMs, 150 * kMs, 400 * kMs}));
  EXPECT_EQ(fake.event_kinds(),
            (std::vector<DeviceEvent>{DeviceEvent::kConnected, DeviceEvent::kLost,
                                      DeviceEvent::kReconnected}));
  const auto events = fake.events();
  EXPECT_EQ(events.back().attempt, 3);
  EXPECT_EQ(events.back().device, "test/cam");
  EXPECT_EQ(events[1].message, "cable pulled");
}

TEST(Reconnector, GivesUpAfterMaxAttempts) {
  FakeHost fake;
  Reconnector reconnector(FastPolicy(), fake.services(), "test/table");
  reconnector.ReportLost("serial I/O error");
  int attempts = 0;
  const DriverStatus status = reconnector.Run([&] {
    ++attempts;
    return DriverStatus::Error(StatusCode::kIoError, "no such device");
  });
  EXPECT_EQ(status.code, StatusCode::kDeviceLost);
  EXPECT_NE(status.message.find("gave up after 4"), std::string::npos) << status.message;
  EXPECT_NE(status.message.find("no such device"), std::string::npos) << status.message;
  EXPECT_EQ(attempts, 4);
  EXPECT_EQ(fake.sleeps(), (std::vector<std::int64_t>{50 * kMs, 150 * kMs, 400 * kMs, 400 * kMs}));
  EXPECT_EQ(fake.event_kinds(),
            (std::vector<DeviceEvent>{DeviceEvent::kLost, DeviceEvent::kGaveUp}));
  EXPECT_EQ(fake.events().back().attempt, 4);
}

TEST(Reconnector, StopsOnANonTransientError) {
  FakeHost fake;
  Reconnector reconnector(FastPolicy(), fake.services(), "test/cam");
  int attempts = 0;
  const DriverStatus status = reconnector.Run([&] {
    ++attempts;
    return DriverStatus::Error(StatusCode::kInvalidArgument, "settings refused");
  });
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_EQ(attempts, 1);
  EXPECT_TRUE(fake.events().empty());
}

TEST(HostServices, DefaultsFillEveryMember) {
  const HostServices host = HostServices{}.WithDefaults();
  ASSERT_TRUE(host.log && host.now_ns && host.sleep_ns && host.events);
  const std::int64_t t0 = host.now_ns();
  host.sleep_ns(1 * kMs);
  EXPECT_GE(host.now_ns() - t0, 1 * kMs);
  host.log(LogLevel::kInfo, "discarded");
  host.events({});
}

TEST(Reconnector, WakeEndsTheBackOffWithinOneSlice) {
  FakeHost fake;
  ReconnectPolicy policy;
  policy.max_attempts = 3;
  policy.initial_delay = milliseconds(60'000);  // a long back-off the wake must cut short
  policy.max_delay = milliseconds(60'000);
  Reconnector reconnector(policy, fake.services(), "test/usbcam");
  ReconnectWake wake;
  // The device "arrives" during the 3rd slice of the first delay.
  int slices = 0;
  fake.OnSleep([&] {
    if (++slices == 3) wake.Notify();
  });
  const std::int64_t start = fake.now_ns();
  std::vector<std::int64_t> attempt_times;
  const DriverStatus status = reconnector.Run(
      [&] {
        attempt_times.push_back(fake.now_ns() - start);
        return DriverStatus::Ok();
      },
      &wake, milliseconds(10));
  fake.OnSleep({});
  EXPECT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(attempt_times, (std::vector<std::int64_t>{30 * kMs}));  // not 60 s
  EXPECT_EQ(fake.sleeps(), (std::vector<std::int64_t>{10 * kMs, 10 * kMs, 10 * kMs}));
  EXPECT_FALSE(wake.Consume());  // consumed by Run

  // A wake notified before Run skips the first delay entirely; without one,
  // the whole delay is slept (in slices).
  FakeHost fake2;
  Reconnector r2(policy, fake2.services(), "test/usbcam");
  wake.Notify();
  int attempts = 0;
  const DriverStatus gave_up = r2.Run(
      [&] {
        ++attempts;
        return DriverStatus::Error(StatusCode::kDeviceLost, "unplugged");
      },
      &wake, milliseconds(20'000));
  EXPECT_EQ(gave_up.code, StatusCode::kDeviceLost);
  EXPECT_EQ(attempts, 3);
  std::int64_t total = 0;
  for (std::int64_t ns : fake2.sleeps()) total += ns;
  EXPECT_EQ(total, 2 * 60'000 * kMs);    // delays before attempts 2 and 3 only
  EXPECT_EQ(fake2.sleeps().size(), 6u);  // 3 slices each
}

}  // namespace
}  // namespace craftscan::drivers
