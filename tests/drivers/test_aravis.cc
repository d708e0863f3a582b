// The aravis driver against Aravis's own fake GigE Vision cameras. Two fakes
// need two addresses, so each test process moves into a private network
// namespace (unshare) where lo carries 127.0.0.1 and 127.0.0.2; the tests skip
// when namespaces cannot be created here.
#include <arv.h>
#include <fcntl.h>
#include <sched.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "aravis_camera.h"
#include "craftscan/drivers/plugin_loader.h"

namespace craftscan::aravis {
namespace {

using drivers::CameraSettings;
using drivers::CameraState;
using drivers::DeviceEvent;
using drivers::PixelFormat;
using drivers::StatusCode;
using drivers::StereoFrame;
using Clock = std::chrono::steady_clock;

bool WriteFile(const char* path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  return static_cast<bool>(out.flush());
}

// Enters a private network namespace once per process; empty on success,
// else why not.
std::string EnterNetns() {
  static const std::string result = [] {
    if (unshare(CLONE_NEWNET) != 0) {
      const uid_t uid = getuid();
      const gid_t gid = getgid();
      if (unshare(CLONE_NEWUSER | CLONE_NEWNET) != 0) {
        return std::string("unshare(CLONE_NEWUSER|CLONE_NEWNET) failed");
      }
      WriteFile("/proc/self/setgroups", "deny");
      if (!WriteFile("/proc/self/uid_map", "0 " + std::to_string(uid) + " 1") ||
          !WriteFile("/proc/self/gid_map", "0 " + std::to_string(gid) + " 1")) {
        return std::string("cannot map uid/gid in the user namespace");
      }
    }
    if (std::system("ip link set lo up >/dev/null 2>&1 && "
                    "ip addr add 127.0.0.2/8 dev lo >/dev/null 2>&1") != 0) {
      return std::string("cannot bring up lo with 127.0.0.2 (is iproute2 installed?)");
    }
    return std::string();
  }();
  return result;
}

// Fill pattern: pixel (X, Y) in sensor coordinates = 7X + 13Y + seed (mod 256).
// The image geometry comes from the fake's registers (the buffer's image
// fields are not yet set when the fake calls the pattern).
struct Pattern {
  ArvFakeCamera* fake = nullptr;
  int seed = 0;
};

void FillPattern(ArvBuffer* buffer, void* data, guint32 /*exposure_us*/, guint32 /*gain*/,
                 ArvPixelFormat /*format*/) {
  const auto* pattern = static_cast<const Pattern*>(data);
  guint32 w = 0, h = 0, x0 = 0, y0 = 0;
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, &w);
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_HEIGHT, &h);
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_X_OFFSET, &x0);
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_Y_OFFSET, &y0);
  // arv_buffer_get_data's size is the received size, still 0 here: bound by
  // the payload the fake allocated instead.
  auto* bytes = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, nullptr)));
  const size_t size = std::min<size_t>(arv_fake_camera_get_payload(pattern->fake),
                                       static_cast<size_t>(w) * h);
  for (guint32 y = 0; y < h; ++y) {
    for (guint32 x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      if (i < size) bytes[i] = static_cast<std::uint8_t>(7 * (x + x0) + 13 * (y + y0) + static_cast<guint32>(pattern->seed));
    }
  }
}

cv::Mat Expected(cv::Rect roi, int seed) {
  cv::Mat m(roi.height, roi.width, CV_8UC1);
  for (int y = 0; y < roi.height; ++y) {
    for (int x = 0; x < roi.width; ++x) {
      m.at<std::uint8_t>(y, x) =
          static_cast<std::uint8_t>(7 * (x + roi.x) + 13 * (y + roi.y) + seed);
    }
  }
  return m;
}

bool Same(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) != 0) {
    std::fprintf(stderr, "got %d %d %d, want %d %d %d; row1 %d want %d\n", a.at<std::uint8_t>(0, 0), a.at<std::uint8_t>(0, 1), a.at<std::uint8_t>(0, 2), b.at<std::uint8_t>(0, 0), b.at<std::uint8_t>(0, 1), b.at<std::uint8_t>(0, 2), a.at<std::uint8_t>(1, 0), b.at<std::uint8_t>(1, 0));
  }
  return a.size() == b.size() && a.type() == b.type() && cv::countNonZero(a != b) == 0;
}

struct FakeCamera {
  ArvGvFakeCamera* gv = nullptr;
  Pattern pattern;
  FakeCamera(const char* address, const char* serial, int seed) {
    gv = arv_gv_fake_camera_new(address, serial);
    if (gv != nullptr && arv_gv_fake_camera_is_running(gv)) {
      pattern = {arv_gv_fake_camera_get_fake_camera(gv), seed};
      arv_fake_camera_set_fill_pattern(pattern.fake, FillPattern, &pattern);
    }
  }
  FakeCamera(const FakeCamera&) = delete;
  FakeCamera& operator=(const FakeCamera&) = delete;
  ~FakeCamera() {
    if (gv != nullptr) g_object_unref(gv);
  }
  bool running() const { return gv != nullptr && arv_gv_fake_camera_is_running(gv); }
};

constexpr int kLeftSeed = 11, kRightSeed = 99;

class AravisTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string why = EnterNetns();
    if (!why.empty()) GTEST_SKIP() << "no private network namespace: " << why;
    left_ = std::make_unique<FakeCamera>("127.0.0.1", "LEFT01", kLeftSeed);
    right_ = std::make_unique<FakeCamera>("127.0.0.2", "RIGHT01", kRightSeed);
    ASSERT_TRUE(left_->running() && right_->running());
  }

  std::unique_ptr<AravisStereoCamera> Make(drivers::DriverConfig config) {
    drivers::HostServices host;
    host.events = [this](const drivers::DeviceEventInfo& e) {
      std::lock_guard lock(mutex_);
      events_.push_back(e.event);
    };
    host.log = [](drivers::LogLevel, std::string_view m) {
      std::fprintf(stderr, "%.*s\n", static_cast<int>(m.size()), m.data());
    };
    drivers::DriverStatus status;
    auto camera = CreateAravisCamera(config, host, &status);
    EXPECT_TRUE(status.ok()) << status.ToString();
    return camera;
  }

  static drivers::DriverConfig Config() {
    return {{"left", "127.0.0.1"}, {"right", "127.0.0.2"}, {"packet_size", "8000"},
            {"reconnect_attempts", "3"}, {"reconnect_delay_ms", "100"}};
  }

  static CameraSettings Settings(cv::Rect roi) {
    CameraSettings s;
    s.pixel_format = PixelFormat::kMono8;
    s.exposure_us = 2000;
    s.gain_db = 1;
    s.roi = roi;
    return s;
  }

  std::vector<DeviceEvent> events() {
    std::lock_guard lock(mutex_);
    return events_;
  }

  std::unique_ptr<FakeCamera> left_, right_;
  std::mutex mutex_;
  std::vector<DeviceEvent> events_;
};

TEST_F(AravisTest, FramesArriveBitExactAndPaired) {
  auto camera = Make(Config());
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->Open().ok());
  EXPECT_EQ(camera->info().sensor_size, cv::Size(2048, 2048));
  StereoFrame frame;
  EXPECT_EQ(camera->Capture(std::chrono::milliseconds(100), &frame).code,
            StatusCode::kWrongState);
  CameraSettings bgr = Settings({});
  bgr.pixel_format = PixelFormat::kBgr8;
  EXPECT_EQ(camera->Configure(bgr).code, StatusCode::kUnsupported);
  EXPECT_EQ(camera->Configure(Settings({2000, 0, 100, 100})).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(camera->state(), CameraState::kOpen);

  const cv::Rect roi(64, 32, 320, 240);
  ASSERT_TRUE(camera->Configure(Settings(roi)).ok());
  ASSERT_TRUE(camera->Start().ok());
  for (std::uint64_t i = 0; i < 5; ++i) {
    const auto status = camera->Capture(std::chrono::milliseconds(2000), &frame);
    ASSERT_TRUE(status.ok()) << status.ToString();
    EXPECT_TRUE(Same(frame.left.image, Expected(roi, kLeftSeed))) << "left frame " << i;
    EXPECT_TRUE(Same(frame.right.image, Expected(roi, kRightSeed))) << "right frame " << i;
    EXPECT_EQ(frame.left.frame_id, i);
    EXPECT_EQ(frame.right.frame_id, i);
    EXPECT_GT(frame.left.timestamp_ns, 0);
    EXPECT_GE(frame.right.timestamp_ns, frame.left.timestamp_ns);
    EXPECT_EQ(frame.settings.roi, roi);
    EXPECT_EQ(frame.settings.pixel_format, PixelFormat::kMono8);
    EXPECT_DOUBLE_EQ(frame.settings.exposure_us, 2000);
  }
  const StreamStatistics stats = camera->Statistics(true);
  EXPECT_EQ(stats.completed, 5u);
  EXPECT_EQ(stats.failures, 0u);
  EXPECT_EQ(camera->Configure(Settings(roi)).code, StatusCode::kWrongState);
  ASSERT_TRUE(camera->Stop().ok());
  EXPECT_EQ(camera->state(), CameraState::kConfigured);
  ASSERT_TRUE(camera->Close().ok());
  EXPECT_EQ(camera->state(), CameraState::kClosed);
  EXPECT_EQ(events(), std::vector<DeviceEvent>{DeviceEvent::kConnected});
}

TEST_F(AravisTest, FullFrameRate1280x1024) {
  auto camera = Make(Config());
  ASSERT_TRUE(camera && camera->Open().ok());
  const cv::Rect roi(0, 0, 1280, 1024);
  ASSERT_TRUE(camera->Configure(Settings(roi)).ok());
  ASSERT_TRUE(camera->Start().ok());
  StereoFrame frame;
  const int n = 20;
  const auto t0 = Clock::now();
  double worst_ms = 0;
  for (int i = 0; i < n; ++i) {
    const auto t = Clock::now();
    const auto status = camera->Capture(std::chrono::milliseconds(2000), &frame);
    ASSERT_TRUE(status.ok()) << status.ToString();
    worst_ms = std::max(worst_ms, std::chrono::duration<double, std::milli>(Clock::now() - t).count());
  }
  const double s = std::chrono::duration<double>(Clock::now() - t0).count();
  EXPECT_TRUE(Same(frame.left.image, Expected(roi, kLeftSeed)));
  EXPECT_TRUE(Same(frame.right.image, Expected(roi, kRightSeed)));
  const StreamStatistics l = camera->Statistics(true), r = camera->Statistics(false);
  std::printf("1280x1024 stereo: %d pairs in %.3f s = %.1f pairs/s, mean %.1f ms, worst %.1f ms; "
              "left completed %llu failures %llu resent %llu; right completed %llu failures %llu resent %llu\n",
              n, s, n / s, 1000 * s / n, worst_ms,
              static_cast<unsigned long long>(l.completed), static_cast<unsigned long long>(l.failures),
              static_cast<unsigned long long>(l.resent), static_cast<unsigned long long>(r.completed),
              static_cast<unsigned long long>(r.failures), static_cast<unsigned long long>(r.resent));
  EXPECT_TRUE(camera->Close().ok());
}

TEST_F(AravisTest, MissingCameraFailsFast) {
  auto config = Config();
  config["right"] = "127.0.0.9";  // nobody there
  auto camera = Make(config);
  ASSERT_TRUE(camera);
  const auto t0 = Clock::now();
  const auto status = camera->Open();
  const double s = std::chrono::duration<double>(Clock::now() - t0).count();
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_NE(status.message.find("127.0.0.9"), std::string::npos) << status.message;
  EXPECT_LT(s, 3.0);
  EXPECT_EQ(camera->state(), CameraState::kClosed);
}

TEST_F(AravisTest, BadConfigIsRejected) {
  drivers::DriverStatus status;
  EXPECT_FALSE(CreateAravisCamera({{"left", "127.0.0.1"}}, {}, &status));
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  auto config = Config();
  config["colour"] = "blue";
  EXPECT_FALSE(CreateAravisCamera(config, {}, &status));
  EXPECT_NE(status.message.find("colour"), std::string::npos);
}

TEST_F(AravisTest, LoadsAsPlugin) {
  drivers::PluginLoader loader(CRAFTSCAN_PLUGIN_DIR);
  std::shared_ptr<const drivers::Plugin> plugin;
  auto status = loader.Load("aravis", &plugin);
  ASSERT_TRUE(status.ok()) << status.ToString();
  std::unique_ptr<drivers::DriverInstance> instance;
  ASSERT_TRUE(plugin->CreateInstance(Config(), {}, &instance).ok());
  auto camera = instance->CreateCamera(&status);
  ASSERT_TRUE(camera) << status.ToString();
  ASSERT_TRUE(camera->Open().ok());
  ASSERT_TRUE(camera->Configure(Settings({0, 0, 64, 48})).ok());
  ASSERT_TRUE(camera->Start().ok());
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(std::chrono::milliseconds(2000), &frame).ok());
  EXPECT_TRUE(Same(frame.left.image, Expected({0, 0, 64, 48}, kLeftSeed)));
  EXPECT_FALSE(instance->CreateTurntable(&status));
  EXPECT_EQ(status.code, StatusCode::kUnsupported);
}

TEST_F(AravisTest, RestartedCameraIsRecoveredByReconnect) {
  auto camera = Make(Config());
  ASSERT_TRUE(camera && camera->Open().ok());
  const cv::Rect roi(0, 0, 160, 120);
  ASSERT_TRUE(camera->Configure(Settings(roi)).ok());
  ASSERT_TRUE(camera->Start().ok());
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(std::chrono::milliseconds(2000), &frame).ok());

  right_.reset();  // the right camera goes away mid-stream
  const auto t0 = Clock::now();
  auto status = camera->Capture(std::chrono::milliseconds(300), &frame);
  EXPECT_EQ(status.code, StatusCode::kDeviceLost) << status.ToString();
  EXPECT_EQ(camera->state(), CameraState::kLost);
  EXPECT_EQ(camera->Stop().code, StatusCode::kDeviceLost);
  std::printf("loss detected in %.2f s\n",
              std::chrono::duration<double>(Clock::now() - t0).count());

  // The camera comes back (power-cycled: a fresh fake, default state).
  right_ = std::make_unique<FakeCamera>("127.0.0.2", "RIGHT01", kRightSeed);
  ASSERT_TRUE(right_->running());
  const auto t1 = Clock::now();
  status = camera->Reconnect();
  ASSERT_TRUE(status.ok()) << status.ToString();
  std::printf("reconnected in %.2f s\n", std::chrono::duration<double>(Clock::now() - t1).count());
  EXPECT_EQ(camera->state(), CameraState::kStreaming);
  status = camera->Capture(std::chrono::milliseconds(2000), &frame);
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_TRUE(Same(frame.left.image, Expected(roi, kLeftSeed)));
  EXPECT_TRUE(Same(frame.right.image, Expected(roi, kRightSeed)));
  EXPECT_EQ(frame.left.frame_id, 2u);  // the lost capture's trigger left a gap
  const auto ev = events();
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev[1], DeviceEvent::kLost);
  EXPECT_EQ(ev[2], DeviceEvent::kReconnected);
  EXPECT_TRUE(camera->Close().ok());
}

}  // namespace
}  // namespace craftscan::aravis
