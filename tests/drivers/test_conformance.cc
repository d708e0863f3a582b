// The driver conformance suite: written against the abstract StereoCamera and
// Turntable interfaces (camera.h, turntable.h) and run for every driver
// profile below, each loaded THROUGH the PluginLoader from the build's plugin
// directory. A driver joins the suite with one DriverProfile. Fault tests
// need a driver that can simulate the fault; they skip when the profile has
// no config for it. All waiting goes through a fake clock, except for drivers
// of real serial devices (serial_turntable), which talk to an in-process
// emulator on a PTY in real time.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "craftscan/drivers/plugin_loader.h"
#include "fake_host.h"
#include "turntable_emulator.h"

namespace craftscan::drivers {
namespace {

using std::chrono::milliseconds;

struct DriverProfile {
  std::string name;     // test name suffix
  std::string plugin;   // craftscan-driver-<plugin>.so
  DriverConfig config;  // a small, fast device
  // Added to `config`: the camera is lost after `frames_before_loss` frames
  // per connection. Empty: the driver cannot simulate a loss (tests skip).
  DriverConfig loss_config;
  int frames_before_loss = 0;
  // Added to `config`: moves take many host sleeps (for Abort). Empty: skip.
  DriverConfig slow_move_config;
  bool has_camera = true;  // false: the camera tests skip (a turntable-only driver)
  // A GRBL turntable emulator (tests/tools) is started per test and its PTY
  // path passed as the `port` config key.
  bool needs_turntable_emulator = false;
};

void PrintTo(const DriverProfile& profile, std::ostream* os) { *os << profile.name; }

std::vector<DriverProfile> Profiles() {
  DriverProfile sim;
  sim.name = "sim";
  sim.plugin = "sim";
  sim.config = {{"image_size", "320x256"}, {"threads", "2"}, {"object", "egg"}};
  sim.loss_config = {{"disconnect_after", "2"}, {"reconnect_failures", "1"}};
  sim.frames_before_loss = 2;
  sim.slow_move_config = {{"turntable_speed_deg_s", "30"}};

  // The GRBL serial turntable on the PTY emulator: fast feed (600 deg/s) and
  // short timeouts so every test stays well under 2 s. Its moves block in
  // real time (no host sleeps), so the Abort-during-a-move test skips.
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
  serial.has_camera = false;
  serial.needs_turntable_emulator = true;
  return {sim, serial};
}

// Fast emulator: homing takes 20 ms.
std::unique_ptr<craftscan::testing::TurntableEmulator> StartEmulator() {
  craftscan::testing::EmulatorOptions options;
  options.homing_time = milliseconds(20);
  std::string error;
  auto emulator = craftscan::testing::TurntableEmulator::Start(options, &error);
  EXPECT_TRUE(emulator) << error;
  return emulator;
}

constexpr milliseconds kTimeout{2000};

class DriverConformance : public ::testing::TestWithParam<DriverProfile> {
 protected:
  // Creates a driver instance with the profile's config plus `extra`.
  std::unique_ptr<DriverInstance> MakeInstance(const DriverConfig& extra = {}) {
    PluginLoader loader(CRAFTSCAN_PLUGIN_DIR);
    std::shared_ptr<const Plugin> plugin;
    DriverStatus status = loader.Load(GetParam().plugin, &plugin);
    EXPECT_TRUE(status.ok()) << status.ToString();
    if (!plugin) return nullptr;
    DriverConfig config = GetParam().config;
    if (GetParam().needs_turntable_emulator) {
      if (!emulator_) emulator_ = StartEmulator();
      if (!emulator_) return nullptr;
      config.insert_or_assign("port", emulator_->slave_path());
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

  // Opens, configures and starts a camera.
  static void StartStreaming(StereoCamera* camera, const CameraSettings& settings = {}) {
    ASSERT_TRUE(camera->Open().ok());
    const DriverStatus status = camera->Configure(settings);
    ASSERT_TRUE(status.ok()) << status.ToString();
    ASSERT_TRUE(camera->Start().ok());
    ASSERT_EQ(camera->state(), CameraState::kStreaming);
  }

  test::FakeHost fake_;
  std::unique_ptr<craftscan::testing::TurntableEmulator> emulator_;  // outlives the devices
};

// Camera tests skip for a driver without a camera.
#define SKIP_WITHOUT_CAMERA()                                                          \
  do {                                                                                 \
    if (!GetParam().has_camera) GTEST_SKIP() << GetParam().name << " has no camera"; \
  } while (0)

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
  SKIP_WITHOUT_CAMERA();
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
  SKIP_WITHOUT_CAMERA();
  auto camera = MakeCamera();
  ASSERT_TRUE(camera);
  const cv::Size sensor = camera->info().sensor_size;
  ASSERT_FALSE(sensor.empty());
  EXPECT_CODE(camera->Open(), StatusCode::kOk);
  EXPECT_EQ(camera->state(), CameraState::kOpen);
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
  SKIP_WITHOUT_CAMERA();
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
  SKIP_WITHOUT_CAMERA();
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
  SKIP_WITHOUT_CAMERA();
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

TEST_P(DriverConformance, CameraLossAndRecovery) {
  SKIP_WITHOUT_CAMERA();
  const DriverProfile& profile = GetParam();
  if (profile.loss_config.empty()) GTEST_SKIP() << profile.name << " cannot simulate a loss";
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
  EXPECT_CODE(camera->Capture(kTimeout, &frame), StatusCode::kDeviceLost);
  EXPECT_EQ(camera->state(), CameraState::kLost);
  // Lost until reconnected: every call but Reconnect/Close says so.
  EXPECT_CODE(camera->Capture(kTimeout, &frame), StatusCode::kDeviceLost);
  EXPECT_CODE(camera->Stop(), StatusCode::kDeviceLost);
  EXPECT_CODE(camera->Configure(settings), StatusCode::kDeviceLost);
  EXPECT_EQ(camera->state(), CameraState::kLost);

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
  SKIP_WITHOUT_CAMERA();
  const DriverProfile& profile = GetParam();
  if (profile.loss_config.empty()) GTEST_SKIP() << profile.name << " cannot simulate a loss";
  auto camera = MakeCamera(profile.loss_config);
  ASSERT_TRUE(camera);
  ASSERT_NO_FATAL_FAILURE(StartStreaming(camera.get()));
  StereoFrame frame;
  for (int i = 0; i <= profile.frames_before_loss; ++i) camera->Capture(kTimeout, &frame);
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

TEST_P(DriverConformance, TurntableAbortStopsAMove) {
  const DriverProfile& profile = GetParam();
  if (profile.slow_move_config.empty()) GTEST_SKIP() << profile.name << " has no slow moves";
  auto turntable = MakeTurntable(profile.slow_move_config);
  ASSERT_TRUE(turntable);
  ASSERT_TRUE(turntable->Open().ok());
  ASSERT_TRUE(turntable->Home(kTimeout).ok());
  // Abort from inside the move, as another thread would: on the 3rd host
  // sleep the state is Moving; Abort() must not block on the move.
  int sleeps = 0;
  TurntableState state_during_move = TurntableState::kClosed;
  DriverStatus abort_status = DriverStatus::Error(StatusCode::kFault, "not called");
  fake_.OnSleep([&] {
    if (++sleeps == 3) {
      state_during_move = turntable->Status().state;
      abort_status = turntable->Abort();
    }
  });
  EXPECT_CODE(turntable->MoveTo(90, std::chrono::minutes(10)), StatusCode::kAborted);
  fake_.OnSleep({});
  EXPECT_EQ(state_during_move, TurntableState::kMoving);
  EXPECT_TRUE(abort_status.ok()) << abort_status.ToString();
  const TurntableStatus status = turntable->Status();
  EXPECT_EQ(status.state, TurntableState::kReady);
  EXPECT_GT(status.angle_deg, 0);
  EXPECT_LT(status.angle_deg, 90);
  EXPECT_CODE(turntable->MoveTo(90, std::chrono::minutes(10)), StatusCode::kOk);
  EXPECT_NEAR(turntable->Status().angle_deg, 90, 0.01);
}

// ------------------------------------------------- serial_turntable config --

// The serial turntable plugin without an emulator: config errors and the
// missing camera.
class SerialTurntablePlugin : public ::testing::Test {
 protected:
  DriverStatus Create(const DriverConfig& config, std::unique_ptr<DriverInstance>* instance) {
    PluginLoader loader(CRAFTSCAN_PLUGIN_DIR);
    std::shared_ptr<const Plugin> plugin;
    DriverStatus status = loader.Load("serial_turntable", &plugin);
    EXPECT_TRUE(status.ok()) << status.ToString();
    if (!plugin) return status;
    EXPECT_EQ(plugin->kinds(), kCraftscanDriverTurntable);
    return plugin->CreateInstance(config, fake_.services(), instance);
  }

  test::FakeHost fake_;
};

TEST_F(SerialTurntablePlugin, MissingPortIsAClearError) {
  std::unique_ptr<DriverInstance> instance;
  const DriverStatus status = Create({{"baud", "115200"}}, &instance);
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument) << status.ToString();
  EXPECT_NE(status.message.find("missing config key 'port'"), std::string::npos)
      << status.message;
  EXPECT_FALSE(instance);
}

TEST_F(SerialTurntablePlugin, BadConfigValuesNameTheKey) {
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"baud", "fast"},         {"feed_deg_min", "-1"}, {"homing", "maybe"},
      {"settle_ms", "-5"},      {"position_tolerance_deg", "x"},
      {"command_timeout_ms", "0"}, {"no_such_key", "1"}};
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

INSTANTIATE_TEST_SUITE_P(Drivers, DriverConformance, ::testing::ValuesIn(Profiles()),
                         [](const ::testing::TestParamInfo<DriverProfile>& info) {
                           return info.param.name;
                         });

}  // namespace
}  // namespace craftscan::drivers
