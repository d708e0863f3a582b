// The sim driver plugin beyond the conformance suite: the camera pair and the
// turntable share one scene (a capture after a move equals a direct render at
// that angle), move timing on the injected clock, the fault knobs, and the
// calibration scenes (held_board, platter_board) calibrating the rig and the
// turntable axis through the driver API as the daemon's jobs do; PLY mesh
// objects (the shared owl scan) and the refusal of bad meshes. The
// devices are loaded through the PluginLoader; the direct renders use
// craftscan_sim with the driver's own option mapping (driver_options.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "craftscan/drivers/plugin_loader.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/triangle_mesh.h"
#include "craftscan/sim/calibration_scenes.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "fake_host.h"
#include "file_util.h"
#include "mat_util.h"
#include "test_paths.h"

namespace craftscan::sim {
namespace {

using ::craftscan::testing::BitExact;
using ::craftscan::testing::ReadFile;
using ::craftscan::testing::TempDir;
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

// The driver's station and scene made directly with the sim library and the
// driver's own option mapping (SimRigOptions, SimSceneOptions).
struct DirectSim {
  SimDriverOptions options;
  std::unique_ptr<SimStation> station;
  std::unique_ptr<Scene> scene;
};

void MakeDirectSim(const DriverConfig& config, const CameraSettings& settings, DirectSim* out) {
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig(config, &out->options, &why)) << why;
  out->station = SimStation::Create(SimRigOptions(out->options, settings), &why);
  ASSERT_TRUE(out->station) << why;
  out->scene = Scene::Create(SimSceneOptions(out->options), &why);
  ASSERT_TRUE(out->scene) << why;
}

class SimDriver : public ::testing::Test {
 protected:
  // Loads craftscan-driver-sim.so and creates an instance with `config`,
  // its camera (opened, configured, streaming) and its turntable (opened).
  void Create(const DriverConfig& config, const CameraSettings& settings = {}) {
    drivers::PluginLoader loader(::craftscan::testing::PluginDir());
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
  DirectSim sim;
  ASSERT_NO_FATAL_FAILURE(MakeDirectSim(config, at60.settings, &sim));
  const StereoRender direct0 = sim.station->Render(*sim.scene, at0.left.frame_id);
  sim.scene->SetTurntableAngle(60 * std::numbers::pi / 180);
  const StereoRender direct60 = sim.station->Render(*sim.scene, at60.left.frame_id);
  ASSERT_TRUE(direct0.IsUsable() && direct60.IsUsable());
  EXPECT_TRUE(BitExact(at0.left.image, direct0.left));
  EXPECT_TRUE(BitExact(at0.right.image, direct0.right));
  EXPECT_TRUE(BitExact(at60.left.image, direct60.left));
  EXPECT_TRUE(BitExact(at60.right.image, direct60.right));
  EXPECT_FALSE(BitExact(direct0.left, direct60.left));
}

// `projector: 1`: the pair shows the pattern on the object, and every frame
// carries the texture frame (the left view with the projector off), exactly
// what the station renders with it switched off. Without it there is none.
TEST_F(SimDriver, AProjectorAddsItsPatternAndATextureFrame) {
  const DriverConfig config = With(kSmall, {{"object", "egg"}, {"projector", "1"}});
  ASSERT_NO_FATAL_FAILURE(Create(config));
  const StereoFrame frame = Capture();
  ASSERT_FALSE(frame.texture_left.empty());
  ASSERT_EQ(frame.texture_left.size(), frame.left.image.size());
  ASSERT_EQ(frame.texture_left.type(), frame.left.image.type());
  DirectSim sim;
  ASSERT_NO_FATAL_FAILURE(MakeDirectSim(config, frame.settings, &sim));
  const StereoRender lit = sim.station->Render(*sim.scene, frame.left.frame_id);
  ASSERT_TRUE(sim.scene->SetProjectorOn(false));
  const StereoRender dark = sim.station->Render(*sim.scene, frame.left.frame_id);
  ASSERT_TRUE(lit.IsUsable() && dark.IsUsable());
  EXPECT_TRUE(BitExact(frame.left.image, lit.left));
  EXPECT_TRUE(BitExact(frame.right.image, lit.right));
  EXPECT_TRUE(BitExact(frame.texture_left, dark.left));
  // The pattern lights part of the egg: thousands of pixels brighter, none darker.
  cv::Mat brighter = frame.left.image.reshape(1) > dark.left.reshape(1) + 20;
  cv::Mat darker = dark.left.reshape(1) > frame.left.image.reshape(1) + 20;
  EXPECT_GT(cv::countNonZero(brighter), 500);
  EXPECT_EQ(cv::countNonZero(darker), 0);

  Create(With(kSmall, {{"object", "egg"}}));
  EXPECT_TRUE(Capture().texture_left.empty());
  // Bad values name the key.
  drivers::PluginLoader loader(::craftscan::testing::PluginDir());
  std::shared_ptr<const drivers::Plugin> plugin;
  ASSERT_TRUE(loader.Load("sim", &plugin).ok());
  std::unique_ptr<drivers::DriverInstance> instance;
  const DriverStatus bad =
      plugin->CreateInstance(With(kSmall, {{"projector", "bright"}}), fake_.services(), &instance);
  EXPECT_FALSE(bad.ok());
  EXPECT_NE(bad.message.find("'projector'"), std::string::npos) << bad.message;
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
  drivers::PluginLoader loader(::craftscan::testing::PluginDir());
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

// --- calibration scenes ------------------------------------------------------

// Frame i of held_board shows the board at held pose i mod 16, exactly as a
// direct render of SimHeldBoardSceneOptions(…, i) (images only); the board
// moves between frames and comes back with frame 16.
TEST_F(SimDriver, HeldBoardFrameIdPicksThePose) {
  for (const char* type : {"chessboard", "charuco"}) {
    SCOPED_TRACE(type);
    const DriverConfig config =
        With(kSmall, {{"scene", "held_board"}, {"board_type", type}, {"supersampling", "1"}});
    ASSERT_NO_FATAL_FAILURE(Create(config));
    SimDriverOptions options;
    std::string why;
    ASSERT_TRUE(SimDriverOptionsFromConfig(config, &options, &why)) << why;
    std::vector<StereoFrame> frames;
    for (int i = 0; i < 17; ++i) frames.push_back(Capture());
    auto station = SimStation::Create(SimRigOptions(options, frames[1].settings), &why);
    ASSERT_TRUE(station) << why;
    for (const std::uint64_t id : {1u, 16u}) {
      ASSERT_EQ(frames[id].left.frame_id, id);
      auto scene = Scene::Create(SimHeldBoardSceneOptions(options, *station, id), &why);
      ASSERT_TRUE(scene) << why;
      const StereoRender direct = station->Render(*scene, id, RenderOutputs::kImagesOnly);
      EXPECT_TRUE(BitExact(frames[id].left.image, direct.left));
      EXPECT_TRUE(BitExact(frames[id].right.image, direct.right));
    }
    const SceneOptions pose0 = SimHeldBoardSceneOptions(options, *station, 0);
    const SceneOptions pose16 = SimHeldBoardSceneOptions(options, *station, 16);
    EXPECT_EQ(pose0.board.rotation_rad, pose16.board.rotation_rad);
    EXPECT_EQ(pose0.board.translation_mm, pose16.board.translation_mm);
    EXPECT_EQ(pose0.board.spec.type, options.board.type);
    // Frames 0 and 16: the same pose, other noise (σ = 1 grey level).
    cv::Mat diff;
    cv::absdiff(frames[0].left.image, frames[16].left.image, diff);
    EXPECT_LT(cv::mean(diff)[1], 1.5);
    EXPECT_FALSE(BitExact(frames[0].left.image, frames[16].left.image));
    // Frames 0 and 1: the board moved.
    cv::absdiff(frames[0].left.image, frames[1].left.image, diff);
    EXPECT_GT(cv::countNonZero(diff.reshape(1) > 60), 1000);
  }
}

// The exact calibration of the driver's rig and the figures a calibration is
// judged by.
struct RigErrors {
  double focal_pct = 0;     // largest |Δf| / f of fx, fy of both cameras
  double principal_px = 0;  // largest |Δ(cx, cy)| of both cameras
  double baseline_mm = 0;
};

RigErrors CompareRig(const StereoCalibration& estimate, const StereoCalibration& truth) {
  RigErrors e;
  for (int camera = 0; camera < 2; ++camera) {
    const cv::Matx33d& k = (camera ? estimate.right : estimate.left).camera_matrix;
    const cv::Matx33d& t = (camera ? truth.right : truth.left).camera_matrix;
    for (int axis = 0; axis < 2; ++axis) {
      e.focal_pct = std::max(e.focal_pct, 100 * std::abs(k(axis, axis) / t(axis, axis) - 1));
    }
    e.principal_px = std::max(e.principal_px, std::hypot(k(0, 2) - t(0, 2), k(1, 2) - t(1, 2)));
  }
  e.baseline_mm = std::abs(estimate.baseline_mm() - truth.baseline_mm());
  return e;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// The full-size default rig through the driver, point sampled (1×1) to save
// time, as the daemon's calibrate job runs it: 16 captures of the held
// chessboard, DetectStereoBoard, CalibrateStereo. Tolerances of the sim
// calibration test (test_sim_calibration: focal 0.2 %, baseline 0.1 mm,
// stereo RMS 0.2 px); at 1×1 the corners are ~2× noisier than at 2×2, so the
// principal point (held to 3 px there) is only printed.
TEST_F(SimDriver, HeldBoardCapturesCalibrateTheRig) {
  const DriverConfig config = {{"scene", "held_board"}, {"threads", "2"}, {"supersampling", "1"}};
  ASSERT_NO_FATAL_FAILURE(Create(config));
  SimDriverOptions options;
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig(config, &options, &why)) << why;
  const BoardSpec& board = options.board;
  double capture_s = 0, detect_s = 0;
  std::vector<StereoBoardView> views;
  for (int i = 0; i < 16; ++i) {
    auto start = std::chrono::steady_clock::now();
    const StereoFrame frame = Capture();
    capture_s += SecondsSince(start);
    start = std::chrono::steady_clock::now();
    views.push_back(
        DetectStereoBoard("view" + std::to_string(i), frame.left.image, frame.right.image, board));
    detect_s += SecondsSince(start);
    EXPECT_TRUE(views.back().left.found && views.back().right.found)
        << "view " << i << ": " << views.back().left.message << " / " << views.back().right.message;
  }
  StereoCalibrationOptions calibration_options;
  calibration_options.rectification.zero_disparity = false;  // as the station's
  const auto start = std::chrono::steady_clock::now();
  const StereoCalibrationResult r =
      CalibrateStereo(views, options.image_size, board, calibration_options);
  const double calibrate_s = SecondsSince(start);
  ASSERT_EQ(r.status, StereoCalibrationResult::Status::kOk) << r.message;
  auto station = SimStation::Create(SimRigOptions(options), &why);
  ASSERT_TRUE(station) << why;
  const RigErrors e = CompareRig(r.calibration, station->calibration());
  std::printf(
      "held_board through the driver (1x1): %d views; focal %.4f %%, principal point %.3f px, "
      "baseline %.4f mm; RMS stereo %.4f px; per view: capture %.2f s, detect %.2f s; "
      "calibrate %.2f s\n",
      r.report().views_used, e.focal_pct, e.principal_px, e.baseline_mm, r.report().rms_stereo_px,
      capture_s / 16, detect_s / 16, calibrate_s);
  EXPECT_EQ(r.report().views_used, 16);
  EXPECT_TRUE(r.IsUsable()) << r.report().verdict_reason;
  EXPECT_LT(e.focal_pct, 0.2) << "%";
  EXPECT_LT(e.baseline_mm, 0.1) << "mm";
  EXPECT_LT(r.report().rms_stereo_px, 0.2) << "px";
}

// The chessboard on the platter through the driver, as the daemon's
// calibrate-turntable job runs it: MoveTo 0, 60, …, 300°, Capture,
// DetectBoard, CalibrateTurntableAxis with the rig's exact calibration.
// Tolerances of test_sim_calibration's exact-calibration axis test:
// direction 0.1°, platter point 0.2 mm, step angles 0.05°.
TEST_F(SimDriver, PlatterBoardCapturesGiveTheTurntableAxis) {
  const DriverConfig config = {
      {"scene", "platter_board"}, {"threads", "2"}, {"supersampling", "1"}};
  ASSERT_NO_FATAL_FAILURE(Create(config));
  SimDriverOptions options;
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig(config, &options, &why)) << why;
  ASSERT_TRUE(turntable_->Home(kTimeout).ok());
  double capture_s = 0, detect_s = 0;
  std::vector<TurntableStep> steps;
  for (int angle_deg = 0; angle_deg < 360; angle_deg += 60) {
    ASSERT_TRUE(turntable_->MoveTo(angle_deg, kTimeout).ok());
    auto start = std::chrono::steady_clock::now();
    const StereoFrame frame = Capture();
    capture_s += SecondsSince(start);
    TurntableStep step;
    step.commanded_angle_rad = angle_deg * std::numbers::pi / 180;
    start = std::chrono::steady_clock::now();
    step.left = DetectBoard(frame.left.image, options.board);
    detect_s += SecondsSince(start);
    EXPECT_TRUE(step.left.found) << "at " << angle_deg << "°: " << step.left.message;
    steps.push_back(std::move(step));
  }
  auto station = SimStation::Create(SimRigOptions(options), &why);
  ASSERT_TRUE(station) << why;
  StereoCalibration truth = station->calibration();
  truth.board = options.board;
  TurntableAxisOptions axis_options;
  axis_options.board_thickness_mm = SimSceneOptions(options).board.thickness_mm;
  const TurntableAxisResult r = CalibrateTurntableAxis(truth, steps, axis_options);
  ASSERT_EQ(r.status, TurntableAxisResult::Status::kOk) << r.message;
  const cv::Vec3d& direction = truth.turntable.direction_in_rig;
  const double direction_deg =
      std::acos(std::clamp(r.axis.direction_in_rig.dot(direction) /
                               (cv::norm(r.axis.direction_in_rig) * cv::norm(direction)),
                           -1.0, 1.0)) *
      180 / std::numbers::pi;
  const double point_mm = cv::norm(r.axis.point_in_rig_mm - truth.turntable.point_in_rig_mm);
  std::printf(
      "platter_board through the driver (1x1): %d steps; direction %.4f°, point %.3f mm, max "
      "step angle error %.4f°, residual %.4f mm; per view: capture %.2f s, detect %.2f s\n",
      r.steps_used, direction_deg, point_mm, r.max_abs_angle_error_deg, r.residual_mm,
      capture_s / 6, detect_s / 6);
  EXPECT_TRUE(r.IsUsable()) << r.verdict_reason;
  EXPECT_EQ(r.steps_used, 6);
  EXPECT_LT(direction_deg, 0.1);
  EXPECT_LT(point_mm, 0.2);
  EXPECT_LT(r.max_abs_angle_error_deg, 0.05);
}

// --- mesh objects ------------------------------------------------------------

std::string OwlPly() {
  return std::string(::craftscan::testing::SharedDataDir()) + "/meshes/owl.ply";
}

// What vertical rays from above on a 0.25 mm grid over the platter's middle
// find of the object (world frame, mm).
struct TopView {
  double top_mm = -1;  // highest surface point
  double min_x = 1e9, max_x = -1e9, min_y = 1e9, max_y = -1e9;
};

TopView LookDown(const Scene& scene) {
  TopView v;
  for (double x = -60; x <= 60; x += 0.25) {
    for (double y = -60; y <= 60; y += 0.25) {
      double t = 0;
      SurfaceLabel label;
      if (!scene.Intersect({x, y, 200}, {0, 0, -1}, &t, &label) || label != SurfaceLabel::kObject) {
        continue;
      }
      v.top_mm = std::max(v.top_mm, 200 - t);
      v.min_x = std::min(v.min_x, x);
      v.max_x = std::max(v.max_x, x);
      v.min_y = std::min(v.min_y, y);
      v.max_y = std::max(v.max_y, y);
    }
  }
  return v;
}

// The shared owl scan (38.8 × 41.1 × 60 mm in the file, +z up) through the
// driver: scaled to 45 mm (its height is its largest extent: × 0.75),
// turned 90° and placed 20 mm off the axis, painted. The frame is the sim
// library's render of the driver's scene; the ground truth puts the owl's
// top at 45 mm and its footprint (turned: 41.1 · 0.75 = 30.8 mm along x,
// 38.8 · 0.75 = 29.1 mm along y) around (20, −10).
TEST_F(SimDriver, MeshObjectStandsOnThePlatterAtItsSizeAndPlace) {
  if (!std::filesystem::exists(OwlPly())) GTEST_SKIP() << "shared mesh absent: " << OwlPly();
  const DriverConfig config = With(kSmall, {{"object", "mesh"},
                                            {"mesh", OwlPly()},
                                            {"mesh_size_mm", "45"},
                                            {"mesh_surface", "painted"},
                                            {"object_position_mm", "20, -10"},
                                            {"object_yaw_deg", "90"}});
  ASSERT_NO_FATAL_FAILURE(Create(config));
  const StereoFrame frame = Capture();

  DirectSim sim;
  ASSERT_NO_FATAL_FAILURE(MakeDirectSim(config, frame.settings, &sim));
  EXPECT_EQ(sim.scene->mesh_triangle_count(), 24407u);
  const StereoRender direct = sim.station->Render(*sim.scene, frame.left.frame_id);
  ASSERT_TRUE(direct.IsUsable()) << direct.message;
  EXPECT_TRUE(BitExact(frame.left.image, direct.left));
  EXPECT_TRUE(BitExact(frame.right.image, direct.right));

  const double share = static_cast<double>(cv::countNonZero(direct.left_object_mask)) /
                       static_cast<double>(direct.left_object_mask.total());
  const TopView v = LookDown(*sim.scene);
  std::printf(
      "owl through the driver (320x256): %.2f %% of the left image; top %.3f mm, "
      "footprint x %.2f … %.2f, y %.2f … %.2f mm\n",
      100 * share, v.top_mm, v.min_x, v.max_x, v.min_y, v.max_y);
  EXPECT_NEAR(share, 0.028, 0.003);  // 60 mm (mesh_size_mm ignored) would be ~0.05
  EXPECT_NEAR(v.top_mm, 45, 0.15) << "mm";
  EXPECT_NEAR(v.max_x - v.min_x, 30.8, 0.6) << "mm";
  EXPECT_NEAR(v.max_y - v.min_y, 29.1, 0.6) << "mm";
  EXPECT_NEAR(0.5 * (v.min_x + v.max_x), 20, 0.4) << "mm";
  EXPECT_NEAR(0.5 * (v.min_y + v.max_y), -10, 0.4) << "mm";

  // mesh_rotation_deg 90,0,0 turns file +y up: the owl lies on its back,
  // its file depth (41.1 mm · 0.75) now its height.
  DirectSim lying;
  ASSERT_NO_FATAL_FAILURE(
      MakeDirectSim(With(config, {{"mesh_rotation_deg", "90,0,0"}}), frame.settings, &lying));
  const TopView on_back = LookDown(*lying.scene);
  std::printf("owl on its back: top %.3f mm\n", on_back.top_mm);
  EXPECT_NEAR(on_back.top_mm, 30.8, 0.15) << "mm";
}

// The surface keys change the object's colours in the driver's frames (the
// same owl, the same seed).
TEST_F(SimDriver, MeshSurfacesLookDifferent) {
  if (!std::filesystem::exists(OwlPly())) GTEST_SKIP() << "shared mesh absent: " << OwlPly();
  std::vector<cv::Scalar> means;
  cv::Mat mask;
  for (const char* surface : {"stone", "wood", "painted", "fabric"}) {
    SCOPED_TRACE(surface);
    const DriverConfig config =
        With(kSmall, {{"object", "mesh"}, {"mesh", OwlPly()}, {"mesh_surface", surface}});
    ASSERT_NO_FATAL_FAILURE(Create(config));
    const StereoFrame frame = Capture();
    if (mask.empty()) {
      DirectSim sim;
      ASSERT_NO_FATAL_FAILURE(MakeDirectSim(config, frame.settings, &sim));
      mask = sim.station->Render(*sim.scene, 0).left_object_mask;  // the same for every surface
      ASSERT_GT(cv::countNonZero(mask), 1000);
    }
    means.push_back(cv::mean(frame.left.image, mask));
    std::printf("owl %-7s: mean BGR (%.1f, %.1f, %.1f)\n", surface, means.back()[0],
                means.back()[1], means.back()[2]);
  }
  for (std::size_t i = 0; i < means.size(); ++i)
    for (std::size_t j = 0; j < i; ++j) EXPECT_GT(cv::norm(means[i] - means[j]), 10) << i << j;
}

DriverStatus CreateInstanceStatus(const DriverConfig& config) {
  drivers::PluginLoader loader(::craftscan::testing::PluginDir());
  std::shared_ptr<const drivers::Plugin> plugin;
  DriverStatus status = loader.Load("sim", &plugin);
  if (!status.ok()) return status;
  std::unique_ptr<drivers::DriverInstance> instance;
  return plugin->CreateInstance(config, {}, &instance);
}

void WriteBytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// A mesh that cannot be used fails the instance's creation, and every mesh
// refusal names the key and the file.
TEST(SimDriverMesh, BadMeshesAreRefusedNamingTheKeyAndTheFile) {
  TempDir dir;
  TriangleMesh tetrahedron;
  tetrahedron.vertices_mm = {{0, 0, 0}, {10, 0, 0}, {0, 10, 0}, {0, 0, 10}};
  tetrahedron.faces = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  std::string error;
  const std::string good = dir.File("tetrahedron.ply");
  ASSERT_TRUE(WriteMeshPly(good, tetrahedron, /*binary=*/true, &error)) << error;
  const std::string bytes = ReadFile(good);
  ASSERT_GT(bytes.size(), 40u);
  WriteBytes(dir.File("cut.ply"), bytes.substr(0, bytes.size() - 10));
  WriteBytes(dir.File("owl.ply"), "solid owl\n  facet normal 0 0 1\nendsolid owl\n");
  WriteBytes(dir.File("cloud.ply"),
             "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
             "property float z\nend_header\n0 0 0\n");
  ASSERT_TRUE(CreateInstanceStatus(With(kSmall, {{"object", "mesh"}, {"mesh", good}})).ok());

  struct Case {
    DriverConfig config;
    std::string key, file, problem;
  };
  const std::string missing = dir.File("missing.ply");
  const std::vector<Case> cases = {
      {{{"object", "mesh"}, {"mesh", missing}}, "'mesh'", missing, "no such file"},
      {{{"object", "mesh"}, {"mesh", dir.File("owl.ply")}},
       "'mesh'",
       dir.File("owl.ply"),
       "not a PLY file"},
      {{{"object", "mesh"}, {"mesh", dir.File("cut.ply")}},
       "'mesh'",
       dir.File("cut.ply"),
       "truncated file"},
      {{{"object", "mesh"}, {"mesh", dir.File("cloud.ply")}},
       "'mesh'",
       dir.File("cloud.ply"),
       "no faces"},
      {{{"object", "mesh"}, {"mesh", good}, {"mesh_surface", "glass"}},
       "'mesh_surface'",
       good,
       "unknown surface 'glass'"},
      {{{"object", "carved_box"}, {"mesh", good}}, "'mesh'", good, "only for object mesh"},
      {{{"object", "egg"}, {"mesh", good}, {"mesh_size_mm", "40"}},
       "'mesh'",
       good,
       "only for object mesh (object is egg; mesh '"},
      {{{"object", "mesh"}, {"mesh", good}, {"mesh_size_mm", "forty"}},
       "'mesh_size_mm'",
       good,
       "bad value 'forty'"},
      {{{"object", "mesh"}, {"mesh", good}, {"mesh_rotation_deg", "90,0"}},
       "'mesh_rotation_deg'",
       good,
       "bad value '90,0'"},
      {{{"object", "mesh"}, {"mesh", good}, {"mesh_size_mm", "40"}, {"mesh_scale", "2"}},
       "'mesh_size_mm' and 'mesh_scale'",
       good,
       "not both"},
      {{{"object", "mesh"}, {"mesh", good}, {"mesh_scale", "-1"}}, "mesh_scale", good, "(0, 1e6]"},
      {{{"object", "mesh"}, {"mesh", "meshes/owl.ply"}},
       "'mesh'",
       "meshes/owl.ply",
       "not an absolute path"},
  };
  for (const Case& c : cases) {
    const DriverStatus status = CreateInstanceStatus(With(kSmall, c.config));
    SCOPED_TRACE(status.message);
    EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
    EXPECT_NE(status.message.find(c.key), std::string::npos) << c.key;
    EXPECT_NE(status.message.find("'" + c.file + "'"), std::string::npos) << c.file;
    EXPECT_NE(status.message.find(c.problem), std::string::npos) << c.problem;
  }
  // Without a file there is only the key to name.
  DriverStatus status = CreateInstanceStatus({{"object", "mesh"}});
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_NE(status.message.find("'mesh' is missing"), std::string::npos) << status.message;
  status = CreateInstanceStatus({{"mesh_surface", "wood"}});
  EXPECT_NE(status.message.find("'mesh_surface' is only for object mesh (object is carved_box)"),
            std::string::npos)
      << status.message;
}

// The placement keys map onto the scene (for every object) and the mesh
// keys onto MeshOptions; the rotation is x, then y, then z.
TEST(SimDriverOptions, ObjectPlacementAndMeshKeys) {
  SimDriverOptions o;
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig(
      {{"object", "egg"}, {"object_position_mm", "12.5,-4"}, {"object_yaw_deg", "-30"}}, &o, &why))
      << why;
  SceneOptions scene = SimSceneOptions(o);
  EXPECT_EQ(scene.object.type, ObjectType::kEgg);
  EXPECT_EQ(scene.object.position_mm, cv::Point2d(12.5, -4));
  EXPECT_NEAR(scene.object.yaw_rad, -std::numbers::pi / 6, 1e-12);
  EXPECT_EQ(scene.object.rotation_rad, cv::Vec3d(0, 0, 0)) << "standing, untouched";

  // Laid on its side: 90° about x (object z → −y).
  ASSERT_TRUE(
      SimDriverOptionsFromConfig({{"object", "egg"}, {"object_rotation_deg", "90,0,0"}}, &o, &why))
      << why;
  cv::Matx33d laid;
  cv::Rodrigues(SimSceneOptions(o).object.rotation_rad, laid);
  EXPECT_LT(cv::norm(laid * cv::Vec3d(0, 0, 1) - cv::Vec3d(0, -1, 0)), 1e-12);

  // Turns (the daemon sets `turn` when a scan adds a turn to a session):
  // turn 1 stands as object_rotation_deg, turn t ≥ 2 lies in the (t−1)-th
  // pose of turn_rotations_deg, later turns in its last; by default on its side.
  const auto pose_of = [&](const DriverConfig& config) {
    SimDriverOptions options;
    std::string error;
    EXPECT_TRUE(SimDriverOptionsFromConfig(config, &options, &error)) << error;
    return options.ObjectRotationDeg();
  };
  EXPECT_EQ(pose_of({{"object_rotation_deg", "0,0,30"}}), cv::Vec3d(0, 0, 30));
  EXPECT_EQ(pose_of({{"object_rotation_deg", "0,0,30"}, {"turn", "2"}}), cv::Vec3d(90, 0, 0));
  const std::string poses = "0,90,0; 180,0,0";
  EXPECT_EQ(pose_of({{"turn", "2"}, {"turn_rotations_deg", poses}}), cv::Vec3d(0, 90, 0));
  EXPECT_EQ(pose_of({{"turn", "3"}, {"turn_rotations_deg", poses}}), cv::Vec3d(180, 0, 0));
  EXPECT_EQ(pose_of({{"turn", "7"}, {"turn_rotations_deg", poses}}), cv::Vec3d(180, 0, 0));
  ASSERT_TRUE(SimDriverOptionsFromConfig({{"object", "egg"}, {"turn", "2"}}, &o, &why)) << why;
  cv::Rodrigues(SimSceneOptions(o).object.rotation_rad, laid);
  EXPECT_LT(cv::norm(laid * cv::Vec3d(0, 0, 1) - cv::Vec3d(0, -1, 0)), 1e-12) << "on its side";

  ASSERT_TRUE(SimDriverOptionsFromConfig({{"object", "mesh"},
                                          {"mesh", "/data/owl.ply"},
                                          {"mesh_scale", "1000"},
                                          {"mesh_rotation_deg", " 90 , 0, 90"},
                                          {"mesh_surface", "fabric"}},
                                         &o, &why))
      << why;
  scene = SimSceneOptions(o);
  const MeshOptions& mesh = scene.object.mesh;
  EXPECT_EQ(scene.object.type, ObjectType::kMesh);
  EXPECT_EQ(mesh.path, "/data/owl.ply");
  EXPECT_EQ(mesh.scale, 1000);
  EXPECT_EQ(mesh.size_mm, 0);
  EXPECT_EQ(mesh.surface, MeshSurface::kFabric);
  // 90° about x (file y → z, z → −y), then 90° about z (x → y, y → −x).
  cv::Matx33d R;
  cv::Rodrigues(mesh.rotation_rad, R);
  const cv::Vec3d y_to = R * cv::Vec3d(0, 1, 0), z_to = R * cv::Vec3d(0, 0, 1);
  EXPECT_LT(cv::norm(y_to - cv::Vec3d(0, 0, 1)), 1e-12);
  EXPECT_LT(cv::norm(z_to - cv::Vec3d(1, 0, 0)), 1e-12);

  // The board scenes ignore the object and its keys (the daemon switches
  // scenes with the same config).
  ASSERT_TRUE(SimDriverOptionsFromConfig(
      {{"scene", "held_board"}, {"object", "mesh"}, {"mesh", "/data/owl.ply"}}, &o, &why))
      << why;
  EXPECT_EQ(SimSceneOptions(o).object.type, ObjectType::kNone);

  for (const auto& [config, needle] : std::vector<std::pair<DriverConfig, std::string>>{
           {{{"object_position_mm", "10"}}, "'object_position_mm'"},
           {{{"object_position_mm", "200,0"}}, "object_position_mm must be finite and on the"},
           {{{"object_yaw_deg", "1e9"}}, "object_yaw_deg"},
           {{{"object_rotation_deg", "90,0"}}, "'object_rotation_deg'"},
           {{{"object_rotation_deg", "400,0,0"}}, "object_rotation_deg: each angle must be in"},
           {{{"turn", "0"}}, "turn must be in [1, 999]"},
           {{{"turn", "two"}}, "bad value 'two' for sim driver config key 'turn'"},
           {{{"turn_rotations_deg", "90,0,0;"}}, "'turn_rotations_deg'"},
           {{{"turn_rotations_deg", "90,0"}}, "'turn_rotations_deg'"},
           {{{"turn_rotations_deg", "0,0,0;400,0,0"}}, "turn_rotations_deg: each angle must be in"},
           {{{"mesh_colour", "red"}, {"object", "mesh"}, {"mesh", "/a.ply"}},
            "unknown sim driver config key 'mesh_colour' (mesh '/a.ply')"},
       }) {
    EXPECT_FALSE(SimDriverOptionsFromConfig(config, &o, &why)) << needle;
    EXPECT_NE(why.find(needle), std::string::npos) << why;
  }
}

TEST(SimDriverOptions, SceneAndBoardKeys) {
  SimDriverOptions o;
  std::string why;
  ASSERT_TRUE(SimDriverOptionsFromConfig({}, &o, &why)) << why;
  EXPECT_EQ(o.scene, SimSceneType::kObject);
  EXPECT_EQ(o.supersampling, 2);
  auto board_of = [&](const DriverConfig& config) {
    SimDriverOptions options;
    std::string error;
    EXPECT_TRUE(SimDriverOptionsFromConfig(config, &options, &error)) << error;
    return options.board;
  };
  auto same = [](const BoardSpec& a, const BoardSpec& b) {
    return a.type == b.type && a.cols == b.cols && a.rows == b.rows && a.square_mm == b.square_mm &&
           a.marker_mm == b.marker_mm && a.aruco_dictionary == b.aruco_dictionary;
  };
  EXPECT_TRUE(same(board_of({{"scene", "held_board"}}), HeldChessboard()));
  EXPECT_TRUE(same(board_of({{"scene", "held_board"}, {"board_type", "charuco"}}), HeldCharuco()));
  EXPECT_TRUE(same(board_of({{"scene", "platter_board"}}), PlatterChessboard()));
  EXPECT_TRUE(
      same(board_of({{"scene", "platter_board"}, {"board_type", "charuco"}}), PlatterCharuco()));
  // Keys override single fields; a ChArUco marker defaults to 2/3 of the square.
  const BoardSpec custom = board_of({{"scene", "held_board"},
                                     {"board_type", "charuco"},
                                     {"board_cols", "8"},
                                     {"board_rows", "6"},
                                     {"board_square_mm", "15"},
                                     {"board_dictionary", "0"}});
  EXPECT_EQ(custom.cols, 8);
  EXPECT_EQ(custom.rows, 6);
  EXPECT_DOUBLE_EQ(custom.square_mm, 15);
  EXPECT_DOUBLE_EQ(custom.marker_mm, 10);
  EXPECT_EQ(custom.aruco_dictionary, 0);
  EXPECT_DOUBLE_EQ(
      board_of({{"scene", "held_board"}, {"board_type", "charuco"}, {"board_marker_mm", "7.5"}})
          .marker_mm,
      7.5);
  ASSERT_TRUE(SimDriverOptionsFromConfig(
      {{"scene", "platter_board"}, {"object", "egg"}, {"supersampling", "1"}}, &o, &why))
      << why;
  EXPECT_EQ(SimRigOptions(o).supersampling, 1);
  EXPECT_EQ(SimSceneOptions(o).object.type, ObjectType::kNone);  // `object` ignored
  EXPECT_TRUE(SimSceneOptions(o).board.enabled);
  ASSERT_TRUE(SimDriverOptionsFromConfig({{"scene", "held_board"}}, &o, &why)) << why;
  EXPECT_EQ(SimSceneOptions(o).object.type, ObjectType::kNone);
  EXPECT_FALSE(SimSceneOptions(o).board.enabled);  // each frame places it
  for (SimSceneType t :
       {SimSceneType::kObject, SimSceneType::kHeldBoard, SimSceneType::kPlatterBoard}) {
    SimSceneType back = SimSceneType::kObject;
    EXPECT_TRUE(SimSceneTypeFromString(ToString(t), &back));
    EXPECT_EQ(back, t);
  }

  // Refusals name the key.
  const std::vector<std::pair<DriverConfig, std::string>> bad = {
      {{{"scene", "desk"}}, "'scene'"},
      {{{"scene", "held_board"}, {"board_type", "circles"}}, "'board_type'"},
      {{{"scene", "held_board"}, {"board_cols", "nine"}}, "'board_cols'"},
      {{{"scene", "held_board"}, {"board_colz", "9"}}, "'board_colz'"},
      {{{"scene", "held_board"}, {"board_rows", "2"}}, "board_rows"},
      {{{"scene", "held_board"}, {"board_square_mm", "-8"}}, "board_square_mm"},
      {{{"scene", "held_board"}, {"board_type", "charuco"}, {"board_marker_mm", "12"}},
       "board_marker_mm"},
      {{{"scene", "held_board"}, {"board_type", "charuco"}, {"board_cols", "20"}},
       "board_dictionary"},
      {{{"scene", "platter_board"}, {"board_cols", "8"}}, "board_cols + board_rows must be odd"},
      {{{"scene", "platter_board"}, {"board_square_mm", "25"}}, "does not fit on the platter"},
      {{{"supersampling", "5"}}, "supersampling"},
  };
  for (const auto& [config, needle] : bad) {
    EXPECT_FALSE(SimDriverOptionsFromConfig(config, &o, &why)) << needle;
    EXPECT_NE(why.find(needle), std::string::npos) << why;
  }
  // Board keys are not checked by the object scene, which does not show one.
  EXPECT_TRUE(SimDriverOptionsFromConfig({{"board_rows", "2"}}, &o, &why)) << why;
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
