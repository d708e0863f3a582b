// The driver conformance suite: written against the abstract StereoCamera and
// Turntable interfaces (camera.h, turntable.h) and run for every driver
// profile below, each loaded THROUGH the PluginLoader from the build's plugin
// directory. A driver joins the suite with one DriverProfile; what it talks
// to (an emulator, fake devices) is its TestRig, set up per test. Fault tests
// need a driver or rig that can make the fault; they skip otherwise.
//
//   driver            camera part                    turntable part
//   sim               all, loss by config            all (fake clock)
//   aravis            all, loss by killing a fake    - (camera only)
//                     camera (Aravis fakes in a
//                     private network namespace)
//   serial_turntable  - (turntable only)             all, against the PTY GRBL
//                                                    emulator in real time
//
// Host services are a fake clock (FakeHost): the sim waits on it; the aravis
// and serial drivers wait on real I/O with real timeouts.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "aravis_fakes.h"
#include "craftscan/drivers/plugin_loader.h"
#include "fake_host.h"
#include "test_paths.h"
#include "turntable_emulator.h"

namespace craftscan::drivers {
namespace {

using std::chrono::milliseconds;
using Clock = std::chrono::steady_clock;

// What a driver under test talks to, set up for each test.
class TestRig {
 public:
  virtual ~TestRig() = default;
  // Added to the profile's config (e.g. the emulator's PTY as `port`).
  virtual DriverConfig Config() const { return {}; }
  // A camera loss from outside the driver: LoseCamera() makes a device
  // vanish mid-stream, RestoreCamera() brings it back power-cycled.
  virtual bool CanLoseCamera() const { return false; }
  virtual void LoseCamera() {}
  virtual void RestoreCamera() {}
  // The platter's true angle (deg from home), when the rig knows it.
  virtual std::optional<double> TurntableAngle() const { return std::nullopt; }
};

struct DriverProfile {
  std::string name;     // test name suffix
  std::string plugin;   // craftscan-driver-<plugin>.so
  DriverConfig config;  // a small, fast device
  // Makes the rig for one test. Null with *skip set: the environment lacks
  // what the rig needs (the test skips); null without: the test fails.
  // Empty function: no rig.
  std::function<std::unique_ptr<TestRig>(std::string* skip)> make_rig;
  // Added to `config`: the camera is lost after `frames_before_loss` frames
  // per connection. Empty: the loss comes from the rig (LoseCamera), if it can.
  DriverConfig loss_config;
  int frames_before_loss = 2;
  // Added to `config`: moves slow enough to be aborted or time out
  // (turntable tests skip without it).
  DriverConfig slow_move_config;
  // Real time per host sleep during slow moves, so that a driver waiting on
  // the fake clock (sim) is seen Moving by another thread.
  milliseconds real_time_per_sleep{0};
  bool has_camera = true;     // false: the camera tests skip
  bool has_turntable = true;  // false: the turntable tests skip
  // After Abort() mid-move: Ready at the stop angle (true) or Unhomed (the
  // driver lost the position).
  bool abort_keeps_position = true;
};

void PrintTo(const DriverProfile& profile, std::ostream* os) { *os << profile.name; }

// The GRBL emulator on a PTY (tests/tools/turntable-emulator): fast homing.
class EmulatorRig : public TestRig {
 public:
  static std::unique_ptr<TestRig> Make(std::string* skip) {
    craftscan::testing::EmulatorOptions options;
    options.homing_time = milliseconds(20);
    std::string error;
    auto emulator = craftscan::testing::TurntableEmulator::Start(options, &error);
    if (!emulator) {
      *skip = "";
      ADD_FAILURE() << "turntable emulator: " << error;
      return nullptr;
    }
    return std::unique_ptr<TestRig>(new EmulatorRig(std::move(emulator)));
  }
  DriverConfig Config() const override { return {{"port", emulator_->slave_path()}}; }
  std::optional<double> TurntableAngle() const override {
    return emulator_->machine_position_deg();  // homed at machine 0
  }

 private:
  explicit EmulatorRig(std::unique_ptr<craftscan::testing::TurntableEmulator> emulator)
      : emulator_(std::move(emulator)) {}
  std::unique_ptr<craftscan::testing::TurntableEmulator> emulator_;
};

// Two Aravis fake GigE cameras, 640×480, polling their trigger at 500 Hz.
class AravisRig : public TestRig {
 public:
  static std::unique_ptr<TestRig> Make(std::string* skip) {
    const std::string why = aravis::test::EnterNetns();
    if (!why.empty()) {
      *skip = "no private network namespace: " + why;
      return nullptr;
    }
    auto rig = std::unique_ptr<AravisRig>(new AravisRig);
    rig->left_ = rig->NewFake("127.0.0.1", "LEFT01", 11);
    rig->right_ = rig->NewFake("127.0.0.2", "RIGHT01", 99);
    if (!rig->left_->running() || !rig->right_->running()) {
      ADD_FAILURE() << "the Aravis fake cameras did not start";
      return nullptr;
    }
    return rig;
  }
  bool CanLoseCamera() const override { return true; }
  void LoseCamera() override { right_.reset(); }
  void RestoreCamera() override {
    right_ = NewFake("127.0.0.2", "RIGHT01", 99);
    ASSERT_TRUE(right_->running());
  }

 private:
  static std::unique_ptr<aravis::test::FakeCamera> NewFake(const char* address, const char* serial,
                                                           int seed) {
    aravis::test::FakeCameraOptions options;
    options.sensor = cv::Size(640, 480);
    options.trigger_poll_hz = 500;
    return std::make_unique<aravis::test::FakeCamera>(address, serial, seed, options);
  }
  std::unique_ptr<aravis::test::FakeCamera> left_, right_;
};

std::vector<DriverProfile> Profiles() {
  DriverProfile sim;
  sim.name = "sim";
  sim.plugin = "sim";
  sim.config = {{"image_size", "320x256"}, {"threads", "2"}, {"object", "egg"}};
  sim.loss_config = {{"disconnect_after", "2"}, {"reconnect_failures", "1"}};
  sim.frames_before_loss = 2;
  sim.slow_move_config = {{"turntable_speed_deg_s", "30"}};
  sim.real_time_per_sleep = milliseconds(1);

  // The aravis plugin on two fake cameras; reconnect delays on the fake clock.
  DriverProfile aravis;
  aravis.name = "aravis";
  aravis.plugin = "aravis";
  aravis.config = {{"left", "127.0.0.1"},
                   {"right", "127.0.0.2"},
                   {"packet_size", "8000"},
                   {"reconnect_attempts", "3"},
                   {"reconnect_delay_ms", "100"}};
  aravis.make_rig = AravisRig::Make;
  aravis.has_turntable = false;

  // The GRBL serial turntable on the PTY emulator: fast feed (600 deg/s) and
  // short timeouts so every test stays well under 2 s; 60 deg/s for the
  // moves that are aborted or time out.
  DriverProfile serial;
  serial.name = "serial_turntable";
  serial.plugin = "serial_turntable";
  serial.config = {{"baud", "115200"},
                   {"feed_deg_min", "36000"},
                   {"homing", "true"},
                   {"settle_ms", "0"},
                   {"position_tolerance_deg", "0.05"},
                   {"banner_timeout_ms", "300"},
                   {"command_timeout_ms", "300"},
                   {"homing_timeout_ms", "1000"},
                   {"move_timeout_margin_ms", "300"},
                   {"status_poll_ms", "5"}};
  serial.make_rig = EmulatorRig::Make;
  serial.slow_move_config = {{"feed_deg_min", "3600"}};
  serial.has_camera = false;
  return {sim, aravis, serial};
}

constexpr milliseconds kTimeout{2000};

class DriverConformance : public ::testing::TestWithParam<DriverProfile> {
 protected:
  void SetUp() override {
    // Before starting a rig: camera tests need a camera, turntable tests a turntable.
    const std::string test = ::testing::UnitTest::GetInstance()->current_test_info()->name();
    if (test.rfind("Camera", 0) == 0 && !GetParam().has_camera) {
      GTEST_SKIP() << GetParam().name << " has no camera";
    }
    if (test.rfind("Turntable", 0) == 0 && !GetParam().has_turntable) {
      GTEST_SKIP() << GetParam().name << " has no turntable";
    }
    if (!GetParam().make_rig) return;
    std::string skip;
    rig_ = GetParam().make_rig(&skip);
    if (!rig_ && !skip.empty()) GTEST_SKIP() << GetParam().name << ": " << skip;
    ASSERT_TRUE(rig_) << GetParam().name << ": the test rig did not start";
  }

  // Creates a driver instance with the profile's config, the rig's, then `extra`.
  std::unique_ptr<DriverInstance> MakeInstance(const DriverConfig& extra = {}) {
    PluginLoader loader(::craftscan::testing::PluginDir());
    std::shared_ptr<const Plugin> plugin;
    DriverStatus status = loader.Load(GetParam().plugin, &plugin);
    EXPECT_TRUE(status.ok()) << status.ToString();
    if (!plugin) return nullptr;
    DriverConfig config = GetParam().config;
    if (rig_) {
      for (const auto& [key, value] : rig_->Config()) config.insert_or_assign(key, value);
    }
    for (const auto& [key, value] : extra) config.insert_or_assign(key, value);
    std::unique_ptr<DriverInstance> instance;
    status = plugin->CreateInstance(config, fake_.services(), &instance);
    EXPECT_TRUE(status.ok()) << status.ToString();
    return instance;
  }

  std::unique_ptr<StereoCamera> MakeCamera(const DriverConfig& extra = {}) {
    auto instance = MakeInstance(extra);
    if (!instance) return nullptr;
    DriverStatus status;
    auto camera = instance->CreateCamera(&status);
    EXPECT_TRUE(camera) << status.ToString();
    return camera;
  }

  std::unique_ptr<Turntable> MakeTurntable(const DriverConfig& extra = {}) {
    auto instance = MakeInstance(extra);
    if (!instance) return nullptr;
    DriverStatus status;
    auto turntable = instance->CreateTurntable(&status);
    EXPECT_TRUE(turntable) << status.ToString();
    return turntable;
  }

  // A turntable opened and homed (null, with a failure, if that fails).
  std::unique_ptr<Turntable> MakeHomedTurntable(const DriverConfig& extra) {
    auto turntable = MakeTurntable(extra);
    if (!turntable) return nullptr;
    DriverStatus status = turntable->Open();
    if (status.ok()) status = turntable->Home(kTimeout);
    EXPECT_TRUE(status.ok()) << status.ToString();
    return status.ok() ? std::move(turntable) : nullptr;
  }

  // Opens, configures and starts a camera.
  static void StartStreaming(StereoCamera* camera, const CameraSettings& settings = {}) {
    DriverStatus status = camera->Open();
    ASSERT_TRUE(status.ok()) << status.ToString();
    status = camera->Configure(settings);
    ASSERT_TRUE(status.ok()) << status.ToString();
    ASSERT_TRUE(camera->Start().ok());
    ASSERT_EQ(camera->state(), CameraState::kStreaming);
  }

  test::FakeHost fake_;
  // Test bodies own their devices as locals, destroyed before the fixture:
  // the rig outlives them.
  std::unique_ptr<TestRig> rig_;
};

// Expects `call` to return `expected`; any error must carry a message.
#define EXPECT_CODE(call, expected)                                                   \
  do {                                                                                \
    const DriverStatus status_ = (call);                                              \
    EXPECT_EQ(status_.code, expected) << #call << " returned " << status_.ToString(); \
    if ((expected) != StatusCode::kOk) {                                              \
      EXPECT_FALSE(status_.message.empty()) << #call;                                 \
    }                                                                                 \
  } while (0)

// ------------------------------------------------------------------ camera --

TEST_P(DriverConformance, CameraCallsBeforeOpenAreWrongState) {
  auto camera = MakeCamera();
  ASSERT_TRUE(camera);
  EXPECT_EQ(camera->state(), CameraState::kClosed);
  StereoFrame frame;
  EXPECT_CODE(camera->Configure({}), StatusCode::kWrongState);
  EXPECT_CODE(camera->Start(), StatusCode::kWrongState);
  EXPECT_CODE(camera->Capture(kTimeout, &frame), StatusCode::kWrongState);
  EXPECT_CODE(camera->Stop(), StatusCode::kWrongState);
  EXPECT_CODE(camera->Reconnect(), StatusCode::kWrongState);
  EXPECT_EQ(camera->state(), CameraState::kClosed);
  EXPECT_CODE(camera->Close(), StatusCode::kOk);
}

TEST_P(DriverConformance, CameraOpenConfigureCaptureStop) {
  auto camera = MakeCamera();
  ASSERT_TRUE(camera);
  EXPECT_CODE(camera->Open(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kOpen);
  const cv::Size sensor = camera->info().sensor_size;  // a real device says at Open
  ASSERT_FALSE(sensor.empty());
  EXPECT_CODE(camera->Open(), StatusCode::kWrongState);
  EXPECT_CODE(camera->Start(), StatusCode::kWrongState);  // not configured yet
  CameraSettings settings;
  settings.exposure_us = 8000;
  settings.gain_db = 2;
  EXPECT_CODE(camera->Configure(settings), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kConfigured);
  EXPECT_CODE(camera->Start(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kStreaming);

  StereoFrame previous;
  for (int i = 0; i < 2; ++i) {
    StereoFrame frame;
    ASSERT_TRUE(camera->Capture(kTimeout, &frame).ok());
    for (const CameraImage* image : {&frame.left, &frame.right}) {
      EXPECT_EQ(image->image.size(), sensor);
      EXPECT_EQ(image->image.type(), CV_8UC3);
      EXPECT_GT(image->timestamp_ns, 0);
    }
    EXPECT_EQ(frame.settings, settings);
    if (i > 0) {
      EXPECT_GT(frame.left.frame_id, previous.left.frame_id);
      EXPECT_GT(frame.right.frame_id, previous.right.frame_id);
      EXPECT_GE(frame.left.timestamp_ns, previous.left.timestamp_ns);
    }
    previous = frame;
  }
  EXPECT_CODE(camera->Stop(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kConfigured);
  StereoFrame frame;
  EXPECT_CODE(camera->Capture(kTimeout, &frame), StatusCode::kWrongState);
  EXPECT_CODE(camera->Close(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kClosed);
  EXPECT_CODE(camera->Open(), StatusCode::kOk);  // reopen after close
}

TEST_P(DriverConformance, CameraUnbalancedStopIsWrongState) {
  auto camera = MakeCamera();
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->Open().ok());
  EXPECT_CODE(camera->Stop(), StatusCode::kWrongState);
  EXPECT_EQ(camera->state(), CameraState::kOpen);
  ASSERT_TRUE(camera->Configure({}).ok());
  EXPECT_CODE(camera->Stop(), StatusCode::kWrongState);
  EXPECT_EQ(camera->state(), CameraState::kConfigured);
  ASSERT_TRUE(camera->Start().ok());
  EXPECT_CODE(camera->Stop(), StatusCode::kOk);
  EXPECT_CODE(camera->Stop(), StatusCode::kWrongState);  // a second Stop
  EXPECT_EQ(camera->state(), CameraState::kConfigured);
}

TEST_P(DriverConformance, CameraReconfigureOnlyWhenNotStreaming) {
  auto camera = MakeCamera();
  ASSERT_TRUE(camera);
  ASSERT_NO_FATAL_FAILURE(StartStreaming(camera.get()));
  CameraSettings mono;
  mono.pixel_format = PixelFormat::kMono8;
  EXPECT_CODE(camera->Configure(mono), StatusCode::kWrongState);
  EXPECT_EQ(camera->state(), CameraState::kStreaming);
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(kTimeout, &frame).ok());
  EXPECT_EQ(frame.settings.pixel_format, PixelFormat::kBgr8);  // unchanged

  ASSERT_TRUE(camera->Stop().ok());
  EXPECT_CODE(camera->Configure(mono), StatusCode::kOk);
  EXPECT_CODE(camera->Configure(mono), StatusCode::kOk);  // again, still Configured
  ASSERT_TRUE(camera->Start().ok());
  ASSERT_TRUE(camera->Capture(kTimeout, &frame).ok());
  EXPECT_EQ(frame.left.image.type(), CV_8UC1);
  EXPECT_EQ(frame.right.image.type(), CV_8UC1);
  EXPECT_EQ(frame.settings, mono);
}

TEST_P(DriverConformance, CameraRoiAndInvalidSettings) {
  auto camera = MakeCamera();
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->Open().ok());
  const cv::Size sensor = camera->info().sensor_size;
  CameraSettings bad;
  bad.roi = cv::Rect(sensor.width / 2, 0, sensor.width, 8);  // past the right edge
  EXPECT_CODE(camera->Configure(bad), StatusCode::kInvalidArgument);
  EXPECT_EQ(camera->state(), CameraState::kOpen);  // unchanged
  bad = {};
  bad.exposure_us = -5;
  EXPECT_CODE(camera->Configure(bad), StatusCode::kInvalidArgument);
  EXPECT_EQ(camera->state(), CameraState::kOpen);

  CameraSettings roi;
  roi.roi = cv::Rect(16, 8, sensor.width / 2, sensor.height / 2);
  ASSERT_TRUE(camera->Configure(roi).ok());
  ASSERT_TRUE(camera->Start().ok());
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(kTimeout, &frame).ok());
  EXPECT_EQ(frame.left.image.size(), roi.roi.size());
  EXPECT_EQ(frame.right.image.size(), roi.roi.size());
  EXPECT_EQ(frame.settings.roi, roi.roi);
}

// The loss comes from the driver's config (a simulated disconnect) or from
// the rig (a fake device killed mid-stream).
bool CanLoseCamera(const DriverProfile& profile, const TestRig* rig) {
  return !profile.loss_config.empty() || (rig != nullptr && rig->CanLoseCamera());
}

TEST_P(DriverConformance, CameraLossAndRecovery) {
  const DriverProfile& profile = GetParam();
  if (!CanLoseCamera(profile, rig_.get())) {
    GTEST_SKIP() << profile.name << " cannot simulate a loss";
  }
  auto camera = MakeCamera(profile.loss_config);
  ASSERT_TRUE(camera);
  CameraSettings settings;
  settings.exposure_us = 12000;
  settings.pixel_format = PixelFormat::kMono8;
  ASSERT_NO_FATAL_FAILURE(StartStreaming(camera.get(), settings));
  StereoFrame frame;
  for (int i = 0; i < profile.frames_before_loss; ++i) {
    ASSERT_TRUE(camera->Capture(kTimeout, &frame).ok()) << i;
  }
  if (profile.loss_config.empty()) rig_->LoseCamera();
  EXPECT_CODE(camera->Capture(kTimeout, &frame), StatusCode::kDeviceLost);
  EXPECT_EQ(camera->state(), CameraState::kLost);
  // Lost until reconnected: every call but Reconnect/Close says so.
  EXPECT_CODE(camera->Capture(kTimeout, &frame), StatusCode::kDeviceLost);
  EXPECT_CODE(camera->Stop(), StatusCode::kDeviceLost);
  EXPECT_CODE(camera->Configure(settings), StatusCode::kDeviceLost);
  EXPECT_EQ(camera->state(), CameraState::kLost);

  if (profile.loss_config.empty()) {
    ASSERT_NO_FATAL_FAILURE(rig_->RestoreCamera());
  }
  EXPECT_CODE(camera->Reconnect(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kStreaming);  // back where it was
  ASSERT_TRUE(camera->Capture(kTimeout, &frame).ok());
  EXPECT_EQ(frame.settings, settings);  // re-applied
  EXPECT_EQ(frame.left.image.type(), CV_8UC1);
  EXPECT_CODE(camera->Reconnect(), StatusCode::kWrongState);  // not lost any more

  const std::vector<DeviceEvent> expected = {DeviceEvent::kConnected, DeviceEvent::kLost,
                                             DeviceEvent::kReconnected};
  EXPECT_EQ(fake_.event_kinds(), expected);
  EXPECT_CODE(camera->Close(), StatusCode::kOk);
}

TEST_P(DriverConformance, CameraCloseFromLost) {
  const DriverProfile& profile = GetParam();
  if (!CanLoseCamera(profile, rig_.get())) {
    GTEST_SKIP() << profile.name << " cannot simulate a loss";
  }
  auto camera = MakeCamera(profile.loss_config);
  ASSERT_TRUE(camera);
  ASSERT_NO_FATAL_FAILURE(StartStreaming(camera.get()));
  StereoFrame frame;
  if (profile.loss_config.empty()) rig_->LoseCamera();
  for (int i = 0; i <= profile.frames_before_loss && camera->state() != CameraState::kLost; ++i) {
    camera->Capture(kTimeout, &frame);
  }
  ASSERT_EQ(camera->state(), CameraState::kLost);
  EXPECT_CODE(camera->Close(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kClosed);
}

// --------------------------------------------------------------- turntable --

TEST_P(DriverConformance, TurntableCallsBeforeOpenAreWrongState) {
  auto turntable = MakeTurntable();
  ASSERT_TRUE(turntable);
  EXPECT_EQ(turntable->Status().state, TurntableState::kClosed);
  EXPECT_CODE(turntable->Home(kTimeout), StatusCode::kWrongState);
  EXPECT_CODE(turntable->MoveTo(10, kTimeout), StatusCode::kWrongState);
  EXPECT_CODE(turntable->Abort(), StatusCode::kWrongState);
  EXPECT_EQ(turntable->Status().state, TurntableState::kClosed);
}

TEST_P(DriverConformance, TurntableMoveBeforeHomeIsWrongState) {
  auto turntable = MakeTurntable();
  ASSERT_TRUE(turntable);
  ASSERT_TRUE(turntable->Open().ok());
  EXPECT_EQ(turntable->Status().state, TurntableState::kUnhomed);
  EXPECT_FALSE(turntable->Status().homed);
  EXPECT_CODE(turntable->MoveTo(30, kTimeout), StatusCode::kWrongState);
  EXPECT_EQ(turntable->Status().state, TurntableState::kUnhomed);
  EXPECT_CODE(turntable->Open(), StatusCode::kWrongState);
}

TEST_P(DriverConformance, TurntableHomeMoveStatus) {
  auto turntable = MakeTurntable();
  ASSERT_TRUE(turntable);
  ASSERT_TRUE(turntable->Open().ok());
  EXPECT_CODE(turntable->Home(kTimeout), StatusCode::kOk);
  TurntableStatus status = turntable->Status();
  EXPECT_EQ(status.state, TurntableState::kReady);
  EXPECT_TRUE(status.homed);
  EXPECT_NEAR(status.angle_deg, 0, 1e-9);
  EXPECT_TRUE(status.fault_reason.empty());
  for (double angle : {60.0, 120.0, 45.5}) {
    EXPECT_CODE(turntable->MoveTo(angle, kTimeout), StatusCode::kOk);
    status = turntable->Status();
    EXPECT_EQ(status.state, TurntableState::kReady);
    EXPECT_NEAR(status.angle_deg, angle, 0.01);
  }
  EXPECT_CODE(turntable->MoveTo(std::nan(""), kTimeout), StatusCode::kInvalidArgument);
  EXPECT_EQ(turntable->Status().state, TurntableState::kReady);
  EXPECT_CODE(turntable->Home(kTimeout), StatusCode::kOk);  // re-home from Ready
  EXPECT_NEAR(turntable->Status().angle_deg, 0, 0.01);
  EXPECT_CODE(turntable->Close(), StatusCode::kOk);
  EXPECT_EQ(turntable->Status().state, TurntableState::kClosed);
  EXPECT_CODE(turntable->MoveTo(10, kTimeout), StatusCode::kWrongState);
}

TEST_P(DriverConformance, TurntableAbortOutsideAMoveDoesNothing) {
  auto turntable = MakeTurntable();
  ASSERT_TRUE(turntable);
  ASSERT_TRUE(turntable->Open().ok());
  EXPECT_CODE(turntable->Abort(), StatusCode::kOk);
  EXPECT_EQ(turntable->Status().state, TurntableState::kUnhomed);
  ASSERT_TRUE(turntable->Home(kTimeout).ok());
  EXPECT_CODE(turntable->Abort(), StatusCode::kOk);
  EXPECT_EQ(turntable->Status().state, TurntableState::kReady);
  EXPECT_CODE(turntable->MoveTo(20, kTimeout), StatusCode::kOk);  // a stale abort is not kept
}

// Abort() from another thread while MoveTo() blocks: the move stops, MoveTo
// returns kAborted, Status() reports where it stopped (Ready), or Unhomed
// for a driver that loses the position; the turntable is usable again.
TEST_P(DriverConformance, TurntableAbortDuringAMove) {
  const DriverProfile& profile = GetParam();
  if (profile.slow_move_config.empty()) GTEST_SKIP() << profile.name << " has no slow moves";
  auto turntable = MakeHomedTurntable(profile.slow_move_config);
  ASSERT_TRUE(turntable);
  if (profile.real_time_per_sleep.count() > 0) {
    fake_.OnSleep([&] { std::this_thread::sleep_for(profile.real_time_per_sleep); });
  }
  DriverStatus move = DriverStatus::Error(StatusCode::kFault, "not run");
  std::thread mover([&] { move = turntable->MoveTo(90, std::chrono::minutes(1)); });
  // Wait (bounded) until the move is under way, let it turn a little, abort.
  const auto give_up = Clock::now() + std::chrono::seconds(5);
  while (turntable->Status().state != TurntableState::kMoving && Clock::now() < give_up) {
    std::this_thread::sleep_for(milliseconds(1));
  }
  const TurntableState during = turntable->Status().state;
  std::this_thread::sleep_for(milliseconds(100));
  const DriverStatus abort = turntable->Abort();
  mover.join();
  fake_.OnSleep({});
  EXPECT_EQ(during, TurntableState::kMoving);
  EXPECT_TRUE(abort.ok()) << abort.ToString();
  EXPECT_EQ(move.code, StatusCode::kAborted) << move.ToString();
  const TurntableStatus status = turntable->Status();
  if (profile.abort_keeps_position) {
    EXPECT_EQ(status.state, TurntableState::kReady);
    EXPECT_TRUE(status.homed);
    EXPECT_GT(status.angle_deg, 0.5);
    EXPECT_LT(status.angle_deg, 89.5);
    if (rig_ && rig_->TurntableAngle()) {
      const double stopped = *rig_->TurntableAngle();
      EXPECT_NEAR(status.angle_deg, stopped, 0.01);  // reports where it really is
      std::this_thread::sleep_for(milliseconds(50));
      EXPECT_NEAR(*rig_->TurntableAngle(), stopped, 1e-9);  // and it stands still
    }
  } else {
    EXPECT_EQ(status.state, TurntableState::kUnhomed);
    EXPECT_FALSE(status.homed);
    EXPECT_CODE(turntable->Home(kTimeout), StatusCode::kOk);
  }
  EXPECT_CODE(turntable->MoveTo(90, std::chrono::minutes(1)), StatusCode::kOk);
  EXPECT_NEAR(turntable->Status().angle_deg, 90, 0.01);
  if (rig_ && rig_->TurntableAngle()) {
    EXPECT_NEAR(*rig_->TurntableAngle(), 90, 0.01);
  }
}

// A move that cannot finish within the call's timeout is stopped: kTimeout,
// state Fault with a reason; Home() makes the turntable usable again.
TEST_P(DriverConformance, TurntableMoveTimeoutStopsAndFaults) {
  const DriverProfile& profile = GetParam();
  if (profile.slow_move_config.empty()) GTEST_SKIP() << profile.name << " has no slow moves";
  auto turntable = MakeHomedTurntable(profile.slow_move_config);
  ASSERT_TRUE(turntable);
  const auto t0 = Clock::now();
  EXPECT_CODE(turntable->MoveTo(90, milliseconds(100)), StatusCode::kTimeout);  // needs > 1 s
  EXPECT_LT(Clock::now() - t0, milliseconds(1000));
  TurntableStatus status = turntable->Status();
  EXPECT_EQ(status.state, TurntableState::kFault);
  EXPECT_FALSE(status.fault_reason.empty());
  if (rig_ && rig_->TurntableAngle()) {
    const double stopped = *rig_->TurntableAngle();
    EXPECT_LT(stopped, 89);
    std::this_thread::sleep_for(milliseconds(50));
    EXPECT_NEAR(*rig_->TurntableAngle(), stopped, 1e-9);  // really stopped
  }
  EXPECT_CODE(turntable->MoveTo(10, kTimeout), StatusCode::kWrongState);  // Fault: Home first
  EXPECT_CODE(turntable->Home(kTimeout), StatusCode::kOk);
  status = turntable->Status();
  EXPECT_EQ(status.state, TurntableState::kReady);
  EXPECT_TRUE(status.fault_reason.empty());
  EXPECT_CODE(turntable->MoveTo(10, kTimeout), StatusCode::kOk);
}

// ------------------------------------------------- serial_turntable config --

// The serial turntable plugin beyond the generic suite: config errors, the
// missing camera, and (on the PTY emulator) the per-call timeouts and the
// abort=reset mode.
class SerialTurntablePlugin : public ::testing::Test {
 protected:
  DriverStatus Create(const DriverConfig& config, std::unique_ptr<DriverInstance>* instance) {
    PluginLoader loader(::craftscan::testing::PluginDir());
    std::shared_ptr<const Plugin> plugin;
    DriverStatus status = loader.Load("serial_turntable", &plugin);
    EXPECT_TRUE(status.ok()) << status.ToString();
    if (!plugin) return status;
    EXPECT_EQ(plugin->kinds(), kCraftscanDriverTurntable);
    return plugin->CreateInstance(config, fake_.services(), instance);
  }

  // An emulator whose homing takes `homing`, and an opened turntable on it.
  struct SerialBench {
    std::unique_ptr<craftscan::testing::TurntableEmulator> emulator;
    std::unique_ptr<DriverInstance> instance;
    std::unique_ptr<Turntable> turntable;  // declared last: closed first
  };
  SerialBench StartSerial(milliseconds homing, const DriverConfig& extra) {
    SerialBench bench;
    craftscan::testing::EmulatorOptions options;
    options.homing_time = homing;
    std::string error;
    bench.emulator = craftscan::testing::TurntableEmulator::Start(options, &error);
    EXPECT_TRUE(bench.emulator) << error;
    if (!bench.emulator) return bench;
    DriverConfig config = {{"port", bench.emulator->slave_path()}, {"feed_deg_min", "3600"},
                           {"banner_timeout_ms", "300"},           {"command_timeout_ms", "300"},
                           {"homing_timeout_ms", "2000"},          {"status_poll_ms", "5"}};
    for (const auto& [key, value] : extra) config.insert_or_assign(key, value);
    const DriverStatus created = Create(config, &bench.instance);
    EXPECT_TRUE(created.ok()) << created.ToString();
    if (!bench.instance) return bench;
    DriverStatus status;
    bench.turntable = bench.instance->CreateTurntable(&status);
    EXPECT_TRUE(bench.turntable) << status.ToString();
    if (bench.turntable) {
      EXPECT_TRUE(bench.turntable->Open().ok());
    }
    return bench;
  }

  test::FakeHost fake_;
};

TEST_F(SerialTurntablePlugin, MissingPortIsAClearError) {
  std::unique_ptr<DriverInstance> instance;
  const DriverStatus status = Create({{"baud", "115200"}}, &instance);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument) << status.ToString();
  EXPECT_NE(status.message.find("missing config key 'port'"), std::string::npos) << status.message;
  EXPECT_FALSE(instance);
}

TEST_F(SerialTurntablePlugin, BadConfigValuesNameTheKey) {
  const std::vector<std::pair<std::string, std::string>> bad = {{"baud", "fast"},
                                                                {"feed_deg_min", "-1"},
                                                                {"homing", "maybe"},
                                                                {"settle_ms", "-5"},
                                                                {"position_tolerance_deg", "x"},
                                                                {"command_timeout_ms", "0"},
                                                                {"no_such_key", "1"},
                                                                {"abort", "stop"},
                                                                {"hold_timeout_ms", "0"}};
  for (const auto& [key, value] : bad) {
    std::unique_ptr<DriverInstance> instance;
    const DriverStatus status = Create({{"port", "/dev/null"}, {key, value}}, &instance);
    EXPECT_EQ(status.code, StatusCode::kInvalidArgument) << key << ": " << status.ToString();
    EXPECT_NE(status.message.find("'" + key + "'"), std::string::npos) << status.message;
    EXPECT_FALSE(instance) << key;
  }
}

TEST_F(SerialTurntablePlugin, ProvidesNoCamera) {
  std::unique_ptr<DriverInstance> instance;
  const DriverStatus created = Create({{"port", "/dev/null"}}, &instance);
  ASSERT_TRUE(created.ok()) << created.ToString();
  ASSERT_TRUE(instance);
  DriverStatus status;
  EXPECT_FALSE(instance->CreateCamera(&status));
  EXPECT_EQ(status.code, StatusCode::kUnsupported);
  EXPECT_NE(status.message.find("turntable only"), std::string::npos) << status.message;
  EXPECT_TRUE(instance->CreateTurntable(&status)) << status.ToString();
}

TEST_F(SerialTurntablePlugin, HomeHonoursTheCallTimeout) {
  SerialBench bench = StartSerial(milliseconds(600), {});
  ASSERT_TRUE(bench.turntable);
  Turntable& table = *bench.turntable;
  const auto t0 = Clock::now();
  const DriverStatus status = table.Home(milliseconds(100));  // homing takes 600 ms
  const auto took = Clock::now() - t0;
  EXPECT_EQ(status.code, StatusCode::kTimeout) << status.ToString();
  EXPECT_NE(status.message.find("Home()'s timeout of 100 ms"), std::string::npos) << status.message;
  EXPECT_GE(took, milliseconds(95));
  EXPECT_LT(took, milliseconds(400));
  EXPECT_EQ(table.Status().state, TurntableState::kFault);
  EXPECT_EQ(bench.emulator->state(), "Alarm");  // the homing cycle was stopped
  const DriverStatus again = table.Home(milliseconds(3000));
  EXPECT_TRUE(again.ok()) << again.ToString();
  EXPECT_EQ(table.Status().state, TurntableState::kReady);
  // Zero or negative timeouts are refused, naming the call.
  EXPECT_EQ(table.Home(milliseconds(0)).code, StatusCode::kInvalidArgument);
  const DriverStatus negative = table.MoveTo(10, milliseconds(-1));
  EXPECT_EQ(negative.code, StatusCode::kInvalidArgument);
  EXPECT_NE(negative.message.find("MoveTo: timeout"), std::string::npos) << negative.message;
  EXPECT_EQ(table.Status().state, TurntableState::kReady);
}

TEST_F(SerialTurntablePlugin, AbortWithResetLosesThePosition) {
  SerialBench bench = StartSerial(milliseconds(20), {{"abort", "reset"}});
  ASSERT_TRUE(bench.turntable);
  Turntable& table = *bench.turntable;
  ASSERT_TRUE(table.Home(milliseconds(2000)).ok());
  DriverStatus move;
  std::thread mover([&] { move = table.MoveTo(90, std::chrono::minutes(1)); });  // 1.5 s
  const auto give_up = Clock::now() + std::chrono::seconds(5);
  while (table.Status().state != TurntableState::kMoving && Clock::now() < give_up) {
    std::this_thread::sleep_for(milliseconds(1));
  }
  std::this_thread::sleep_for(milliseconds(100));
  EXPECT_TRUE(table.Abort().ok());
  mover.join();
  EXPECT_EQ(move.code, StatusCode::kAborted) << move.ToString();
  EXPECT_EQ(table.Status().state, TurntableState::kUnhomed);
  EXPECT_FALSE(table.Status().homed);
  // GRBL: reset in motion. The emulator handles the reset byte on its own
  // thread, which may not have run yet when Abort returns.
  const auto alarm_by = Clock::now() + std::chrono::seconds(2);
  while (bench.emulator->state() != "Alarm" && Clock::now() < alarm_by) {
    std::this_thread::sleep_for(milliseconds(1));
  }
  EXPECT_EQ(bench.emulator->state(), "Alarm");
  const double stopped = bench.emulator->machine_position_deg();
  EXPECT_GT(stopped, 0.5);
  EXPECT_LT(stopped, 89.5);
  EXPECT_TRUE(table.Home(milliseconds(2000)).ok());
  EXPECT_TRUE(table.MoveTo(5, milliseconds(2000)).ok());
}

INSTANTIATE_TEST_SUITE_P(Drivers, DriverConformance, ::testing::ValuesIn(Profiles()),
                         [](const ::testing::TestParamInfo<DriverProfile>& info) {
                           return info.param.name;
                         });

}  // namespace
}  // namespace craftscan::drivers
