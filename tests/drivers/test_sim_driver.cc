// The sim driver plugin beyond the conformance suite: the camera pair and the
// turntable share one scene (a capture after a move equals a direct render at
// that angle), move timing on the injected clock, and the fault knobs. The
// devices are loaded through the PluginLoader; the direct renders use
// craftscan_sim with the driver's own option mapping (driver_options.h).
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <numbers>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/drivers/plugin_loader.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "fake_host.h"

namespace craftscan::sim {
namespace {

using drivers::CameraSettings;
using drivers::CameraState;
using drivers::DeviceEvent;
using drivers::DriverConfig;
using drivers::DriverStatus;
using drivers::StatusCode;
using drivers::StereoFrame;
using drivers::TurntableState;
using std::chrono::milliseconds;

constexpr std::int64_t kMs = 1'000'000;
constexpr milliseconds kTimeout{5000};

const DriverConfig kSmall = {{"image_size", "320x256"}, {"threads", "2"}, {"seed", "7"}};

DriverConfig With(DriverConfig config, const DriverConfig& extra) {
  for (const auto& [key, value] : extra) config.insert_or_assign(key, value);
  return config;
}

bool BitIdentical(const cv::Mat& a, const cv::Mat& b) {
  return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0;
}

class SimDriver : public ::testing::Test {
 protected:
  // Loads craftscan-driver-sim.so and creates an instance with `config`,
  // its camera (opened, configured, streaming) and its turntable (opened).
  void Create(const DriverConfig& config, const CameraSettings& settings = {}) {
    drivers::PluginLoader loader(CRAFTSCAN_PLUGIN_DIR);
    std::shared_ptr<const drivers::Plugin> plugin;
    DriverStatus status = loader.Load("sim", &plugin);
    ASSERT_TRUE(status.ok()) << status.ToString();
    std::unique_ptr<drivers::DriverInstance> instance;
    status = plugin->CreateInstance(config, fake_.services(), &instance);
    ASSERT_TRUE(status.ok()) << status.ToString();
    camera_ = instance->CreateCamera(&status);
    ASSERT_TRUE(camera_) << status.ToString();
    turntable_ = instance->CreateTurntable(&status);
    ASSERT_TRUE(turntable_) << status.ToString();
    ASSERT_TRUE(camera_->Open().ok());
    status = camera_->Configure(settings);
    ASSERT_TRUE(status.ok()) << status.ToString();
    ASSERT_TRUE(camera_->Start().ok());
    ASSERT_TRUE(turntable_->Open().ok());
  }

  StereoFrame Capture() {
    StereoFrame frame;
    const DriverStatus status = camera_->Capture(kTimeout, &frame);
    EXPECT_TRUE(status.ok()) << status.ToString();
    return frame;
  }

  drivers::test::FakeHost fake_;
  std::unique_ptr<drivers::StereoCamera> camera_;
  std::unique_ptr<drivers::Turntable> turntable_;
};

TEST_F(SimDriver, CaptureAfterAMoveShowsTheObjectTurned) {
  const DriverConfig config = With(kSmall, {{"object", "carved_box"}});
  ASSERT_NO_FATAL_FAILURE(Create(config));
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());
  const StereoFrame at0 = Capture();
  ASSERT_TRUE(turntable_->MoveTo(60, kTimeout).ok());
  const StereoFrame at60 = Capture();

  // The object turned: many pixels changed by far more than the noise.
  cv::Mat diff;
  cv::absdiff(at0.left.image, at60.left.image, diff);
  cv::Mat changed = diff.reshape(1) > 40;
  EXPECT_GT(cv::countNonZero(changed), 2000);

  // Exactly what the simulated station renders for that scene at 60°.
  SimDriverOptions options;
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig(config, &options, &why)) << why;
  auto station = SimStation::Create(SimRigOptions(options, at60.settings), &why);
  ASSERT_TRUE(station) << why;
  auto scene = Scene::Create(SimSceneOptions(options), &why);
  ASSERT_TRUE(scene) << why;
  const StereoRender direct0 = station->Render(*scene, at0.left.frame_id);
  scene->SetTurntableAngle(60 * std::numbers::pi / 180);
  const StereoRender direct60 = station->Render(*scene, at60.left.frame_id);
  ASSERT_TRUE(direct0.IsUsable() && direct60.IsUsable());
  EXPECT_TRUE(BitIdentical(at0.left.image, direct0.left));
  EXPECT_TRUE(BitIdentical(at0.right.image, direct0.right));
  EXPECT_TRUE(BitIdentical(at60.left.image, direct60.left));
  EXPECT_TRUE(BitIdentical(at60.right.image, direct60.right));
  EXPECT_FALSE(BitIdentical(direct0.left, direct60.left));
}

TEST_F(SimDriver, MovesTakeTheirTimeOnTheInjectedClock) {
  ASSERT_NO_FATAL_FAILURE(Create(With(kSmall, {{"turntable_speed_deg_s", "30"}})));
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());
  const std::int64_t t0 = fake_.now_ns();
  ASSERT_TRUE(turntable_->MoveTo(60, kTimeout).ok());
  const std::int64_t took = fake_.now_ns() - t0;
  EXPECT_GE(took, 2000 * kMs);  // 60° at 30°/s
  EXPECT_LE(took, 2010 * kMs);
  for (std::int64_t sleep : fake_.sleeps()) EXPECT_LE(sleep, 5 * kMs);
  // Too short a timeout: stopped where it got to, Fault.
  const DriverStatus status = turntable_->MoveTo(0, milliseconds(500));
  EXPECT_EQ(status.code, StatusCode::kTimeout) << status.ToString();
  const drivers::TurntableStatus s = turntable_->Status();
  EXPECT_EQ(s.state, TurntableState::kFault);
  EXPECT_NEAR(s.angle_deg, 45, 0.5);
  EXPECT_NE(s.fault_reason.find("not done within 500 ms"), std::string::npos) << s.fault_reason;
}

TEST_F(SimDriver, InstantaneousMovesDoNotWait) {
  ASSERT_NO_FATAL_FAILURE(Create(kSmall));
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());
  const std::int64_t t0 = fake_.now_ns();
  ASSERT_TRUE(turntable_->MoveTo(270, kTimeout).ok());
  EXPECT_EQ(fake_.now_ns(), t0);
  EXPECT_TRUE(fake_.sleeps().empty());
}

TEST(SimDriverThreads, AbortFromAnotherThreadOnTheRealClock) {
  // The one test on the real clock: a 9 s move aborted from a second thread
  // as soon as it is Moving; MoveTo must return within a few ms of that.
  drivers::PluginLoader loader(CRAFTSCAN_PLUGIN_DIR);
  std::shared_ptr<const drivers::Plugin> plugin;
  ASSERT_TRUE(loader.Load("sim", &plugin).ok());
  std::unique_ptr<drivers::DriverInstance> instance;
  ASSERT_TRUE(
      plugin->CreateInstance(With(kSmall, {{"turntable_speed_deg_s", "10"}}), {}, &instance).ok());
  DriverStatus status;
  auto turntable = instance->CreateTurntable(&status);
  ASSERT_TRUE(turntable) << status.ToString();
  ASSERT_TRUE(turntable->Open().ok());
  ASSERT_TRUE(turntable->Home(kTimeout).ok());
  const auto start = std::chrono::steady_clock::now();
  std::thread aborter([&] {
    while (turntable->Status().state != TurntableState::kMoving) std::this_thread::yield();
    EXPECT_TRUE(turntable->Abort().ok());
  });
  status = turntable->MoveTo(90, std::chrono::seconds(30));
  aborter.join();
  EXPECT_EQ(status.code, StatusCode::kAborted) << status.ToString();
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(1));
  EXPECT_EQ(turntable->Status().state, TurntableState::kReady);
  EXPECT_LT(turntable->Status().angle_deg, 10);
}

TEST_F(SimDriver, TurntableAlarmFaultsUntilHomed) {
  ASSERT_NO_FATAL_FAILURE(Create(With(kSmall, {{"turntable_alarm", "1"}})));
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());
  DriverStatus status = turntable_->MoveTo(30, kTimeout);
  EXPECT_EQ(status.code, StatusCode::kFault) << status.ToString();
  drivers::TurntableStatus s = turntable_->Status();
  EXPECT_EQ(s.state, TurntableState::kFault);
  EXPECT_NE(s.fault_reason.find("ALARM"), std::string::npos) << s.fault_reason;
  status = turntable_->MoveTo(30, kTimeout);
  EXPECT_EQ(status.code, StatusCode::kWrongState) << status.ToString();
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());  // clears the fault
  s = turntable_->Status();
  EXPECT_EQ(s.state, TurntableState::kReady);
  EXPECT_TRUE(s.fault_reason.empty());
}

TEST_F(SimDriver, TurntableStallTimesOut) {
  ASSERT_NO_FATAL_FAILURE(Create(With(kSmall, {{"turntable_stall", "1"}})));
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());
  const std::int64_t t0 = fake_.now_ns();
  const DriverStatus status = turntable_->MoveTo(30, milliseconds(200));
  EXPECT_EQ(status.code, StatusCode::kTimeout) << status.ToString();
  EXPECT_EQ(fake_.now_ns() - t0, 200 * kMs);
  const drivers::TurntableStatus s = turntable_->Status();
  EXPECT_EQ(s.state, TurntableState::kFault);
  EXPECT_NEAR(s.angle_deg, 0, 1e-9);
  EXPECT_NE(s.fault_reason.find("turntable_stall"), std::string::npos) << s.fault_reason;
}

TEST_F(SimDriver, DroppedFramesLeaveGapsInTheIds) {
  ASSERT_NO_FATAL_FAILURE(
      Create(With(kSmall, {{"drop_frame_every", "3"}, {"image_size", "64x48"}})));
  std::vector<std::uint64_t> ids;
  for (int i = 0; i < 5; ++i) {
    const StereoFrame frame = Capture();
    EXPECT_EQ(frame.left.frame_id, frame.right.frame_id);
    ids.push_back(frame.left.frame_id);
  }
  EXPECT_EQ(ids, (std::vector<std::uint64_t>{0, 1, 2, 4, 5}));
}

TEST_F(SimDriver, StalledCapturesTimeOut) {
  ASSERT_NO_FATAL_FAILURE(Create(With(kSmall, {{"stall_ms", "50"}, {"image_size", "64x48"}})));
  StereoFrame frame;
  std::int64_t t0 = fake_.now_ns();
  DriverStatus status = camera_->Capture(milliseconds(20), &frame);
  EXPECT_EQ(status.code, StatusCode::kTimeout) << status.ToString();
  EXPECT_EQ(fake_.now_ns() - t0, 20 * kMs);
  EXPECT_EQ(camera_->state(), CameraState::kStreaming);
  t0 = fake_.now_ns();
  status = camera_->Capture(milliseconds(100), &frame);
  EXPECT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(fake_.now_ns() - t0, 50 * kMs);
  EXPECT_EQ(frame.left.timestamp_ns, fake_.now_ns());
}

TEST_F(SimDriver, ReconnectFollowsThePolicyAndMayGiveUp) {
  ASSERT_NO_FATAL_FAILURE(Create(With(kSmall, {{"image_size", "64x48"},
                                               {"disconnect_after", "1"},
                                               {"reconnect_failures", "4"},
                                               {"reconnect_attempts", "3"},
                                               {"reconnect_delay_ms", "100"},
                                               {"reconnect_max_delay_ms", "250"}})));
  Capture();
  StereoFrame frame;
  ASSERT_EQ(camera_->Capture(kTimeout, &frame).code, StatusCode::kDeviceLost);
  DriverStatus status = camera_->Reconnect();  // attempts 1–3 fail (4 failures queued)
  EXPECT_EQ(status.code, StatusCode::kDeviceLost) << status.ToString();
  EXPECT_NE(status.message.find("gave up after 3"), std::string::npos) << status.message;
  EXPECT_EQ(camera_->state(), CameraState::kLost);
  status = camera_->Reconnect();  // one more failure, then back
  EXPECT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(camera_->state(), CameraState::kStreaming);
  EXPECT_EQ(fake_.sleeps(),
            (std::vector<std::int64_t>{100 * kMs, 200 * kMs, 250 * kMs, 100 * kMs, 200 * kMs}));
  const auto events = fake_.events();
  ASSERT_EQ(events.size(), 5u);
  EXPECT_EQ(fake_.event_kinds(),
            (std::vector<DeviceEvent>{DeviceEvent::kConnected, DeviceEvent::kConnected,
                                      DeviceEvent::kLost, DeviceEvent::kGaveUp,
                                      DeviceEvent::kReconnected}));
  EXPECT_EQ(events[0].device, "sim/camera");
  EXPECT_EQ(events[1].device, "sim/turntable");
  EXPECT_EQ(events[4].attempt, 2);
  Capture();  // a new connection: one more frame before the next loss
}

TEST_F(SimDriver, ExposureAndGainBrightenTheImage) {
  CameraSettings dark;
  dark.exposure_us = 4000;
  ASSERT_NO_FATAL_FAILURE(Create(With(kSmall, {{"image_size", "64x48"}}), dark));
  const double dark_mean = cv::mean(Capture().left.image)[1];
  ASSERT_TRUE(camera_->Stop().ok());
  CameraSettings bright = dark;
  bright.gain_db = 6;
  ASSERT_TRUE(camera_->Configure(bright).ok());
  ASSERT_TRUE(camera_->Start().ok());
  const double bright_mean = cv::mean(Capture().left.image)[1];
  EXPECT_GT(bright_mean, dark_mean * 1.5);
  ASSERT_TRUE(camera_->Stop().ok());
  CameraSettings too_much;
  too_much.exposure_us = 2e6;  // linear exposure 200 > 100
  EXPECT_EQ(camera_->Configure(too_much).code, StatusCode::kInvalidArgument);
}

TEST(SimDriverOptions, ParsesAndRefusesKeys) {
  SimDriverOptions o;
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig({{"object", "embroidery"},
                                          {"image_size", "640x512"},
                                          {"seed", "3"},
                                          {"threads", "2"},
                                          {"turntable_alarm", "true"}},
                                         &o, &why))
      << why;
  EXPECT_EQ(o.object, ObjectType::kEmbroidery);
  EXPECT_EQ(o.image_size, cv::Size(640, 512));
  EXPECT_EQ(o.seed, 3u);
  EXPECT_TRUE(o.turntable_alarm);
  const RigOptions rig = SimRigOptions(o);
  EXPECT_DOUBLE_EQ(rig.left.focal_px, RigOptions().left.focal_px / 2);
  EXPECT_EQ(rig.num_threads, 2);
  EXPECT_DOUBLE_EQ(rig.exposure, 1.0);  // 10 ms at 0 dB

  EXPECT_FALSE(SimDriverOptionsFromConfig({{"objcet", "egg"}}, &o, &why));
  EXPECT_NE(why.find("'objcet'"), std::string::npos) << why;
  EXPECT_FALSE(SimDriverOptionsFromConfig({{"image_size", "640"}}, &o, &why));
  EXPECT_NE(why.find("image_size"), std::string::npos) << why;
  EXPECT_FALSE(SimDriverOptionsFromConfig({{"object", "teapot"}}, &o, &why));
  EXPECT_NE(why.find("object"), std::string::npos) << why;
  EXPECT_FALSE(SimDriverOptionsFromConfig({{"drop_frame_every", "1"}}, &o, &why));
  EXPECT_NE(why.find("drop_frame_every"), std::string::npos) << why;
  EXPECT_FALSE(SimDriverOptionsFromConfig({{"reconnect_attempts", "0"}}, &o, &why));
  EXPECT_NE(why.find("max_attempts"), std::string::npos) << why;
}

}  // namespace
}  // namespace craftscan::sim
