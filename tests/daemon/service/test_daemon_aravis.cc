// craftscand with the aravis camera driver on two Aravis fake GigE Vision
// cameras (aravis_fakes.h: a private network namespace with 127.0.0.1 and
// 127.0.0.2 on lo; craftscand is spawned inside it) and the serial
// turntable on the PTY GRBL emulator. The fakes serve the sim station's
// rendered views, each frame the view of the angle the emulator's platter
// is at, so the scan is reconstructed from real frames through Aravis, and
// every stored capture can be compared bit-exactly with its render.
//
// One fake is killed mid-scan, after a capture was acknowledged: coming
// back within the driver's reconnect window, the scan completes with every
// view; not coming back, the job fails naming the camera, the session is
// interrupted with every acknowledged capture intact, and once the fake is
// back, `resume` completes it. Skipped where network namespaces cannot be
// made. ~35 s per test (Aravis takes seconds to notice a dead camera and to
// release its objects).
#include <arv.h>

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "../sessions/status_util.h"
#include "aravis_fakes.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "daemon_devices.h"
#include "turntable_emulator.h"

using craftscan::testing::StatusInto;

namespace craftscan::testing {
namespace {

constexpr int kViews = 4;
constexpr double kStepDeg = 90;

// The sim station's raw views of the scan (BGR), as the sim camera renders
// them: view k at turntable angle k · kStepDeg.
struct Renders {
  std::vector<cv::Mat> left, right;
};

const Renders& ViewRenders() {
  static const Renders renders = [] {
    Renders r;
    std::string error;
    sim::SimDriverOptions options;
    if (!sim::SimDriverOptionsFromConfig({{"image_size", "320x256"}}, &options, &error)) {
      ADD_FAILURE() << error;
      return r;
    }
    auto station = sim::SimStation::Create(sim::SimRigOptions(options), &error);
    auto scene = sim::Scene::Create(sim::SimSceneOptions(options), &error);
    if (!station || !scene) {
      ADD_FAILURE() << error;
      return r;
    }
    for (int k = 0; k < kViews; ++k) {
      scene->SetTurntableAngle(k * kStepDeg * CV_PI / 180);
      const sim::StereoRender render =
          station->Render(*scene, static_cast<std::uint64_t>(k), sim::RenderOutputs::kImagesOnly);
      EXPECT_TRUE(render.IsUsable()) << render.message;
      r.left.push_back(render.left);
      r.right.push_back(render.right);
    }
    return r;
  }();
  return renders;
}

// What one fake's fill callback reads (owned by FakeView; outlives its fake).
struct ViewSource {
  const std::vector<cv::Mat>* views = nullptr;  // BGR, one per view
  TurntableEmulator* turntable = nullptr;       // where the platter is
  ArvFakeCamera* fake = nullptr;
  std::atomic<int> frames{0}, bad_formats{0};
};

// Fills a frame with the view of the platter's current angle, as RGB8 (the
// format the driver picks for bgr8 captures).
void FillView(ArvBuffer* buffer, void* data, guint32 /*exposure_us*/, guint32 /*gain*/,
              ArvPixelFormat format) {
  auto* source = static_cast<ViewSource*>(data);
  guint32 w = 0, h = 0, x0 = 0, y0 = 0;
  arv_fake_camera_read_register(source->fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, &w);
  arv_fake_camera_read_register(source->fake, ARV_FAKE_CAMERA_REGISTER_HEIGHT, &h);
  arv_fake_camera_read_register(source->fake, ARV_FAKE_CAMERA_REGISTER_X_OFFSET, &x0);
  arv_fake_camera_read_register(source->fake, ARV_FAKE_CAMERA_REGISTER_Y_OFFSET, &y0);
  auto* bytes = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, nullptr)));
  const std::size_t size = arv_fake_camera_get_payload(source->fake);
  const int n = static_cast<int>(source->views->size());
  const long step = std::lround(source->turntable->machine_position_deg() / kStepDeg);
  const cv::Mat& view = (*source->views)[static_cast<std::size_t>(((step % n) + n) % n)];
  if (format != ARV_PIXEL_FORMAT_RGB_8_PACKED) {
    ++source->bad_formats;
    return;
  }
  for (guint32 y = 0; y < h; ++y) {
    for (guint32 x = 0; x < w; ++x) {
      const std::size_t i = 3 * (static_cast<std::size_t>(y) * w + x);
      const int sx = static_cast<int>(x + x0), sy = static_cast<int>(y + y0);
      if (i + 2 >= size || sx >= view.cols || sy >= view.rows) continue;
      const cv::Vec3b bgr = view.at<cv::Vec3b>(sy, sx);
      bytes[i] = bgr[2];
      bytes[i + 1] = bgr[1];
      bytes[i + 2] = bgr[0];
    }
  }
  ++source->frames;
}

// One fake camera serving the views of one side; can be killed and
// restarted (a new fake on the same address, with every setting again: the
// fake's state is per instance).
class FakeView {
 public:
  FakeView(const char* address, const char* serial, const std::vector<cv::Mat>* views,
           TurntableEmulator* turntable)
      : address_(address), serial_(serial) {
    source_.views = views;
    source_.turntable = turntable;
  }
  ~FakeView() { Kill(); }

  bool Start() {
    aravis::test::FakeCameraOptions options;
    options.sensor = cv::Size(320, 256);
    options.trigger_poll_hz = 200;
    camera_ = std::make_unique<aravis::test::FakeCamera>(address_, serial_, 0, options);
    if (!camera_->running()) return false;
    source_.fake = camera_->fake();
    arv_fake_camera_set_fill_pattern(camera_->fake(), FillView, &source_);
    return true;
  }
  void Kill() { camera_.reset(); }  // stops the fake's thread; its socket closes
  const ViewSource& source() const { return source_; }

 private:
  const char* address_;
  const char* serial_;
  ViewSource source_;
  std::unique_ptr<aravis::test::FakeCamera> camera_;
};

class DaemonAravis : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string why = aravis::test::EnterNetns();
    if (!why.empty()) GTEST_SKIP() << "no private network namespace: " << why;
    ASSERT_EQ(ViewRenders().left.size(), static_cast<std::size_t>(kViews));
  }
  void TearDown() override {
    if (HasFailure()) std::printf("craftscand log:\n%s\n", daemon_.fixture.Log().c_str());
  }

  // Emulator, both fakes, then craftscand (in this namespace) with the
  // aravis driver's reconnect policy `reconnect`.
  bool StartStation(const std::string& reconnect) {
    const std::string link = daemon_.fixture.root() + "/ttyGRBL";
    EmulatorOptions emulator;
    emulator.homing_time = std::chrono::milliseconds(50);
    emulator.link_path = link;
    std::string error;
    turntable_ = TurntableEmulator::Start(emulator, &error);
    if (!turntable_) {
      ADD_FAILURE() << "emulator: " << error;
      return false;
    }
    left_ =
        std::make_unique<FakeView>("127.0.0.1", "LEFT01", &ViewRenders().left, turntable_.get());
    right_ =
        std::make_unique<FakeView>("127.0.0.2", "RIGHT01", &ViewRenders().right, turntable_.get());
    if (!left_->Start() || !right_->Start()) {
      ADD_FAILURE() << "the Aravis fake cameras did not start";
      return false;
    }
    // 3600 deg/min: 1.5 s per step, so the kill lands before the last view.
    return daemon_.Start(
        "  camera: {driver: aravis, config: {left: 127.0.0.1, right: 127.0.0.2, "
        "packet_size: 8000, " +
        reconnect +
        "}}\n"
        "  turntable: {driver: serial_turntable, config: {port: " +
        link + ", feed_deg_min: 3600, command_timeout_ms: 1000, homing_timeout_ms: 5000}}\n");
  }

  // Starts the station, then a scan, and kills the right fake once view 0
  // is acknowledged. The scan's {id, session}, or null (the test failed).
  nlohmann::json ScanAndKillTheRightCamera(const std::string& reconnect,
                                           const std::string& object) {
    if (!StartStation(reconnect)) return nullptr;
    start_ = std::chrono::steady_clock::now();
    nlohmann::json scan = daemon_.ScanUntilFirstCapture(object, kViews);
    if (!scan.is_null()) right_->Kill();
    return scan;
  }

  double SecondsSinceScan() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

  // Every durable capture of `session` is its view's render, bit-exact.
  void ExpectCapturesAreTheRenders(const std::string& session) {
    std::string error;
    auto store = daemon::SessionStore::Open(daemon_.fixture.data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    auto opened = store->OpenSession(session, StatusInto(&error));
    ASSERT_TRUE(opened) << error;
    for (int k : opened->DurableViews()) {
      cv::Mat left, right;
      ASSERT_TRUE(opened->LoadCapture(k, &left, &right, nullptr, &error)) << error;
      EXPECT_TRUE(aravis::test::SameImage(left, ViewRenders().left[k])) << "view " << k << " left";
      EXPECT_TRUE(aravis::test::SameImage(right, ViewRenders().right[k]))
          << "view " << k << " right";
    }
    EXPECT_EQ(left_->source().bad_formats.load(), 0);
  }

  RunningDaemon daemon_;
  std::chrono::steady_clock::time_point start_;
  std::unique_ptr<TurntableEmulator> turntable_;
  std::unique_ptr<FakeView> left_, right_;  // after turntable_: their callbacks read it
};

bool CameraMessageHas(const client::StatusUpdate& s, const std::string& part) {
  return StatusWatcher::Device(s, "camera").message.find(part) != std::string::npos;
}

// The fake is back while the driver is still reconnecting: the job waits
// (the daemon answers meanwhile) and completes with every view.
TEST_F(DaemonAravis, CameraKilledMidScanAndBackInTimeTheScanCompletes) {
  const nlohmann::json scan =
      ScanAndKillTheRightCamera("reconnect_attempts: 8, reconnect_delay_ms: 500", "back");
  ASSERT_FALSE(scan.is_null());
  const std::string session = scan["session"];
  ASSERT_TRUE(daemon_.watcher.WaitFor(
      [](const client::StatusUpdate& s) { return CameraMessageHas(s, "lost"); }, 60s))
      << "the loss never showed in StationStatus\n"
      << daemon_.fixture.Log();
  const double lost_s = SecondsSinceScan();
  // Still serving while the job waits for the camera.
  const auto asked = std::chrono::steady_clock::now();
  const auto status = daemon_.client.Send("status", nullptr, kObserverToken, 10s);
  ASSERT_TRUE(status) << "no answer while the camera reconnects";
  EXPECT_EQ(status->result["job"]["state"], "running") << status->result.dump();
  const double answer_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - asked).count();
  ASSERT_TRUE(right_->Start());

  const nlohmann::json job = WaitForJobEnd(daemon_.client, kObserverToken, scan["id"], 180s);
  const double total_s = SecondsSinceScan();
  ASSERT_EQ(job.value("state", ""), "done") << job.dump() << "\n" << daemon_.fixture.Log();
  EXPECT_NE(daemon_.fixture.Log().find("aravis/camera: reconnected (attempt"), std::string::npos);
  const std::vector<CaptureRecord> acknowledged = daemon_.Acknowledged(session);
  EXPECT_EQ(acknowledged.size(), static_cast<std::size_t>(kViews));
  EXPECT_EQ(daemon_.ExpectNothingLost(session, acknowledged).size(),
            static_cast<std::size_t>(kViews));
  ExpectCapturesAreTheRenders(session);
  EXPECT_GT(job["result"].value("fused_points", 0), 1000) << job.dump();
  std::printf(
      "camera killed after view 0: loss shown after %.1f s, status answered in %.0f ms "
      "meanwhile, scan done after %.1f s; frames served %d left, %d right\n",
      lost_s, answer_ms, total_s, left_->source().frames.load(), right_->source().frames.load());
}

// The fake stays away: the job fails naming the camera, the session is
// interrupted with every acknowledged capture intact, the daemon serves;
// with the fake back, resume completes the session.
TEST_F(DaemonAravis, CameraKilledForGoodFailsTheJobAndResumeFinishesOnceItIsBack) {
  const nlohmann::json scan =
      ScanAndKillTheRightCamera("reconnect_attempts: 2, reconnect_delay_ms: 200", "gone");
  ASSERT_FALSE(scan.is_null());
  const std::string session = scan["session"];
  const nlohmann::json job = WaitForJobEnd(daemon_.client, kObserverToken, scan["id"], 180s);
  const double failed_s = SecondsSinceScan();
  ASSERT_EQ(job.value("state", ""), "failed") << job.dump() << "\n" << daemon_.fixture.Log();
  const std::vector<CaptureRecord> acknowledged = daemon_.Acknowledged(session);
  ASSERT_GE(acknowledged.size(), 1u);
  EXPECT_LT(acknowledged.size(), static_cast<std::size_t>(kViews));
  EXPECT_EQ(daemon_.SessionStateOf(session), daemon::SessionState::kInterrupted);
  EXPECT_EQ(daemon_.ExpectNothingLost(session, acknowledged).size(), acknowledged.size());
  ExpectCapturesAreTheRenders(session);
  daemon_.ExpectFailureReported(job, "camera", {"camera lost", "right camera '127.0.0.2'"});
  EXPECT_TRUE(daemon_.watcher.WaitForDeviceState("camera", "Lost"));
  std::printf(
      "camera killed for good after view 0: job failed after %.1f s with %zu of %d "
      "captures acknowledged, all intact\n",
      failed_s, acknowledged.size(), kViews);

  ASSERT_TRUE(right_->Start());
  const nlohmann::json resume = daemon_.Resume(session);
  ASSERT_FALSE(resume.is_null());
  daemon_.ExpectResumed(session, resume["id"], kViews, acknowledged);
  ExpectCapturesAreTheRenders(session);
  EXPECT_TRUE(daemon_.watcher.WaitForDeviceState("camera", "Streaming"));
}

}  // namespace
}  // namespace craftscan::testing
