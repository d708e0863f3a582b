// The aravis driver against Aravis's own fake GigE Vision cameras (two
// addresses in a private network namespace, aravis_fakes.h; the tests skip
// when namespaces cannot be created here), plus its pure parts (pixel
// conversion, pairing) without cameras.
//
// USB3 Vision: these machines have no USB bus and Aravis has no fake USB3
// Vision camera, so the hot-plug path is tested with the GigE fakes followed
// by serial (usb_hotplug=on) and a fake USB event source (fake_usb_source.h).
//
// Figures (printed): frame rate and latency of 1280×1024 stereo captures,
// loss detection and recovery times. Run:
//   build/tests/drivers/test_aravis --gtest_filter='*Figures*:*Recovered*:*ArrivalReconnects*'
#include <arv.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "aravis_camera.h"
#include "aravis_fakes.h"
#include "craftscan/drivers/plugin_loader.h"
#include "fake_host.h"
#include "fake_usb_source.h"
#include "pairing.h"
#include "pixel_conversion.h"
#include "test_paths.h"

namespace craftscan::aravis {
namespace {

using drivers::CameraSettings;
using drivers::CameraState;
using drivers::DeviceEvent;
using drivers::PixelFormat;
using drivers::StatusCode;
using drivers::StereoFrame;
using test::ExpectedBgr;
using test::ExpectedMono;
using test::FakeCamera;
using test::FakeCameraOptions;
using test::SameImage;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// ------------------------------------------------- pure parts, no cameras --

TEST(AravisPixelConversion, Mono16KeepsTheHighByte) {
  const CameraFormat* mono16 = FindCameraFormat("Mono16");
  ASSERT_NE(mono16, nullptr);
  // 3×2 pixels, rows 8 bytes apart (2 bytes of padding).
  const std::uint8_t data[] = {0x5A, 10, 0xFF, 20, 0x00, 255, 0, 0,
                               0x01, 1,  0x80, 0,  0x7F, 128, 0, 0};
  cv::Mat image;
  std::string why;
  ASSERT_TRUE(ConvertImage(data, sizeof(data), 3, 2, 8, *mono16, PixelFormat::kMono8, &image, &why))
      << why;
  const cv::Mat expected = (cv::Mat_<std::uint8_t>(2, 3) << 10, 20, 255, 1, 0, 128);
  EXPECT_TRUE(SameImage(image, expected));
  const CameraFormat* mono12 = FindCameraFormat("Mono12");
  ASSERT_NE(mono12, nullptr);
  const std::uint8_t twelve[] = {0xFF, 0x0F, 0x10, 0x00};  // 4095, 16
  ASSERT_TRUE(
      ConvertImage(twelve, sizeof(twelve), 2, 1, 4, *mono12, PixelFormat::kMono8, &image, &why));
  EXPECT_EQ(image.at<std::uint8_t>(0, 0), 255);
  EXPECT_EQ(image.at<std::uint8_t>(0, 1), 1);
  // A mono camera never yields colour; a short buffer is refused.
  EXPECT_FALSE(
      ConvertImage(data, sizeof(data), 3, 2, 8, *mono16, PixelFormat::kBgr8, &image, &why));
  EXPECT_TRUE(Contains(why, "mono8")) << why;
  EXPECT_FALSE(ConvertImage(data, 10, 3, 2, 8, *mono16, PixelFormat::kMono8, &image, &why));
  EXPECT_TRUE(Contains(why, "does not fit")) << why;
}

TEST(AravisPixelConversion, Rgb8BecomesBgrAndBayerIsDemosaiced) {
  const std::uint8_t rgb[] = {10, 20, 30, 40, 50, 60};
  cv::Mat image;
  std::string why;
  ASSERT_TRUE(ConvertImage(rgb, sizeof(rgb), 2, 1, 6, *FindCameraFormat("RGB8Packed"),
                           PixelFormat::kBgr8, &image, &why));
  EXPECT_EQ(image.at<cv::Vec3b>(0, 0), cv::Vec3b(30, 20, 10));
  EXPECT_EQ(image.at<cv::Vec3b>(0, 1), cv::Vec3b(60, 50, 40));
  // A uniform colour (R 200, G 100, B 50) as an RGGB mosaic comes back as
  // that colour away from the border: checks the GenICam→OpenCV naming.
  cv::Mat mosaic(8, 8, CV_8UC1);
  for (int y = 0; y < 8; ++y) {
    for (int x = 0; x < 8; ++x) {
      mosaic.at<std::uint8_t>(y, x) = y % 2 == 0 && x % 2 == 0 ? 200 : (y % 2 && x % 2 ? 50 : 100);
    }
  }
  ASSERT_TRUE(ConvertImage(mosaic.data, 64, 8, 8, 8, *FindCameraFormat("BayerRG8"),
                           PixelFormat::kBgr8, &image, &why));
  for (int y = 2; y < 6; ++y) {
    for (int x = 2; x < 6; ++x)
      EXPECT_EQ(image.at<cv::Vec3b>(y, x), cv::Vec3b(50, 100, 200)) << x << "," << y;
  }
}

TEST(AravisPixelConversion, AutoChoicePrefersNoConversion) {
  const std::vector<std::uint32_t> fake = {ARV_PIXEL_FORMAT_BAYER_BG_8, ARV_PIXEL_FORMAT_MONO_8,
                                           ARV_PIXEL_FORMAT_RGB_8_PACKED, ARV_PIXEL_FORMAT_MONO_16};
  EXPECT_EQ(ChooseCameraFormat(fake, PixelFormat::kMono8)->name, "Mono8");
  EXPECT_EQ(ChooseCameraFormat(fake, PixelFormat::kBgr8)->name, "RGB8");
  const std::vector<std::uint32_t> mono = {ARV_PIXEL_FORMAT_MONO_8, ARV_PIXEL_FORMAT_MONO_12};
  EXPECT_EQ(ChooseCameraFormat(mono, PixelFormat::kBgr8), nullptr);
  EXPECT_EQ(FindCameraFormat("YUV422"), nullptr);
  EXPECT_EQ(FormatNames(mono), "Mono8, Mono12");
}

TEST(AravisPairing, FrameIdsUnwrapThe16BitBlockId) {
  FrameIdCounter ids;
  EXPECT_EQ(ids.Count(65534), 0u);
  EXPECT_EQ(ids.Count(65535), 1u);
  EXPECT_EQ(ids.Count(1), 2u);  // 0 is skipped on the wrap
  EXPECT_EQ(ids.Count(4), 5u);  // two frames lost
  ids.Reset();
  EXPECT_EQ(ids.Count(70000), 0u);  // wider ids as they are
  EXPECT_EQ(ids.Count(70002), 2u);
}

TEST(AravisPairing, Decisions) {
  const FrameStamp a{5, 1'000'000}, b{5, 1'400'000}, c{6, 9'000'000};
  EXPECT_EQ(DecidePair(a, b, Pairing::kFrameId, 0, false), PairDecision::kPair);
  EXPECT_EQ(DecidePair(a, c, Pairing::kFrameId, 0, false), PairDecision::kDropLeft);
  EXPECT_EQ(DecidePair(c, a, Pairing::kFrameId, 0, true), PairDecision::kDropRight);
  EXPECT_EQ(DecidePair(a, b, Pairing::kTimestamp, 400'000, false), PairDecision::kPair);
  EXPECT_EQ(DecidePair(a, b, Pairing::kTimestamp, 399'999, false), PairDecision::kMismatch);
  EXPECT_EQ(DecidePair(a, b, Pairing::kTimestamp, 1000, true), PairDecision::kDropLeft);
  EXPECT_EQ(DecidePair(b, a, Pairing::kTimestamp, 1000, true), PairDecision::kDropRight);
}

// --------------------------------------------------------- fake cameras --

constexpr int kLeftSeed = 11, kRightSeed = 99;

class Aravis : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string why = test::EnterNetns();
    if (!why.empty()) GTEST_SKIP() << "no private network namespace: " << why;
    StartFakes({});
  }

  void StartFakes(const FakeCameraOptions& options) {
    right_.reset();
    left_.reset();
    left_ = std::make_unique<FakeCamera>("127.0.0.1", "LEFT01", kLeftSeed, options);
    right_ = std::make_unique<FakeCamera>("127.0.0.2", "RIGHT01", kRightSeed, options);
    ASSERT_TRUE(left_->running() && right_->running());
  }

  // The camera on a real-time host that records events.
  std::unique_ptr<AravisStereoCamera> Make(drivers::DriverConfig config,
                                           UsbSourceFactory usb = {}) {
    drivers::HostServices host;
    host.events = [this](const drivers::DeviceEventInfo& e) {
      std::lock_guard lock(mutex_);
      events_.push_back(e.event);
    };
    host.log = [](drivers::LogLevel level, std::string_view m) {
      if (level != drivers::LogLevel::kDebug) {
        std::fprintf(stderr, "%.*s\n", static_cast<int>(m.size()), m.data());
      }
    };
    drivers::DriverStatus status;
    auto camera = CreateAravisCamera(config, host, &status, std::move(usb));
    EXPECT_TRUE(status.ok()) << status.ToString();
    return camera;
  }

  static drivers::DriverConfig Config() {
    return {{"left", "127.0.0.1"},
            {"right", "127.0.0.2"},
            {"packet_size", "8000"},
            {"reconnect_attempts", "3"},
            {"reconnect_delay_ms", "100"}};
  }

  // Config() with `extra` added or replacing keys.
  static drivers::DriverConfig With(const drivers::DriverConfig& extra) {
    auto config = Config();
    for (const auto& [key, value] : extra) config[key] = value;
    return config;
  }

  static CameraSettings Settings(cv::Rect roi, PixelFormat format = PixelFormat::kMono8) {
    CameraSettings s;
    s.pixel_format = format;
    s.exposure_us = 2000;
    s.gain_db = 1;
    s.roi = roi;
    return s;
  }

  static void StartStreaming(AravisStereoCamera* camera, const CameraSettings& settings) {
    auto status = camera->Open();
    ASSERT_TRUE(status.ok()) << status.ToString();
    status = camera->Configure(settings);
    ASSERT_TRUE(status.ok()) << status.ToString();
    status = camera->Start();
    ASSERT_TRUE(status.ok()) << status.ToString();
  }

  // Config() plus `extra`, opened, configured with Settings(roi, format) and
  // started; null (with a failure) if any step fails.
  std::unique_ptr<AravisStereoCamera> Streaming(const drivers::DriverConfig& extra, cv::Rect roi,
                                                PixelFormat format = PixelFormat::kMono8) {
    auto camera = Make(With(extra));
    if (!camera) return nullptr;
    StartStreaming(camera.get(), Settings(roi, format));
    if (camera->state() != CameraState::kStreaming) return nullptr;
    return camera;
  }

  std::vector<DeviceEvent> events() {
    std::lock_guard lock(mutex_);
    return events_;
  }

  std::unique_ptr<FakeCamera> left_, right_;
  std::mutex mutex_;
  std::vector<DeviceEvent> events_;
};

TEST_F(Aravis, FramesArriveBitExactAndPaired) {
  auto camera = Make(Config());
  ASSERT_TRUE(camera);
  EXPECT_TRUE(camera->info().sensor_size.empty());  // read from the cameras at Open
  ASSERT_TRUE(camera->Open().ok());
  EXPECT_EQ(camera->info().sensor_size, cv::Size(2048, 2048));
  StereoFrame frame;
  EXPECT_EQ(camera->Capture(milliseconds(100), &frame).code, StatusCode::kWrongState);
  EXPECT_EQ(camera->Configure(Settings({2000, 0, 100, 100})).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(camera->state(), CameraState::kOpen);

  const cv::Rect roi(64, 32, 320, 240);
  ASSERT_TRUE(camera->Configure(Settings(roi)).ok());
  EXPECT_EQ(camera->Identity(true).pixel_format, "Mono8");
  ASSERT_TRUE(camera->Start().ok());
  for (std::uint64_t i = 0; i < 5; ++i) {
    const auto status = camera->Capture(milliseconds(2000), &frame);
    ASSERT_TRUE(status.ok()) << status.ToString();
    EXPECT_TRUE(SameImage(frame.left.image, ExpectedMono(roi, kLeftSeed))) << "left frame " << i;
    EXPECT_TRUE(SameImage(frame.right.image, ExpectedMono(roi, kRightSeed))) << "right frame " << i;
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
  EXPECT_EQ(camera->Pairing().pairs, 5u);
  EXPECT_EQ(camera->Pairing().dropped, 0u);
  EXPECT_EQ(camera->Configure(Settings(roi)).code, StatusCode::kWrongState);
  ASSERT_TRUE(camera->Stop().ok());
  EXPECT_EQ(camera->state(), CameraState::kConfigured);

  // Colour: the fake offers RGB8, delivered as BGR.
  ASSERT_TRUE(camera->Configure(Settings(roi, PixelFormat::kBgr8)).ok());
  EXPECT_EQ(camera->Identity(false).pixel_format, "RGB8");
  EXPECT_EQ(right_->Register(ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT),
            static_cast<guint32>(ARV_PIXEL_FORMAT_RGB_8_PACKED));
  ASSERT_TRUE(camera->Start().ok());
  ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
  EXPECT_TRUE(SameImage(frame.left.image, ExpectedBgr(roi, kLeftSeed)));
  EXPECT_TRUE(SameImage(frame.right.image, ExpectedBgr(roi, kRightSeed)));
  ASSERT_TRUE(camera->Close().ok());
  EXPECT_EQ(camera->state(), CameraState::kClosed);
  EXPECT_EQ(events(), std::vector<DeviceEvent>{DeviceEvent::kConnected});
}

TEST_F(Aravis, CameraPixelFormatsAreConvertedOrRefused) {
  const cv::Rect roi(10, 6, 64, 48);  // even offsets keep the Bayer phase
  {
    auto camera = Streaming({{"camera_pixel_format", "Mono16"}}, roi);
    ASSERT_TRUE(camera);
    EXPECT_EQ(left_->Register(ARV_FAKE_CAMERA_REGISTER_PIXEL_FORMAT),
              static_cast<guint32>(ARV_PIXEL_FORMAT_MONO_16));
    StereoFrame frame;
    ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
    EXPECT_TRUE(SameImage(frame.left.image, ExpectedMono(roi, kLeftSeed)));
    EXPECT_TRUE(SameImage(frame.right.image, ExpectedMono(roi, kRightSeed)));
    ASSERT_TRUE(camera->Stop().ok());
    const auto status = camera->Configure(Settings(roi, PixelFormat::kBgr8));
    EXPECT_EQ(status.code, StatusCode::kUnsupported);
    EXPECT_TRUE(Contains(status.message, "Mono16") &&
                Contains(status.message, "camera_pixel_format"))
        << status.message;
  }
  {
    auto camera = Streaming({{"camera_pixel_format", "BayerRG8"}}, roi, PixelFormat::kBgr8);
    ASSERT_TRUE(camera);
    StereoFrame frame;
    ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
    ASSERT_EQ(frame.left.image.type(), CV_8UC3);
    const cv::Mat inner = frame.left.image(cv::Rect(2, 2, roi.width - 4, roi.height - 4));
    cv::Mat diff;
    cv::absdiff(inner, cv::Scalar(50, 100, 200), diff);
    EXPECT_EQ(cv::countNonZero(diff.reshape(1)), 0);
  }
  {
    auto config = Config();
    config["camera_pixel_format"] = "Mono12";  // the fake does not offer it
    auto camera = Make(config);
    ASSERT_TRUE(camera);
    const auto status = camera->Open();
    EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
    EXPECT_TRUE(Contains(status.message, "Mono12") && Contains(status.message, "offers") &&
                Contains(status.message, "Mono16"))
        << status.message;
    EXPECT_EQ(camera->state(), CameraState::kClosed);
  }
}

TEST_F(Aravis, CamerasAreFoundBySerialDeviceIdOrName) {
  FakeCameraOptions named;
  named.user_name = "RightCam";
  right_.reset();
  right_ = std::make_unique<FakeCamera>("127.0.0.2", "RIGHT01", kRightSeed, named);
  ASSERT_TRUE(right_->running());
  auto config = Config();
  config["left"] = "LEFT01";                // serial number
  config["right"] = "Aravis-Fake-RIGHT01";  // device id
  auto camera = Make(config);
  ASSERT_TRUE(camera);
  auto status = camera->Open();
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(camera->Identity(true).opened_as, "Aravis-Fake-LEFT01");
  EXPECT_EQ(camera->Identity(true).serial, "LEFT01");
  EXPECT_EQ(camera->Identity(true).transport, "GigE Vision");
  EXPECT_EQ(camera->Identity(false).serial, "RIGHT01");
  ASSERT_TRUE(camera->Configure(Settings({0, 0, 32, 32})).ok());
  ASSERT_TRUE(camera->Start().ok());
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
  EXPECT_TRUE(SameImage(frame.left.image, ExpectedMono({0, 0, 32, 32}, kLeftSeed)));  // not swapped
  EXPECT_TRUE(SameImage(frame.right.image, ExpectedMono({0, 0, 32, 32}, kRightSeed)));
  camera->Close();

  config["left"] = "127.0.0.1";
  config["right"] = "RightCam";  // GigE user-defined name (Aravis's own lookup)
  camera = Make(config);
  status = camera->Open();
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_EQ(camera->Identity(false).serial, "RIGHT01");
  camera->Close();

  config["right"] = "NOSUCHCAM";
  camera = Make(config);
  status = camera->Open();
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_TRUE(Contains(status.message, "NOSUCHCAM") &&
              Contains(status.message, "Aravis-Fake-LEFT01"))
      << status.message;  // names what was discovered
}

TEST_F(Aravis, FrameRateIsAppliedAndValidated) {
  auto camera = Streaming({{"frame_rate_hz", "30"}}, {0, 0, 64, 48});
  ASSERT_TRUE(camera);
  for (const auto& fake : {left_.get(), right_.get()}) {
    EXPECT_EQ(fake->Register(ARV_FAKE_CAMERA_REGISTER_ACQUISITION_FRAME_PERIOD_US), 33333u);
    // arv_camera_set_frame_rate turns triggering off; the driver turns it on again.
    EXPECT_EQ(fake->Register(ARV_FAKE_CAMERA_REGISTER_TRIGGER_MODE), 1u);
    EXPECT_EQ(fake->Register(ARV_FAKE_CAMERA_REGISTER_TRIGGER_SOURCE), 1u);  // Software
  }
  StereoFrame frame;
  EXPECT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
  camera->Close();

  camera = Make(With({{"frame_rate_hz", "5000"}}));  // the fake allows 0.1..1000 Hz
  const auto status = camera->Open();
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(status.message, "frame_rate_hz") && Contains(status.message, "1000.000"))
      << status.message;
}

TEST_F(Aravis, HardwareTriggerIsConfiguredAndWaitsForAPulse) {
  drivers::DriverConfig hardware = {
      {"trigger", "hardware"}, {"trigger_source", "Line0"}, {"trigger_activation", "RisingEdge"}};
  auto camera = Streaming(hardware, {0, 0, 64, 48});
  ASSERT_TRUE(camera);
  for (const auto& fake : {left_.get(), right_.get()}) {
    EXPECT_EQ(fake->Register(ARV_FAKE_CAMERA_REGISTER_TRIGGER_MODE), 1u);        // On
    EXPECT_EQ(fake->Register(ARV_FAKE_CAMERA_REGISTER_TRIGGER_SOURCE), 0u);      // Line0
    EXPECT_EQ(fake->Register(ARV_FAKE_CAMERA_REGISTER_TRIGGER_ACTIVATION), 0u);  // RisingEdge
  }
  // The fake has no trigger input: no pulse ever comes.
  StereoFrame frame;
  const auto t0 = Clock::now();
  const auto status = camera->Capture(milliseconds(300), &frame);
  EXPECT_EQ(status.code, StatusCode::kTimeout) << status.ToString();
  EXPECT_TRUE(Contains(status.message, "trigger=hardware on Line0") &&
              Contains(status.message, "no trigger pulse"))
      << status.message;
  EXPECT_LT(MsSince(t0), 1500);
  EXPECT_EQ(camera->state(), CameraState::kStreaming);  // a timeout, not a loss
  EXPECT_TRUE(camera->Stop().ok());
  camera->Close();

  hardware["trigger_activation"] = "FallingEdge";  // the fake only has RisingEdge
  camera = Make(With(hardware));
  auto refused = camera->Open();
  EXPECT_EQ(refused.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(refused.message, "trigger_activation") &&
              Contains(refused.message, "RisingEdge"))
      << refused.message;
  hardware["trigger_activation"] = "RisingEdge";
  hardware["trigger_source"] = "Line3";
  camera = Make(With(hardware));
  refused = camera->Open();
  EXPECT_EQ(refused.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(refused.message, "Line3") && Contains(refused.message, "Line0, Software"))
      << refused.message;
}

TEST_F(Aravis, TimestampPairingRefusesPairsOutsideTheTolerance) {
  FakeCameraOptions fast;  // 1 kHz trigger polling: natural skew ≤ ~1 ms
  fast.trigger_poll_hz = 1000;
  StartFakes(fast);
  auto camera =
      Streaming({{"pairing", "timestamp"}, {"pair_tolerance_us", "5000"}, {"pair_retries", "2"}},
                {0, 0, 32, 32});
  ASSERT_TRUE(camera);
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
  // The right camera's next frame is stamped 20 ms late: refused, re-triggered.
  right_->pattern().timestamp_skew_ns = 20'000'000;
  right_->pattern().skewed_frames_left = 1;
  auto status = camera->Capture(milliseconds(3000), &frame);
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_GE(camera->Pairing().refused, 1u);
  EXPECT_LE(camera->Pairing().max_difference_ns, 5'000'000);
  // Every right frame late: the capture fails after 1 + pair_retries tries.
  right_->pattern().skewed_frames_left = -1;
  status = camera->Capture(milliseconds(3000), &frame);
  EXPECT_EQ(status.code, StatusCode::kIoError);
  double differ_ms = 0;
  const size_t at = status.message.find("differ by ");
  ASSERT_NE(at, std::string::npos) << status.message;
  ASSERT_EQ(std::sscanf(status.message.c_str() + at, "differ by %lf", &differ_ms), 1);
  EXPECT_GT(differ_ms, 5.0);
  EXPECT_TRUE(Contains(status.message, "in 3 tries") && Contains(status.message, "(> 5.000 ms"))
      << status.message;
  EXPECT_EQ(camera->state(), CameraState::kStreaming);
  right_->pattern().skewed_frames_left = 0;
  status = camera->Capture(milliseconds(3000), &frame);
  EXPECT_TRUE(status.ok()) << status.ToString();
}

TEST_F(Aravis, FrameIdPairingSurvivesTheWrapAndASpuriousFrame) {
  FakeCameraOptions fast;
  fast.trigger_poll_hz = 1000;
  StartFakes(fast);
  auto camera = Streaming({}, {0, 0, 16, 16});
  ASSERT_TRUE(camera);
  // The fakes' 16-bit block ids start at 65401 and wrap to 1 after 135 frames.
  StereoFrame frame;
  for (std::uint64_t i = 0; i < 150; ++i) {
    const auto status = camera->Capture(milliseconds(2000), &frame);
    ASSERT_TRUE(status.ok()) << i << ": " << status.ToString();
    ASSERT_EQ(frame.left.frame_id, i);
  }
  EXPECT_EQ(camera->Pairing().pairs, 150u);
  EXPECT_EQ(camera->Pairing().dropped, 0u);
  // A spurious frame on the left (triggered behind the driver's back): the
  // ids are out of step; the driver drops, re-counts and re-triggers.
  const int before = left_->pattern().frames.load();
  arv_fake_camera_write_register(left_->fake(), ARV_FAKE_CAMERA_REGISTER_TRIGGER_SOFTWARE, 1);
  for (int i = 0; i < 200 && left_->pattern().frames.load() == before; ++i) {
    std::this_thread::sleep_for(milliseconds(5));
  }
  ASSERT_EQ(left_->pattern().frames.load(), before + 1);
  std::this_thread::sleep_for(milliseconds(50));  // received by the stream
  const auto status = camera->Capture(milliseconds(2000), &frame);
  ASSERT_TRUE(status.ok()) << status.ToString();
  EXPECT_GE(camera->Pairing().dropped + camera->Pairing().refused, 1u);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
  EXPECT_EQ(frame.left.frame_id, frame.right.frame_id);
}

TEST_F(Aravis, MissingCameraFailsFast) {
  auto config = Config();
  config["right"] = "127.0.0.9";  // nobody there
  auto camera = Make(config);
  ASSERT_TRUE(camera);
  const auto t0 = Clock::now();
  const auto status = camera->Open();
  EXPECT_EQ(status.code, StatusCode::kIoError);
  EXPECT_TRUE(Contains(status.message, "127.0.0.9")) << status.message;
  EXPECT_LT(MsSince(t0), 3000);
  EXPECT_EQ(camera->state(), CameraState::kClosed);
}

TEST_F(Aravis, BadConfigIsRejected) {
  drivers::DriverStatus status;
  EXPECT_FALSE(CreateAravisCamera({{"left", "127.0.0.1"}}, {}, &status));
  EXPECT_EQ(status.code, StatusCode::kInvalidArgument);
  for (const auto& [key, value] : std::vector<std::pair<std::string, std::string>>{
           {"colour", "blue"},
           {"pairing", "nearest"},
           {"pair_tolerance_us", "-1"},
           {"usb_hotplug", "maybe"},
           {"trigger", "external"},
           {"buffers", "0"},
           {"camera_pixel_format", "YUV422"},
           {"frame_rate_hz", "-3"},
           {"trigger_source", "Line1"}}) {  // trigger_source needs trigger=hardware
    auto config = Config();
    config[key] = value;
    EXPECT_FALSE(CreateAravisCamera(config, {}, &status)) << key;
    EXPECT_EQ(status.code, StatusCode::kInvalidArgument) << key;
    EXPECT_TRUE(Contains(status.message, "'" + key + "'")) << status.message;
  }
}

TEST_F(Aravis, LoadsAsPlugin) {
  drivers::PluginLoader loader(::craftscan::testing::PluginDir());
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
  ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());
  EXPECT_TRUE(SameImage(frame.left.image, ExpectedMono({0, 0, 64, 48}, kLeftSeed)));
  EXPECT_FALSE(instance->CreateTurntable(&status));
  EXPECT_EQ(status.code, StatusCode::kUnsupported);
}

TEST_F(Aravis, RestartedCameraIsRecoveredByReconnect) {
  const cv::Rect roi(0, 0, 160, 120);
  auto camera = Streaming({}, roi);
  ASSERT_TRUE(camera);
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());

  right_.reset();  // the right camera goes away mid-stream
  const auto t0 = Clock::now();
  auto status = camera->Capture(milliseconds(300), &frame);
  EXPECT_EQ(status.code, StatusCode::kDeviceLost) << status.ToString();
  const double detect_ms = MsSince(t0);
  EXPECT_EQ(camera->state(), CameraState::kLost);
  EXPECT_EQ(camera->Stop().code, StatusCode::kDeviceLost);

  // The camera comes back (power-cycled: a fresh fake, default state).
  right_ = std::make_unique<FakeCamera>("127.0.0.2", "RIGHT01", kRightSeed);
  ASSERT_TRUE(right_->running());
  const auto t1 = Clock::now();
  status = camera->Reconnect();
  ASSERT_TRUE(status.ok()) << status.ToString();
  const double reconnect_ms = MsSince(t1);
  EXPECT_EQ(camera->state(), CameraState::kStreaming);
  status = camera->Capture(milliseconds(2000), &frame);
  ASSERT_TRUE(status.ok()) << status.ToString();
  const double first_frame_ms = MsSince(t1);
  EXPECT_TRUE(SameImage(frame.left.image, ExpectedMono(roi, kLeftSeed)));
  EXPECT_TRUE(SameImage(frame.right.image, ExpectedMono(roi, kRightSeed)));
  EXPECT_EQ(frame.left.frame_id, 2u);  // the lost capture's trigger left a gap
  EXPECT_EQ(right_->Register(ARV_FAKE_CAMERA_REGISTER_WIDTH), 160u);  // settings re-applied
  const auto ev = events();
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev[1], DeviceEvent::kLost);
  EXPECT_EQ(ev[2], DeviceEvent::kReconnected);
  std::printf(
      "FIGURE recovery (GigE camera killed mid-stream): loss detected in %.0f ms; camera back -> "
      "Reconnect() ok in %.0f ms (reconnect_delay_ms 100), first pair after %.0f ms\n",
      detect_ms, reconnect_ms, first_frame_ms);
  EXPECT_TRUE(camera->Close().ok());
}

// 1280×1024 stereo pairs through the driver: frame rate and latency
// (trigger to both frames converted), with Aravis's default fake (trigger
// register polled at 25 Hz, which bounds it) and with the fakes polling at
// 1 kHz (closer to a camera's trigger latency).
TEST_F(Aravis, Figures1280x1024StereoCapture) {
  for (double poll_hz : {25.0, 1000.0}) {
    FakeCameraOptions options;
    options.trigger_poll_hz = poll_hz;
    StartFakes(options);
    const cv::Rect roi(0, 0, 1280, 1024);
    auto camera = Streaming({}, roi);
    ASSERT_TRUE(camera);
    StereoFrame frame;
    ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());  // warm-up
    const int n = poll_hz < 100 ? 20 : 60;
    std::vector<double> latency_ms;
    const auto t0 = Clock::now();
    for (int i = 0; i < n; ++i) {
      const auto t = Clock::now();
      const auto status = camera->Capture(milliseconds(2000), &frame);
      ASSERT_TRUE(status.ok()) << status.ToString();
      latency_ms.push_back(MsSince(t));
    }
    const double s = MsSince(t0) / 1000;
    EXPECT_TRUE(SameImage(frame.left.image, ExpectedMono(roi, kLeftSeed)));
    EXPECT_TRUE(SameImage(frame.right.image, ExpectedMono(roi, kRightSeed)));
    std::sort(latency_ms.begin(), latency_ms.end());
    const StreamStatistics l = camera->Statistics(true), r = camera->Statistics(false);
    std::printf(
        "FIGURE 1280x1024 mono8 stereo, fake trigger poll %.0f Hz: %d pairs in %.2f s = %.1f "
        "pairs/s; "
        "latency median %.1f ms, p90 %.1f ms, max %.1f ms; completed %llu/%llu, failures "
        "%llu/%llu, "
        "resent %llu/%llu\n",
        poll_hz, n, s, n / s, latency_ms[latency_ms.size() / 2],
        latency_ms[latency_ms.size() * 9 / 10], latency_ms.back(),
        static_cast<unsigned long long>(l.completed), static_cast<unsigned long long>(r.completed),
        static_cast<unsigned long long>(l.failures), static_cast<unsigned long long>(r.failures),
        static_cast<unsigned long long>(l.resent), static_cast<unsigned long long>(r.resent));
    EXPECT_EQ(l.failures + r.failures, 0u);
    EXPECT_TRUE(camera->Close().ok());
  }
}

// ------------------------------------------------------- USB hot-plug ----
// No USB bus here: the GigE fakes are followed by serial (usb_hotplug=on)
// and USB arrivals/departures come from a fake event source.

class AravisUsb : public Aravis {
 protected:
  std::unique_ptr<AravisStereoCamera> MakeFollowed(drivers::test::FakeHost* host, int attempts) {
    auto config = Config();
    config["usb_hotplug"] = "on";
    config["reconnect_attempts"] = std::to_string(attempts);
    config["reconnect_delay_ms"] = "60000";  // a long back-off the arrival must cut short
    drivers::DriverStatus status;
    auto camera = CreateAravisCamera(config, host->services(), &status, [this] {
      auto source = std::make_unique<drivers::test::FakeUsbEventSource>();
      source_ = source.get();
      return source;
    });
    EXPECT_TRUE(status.ok()) << status.ToString();
    return camera;
  }

  drivers::test::FakeUsbEventSource* source_ = nullptr;  // owned by the camera's monitor
};

TEST_F(AravisUsb, DepartureIsALossAndArrivalReconnectsAtOnce) {
  drivers::test::FakeHost host;
  auto camera = MakeFollowed(&host, 3);
  ASSERT_TRUE(camera);
  ASSERT_NO_FATAL_FAILURE(StartStreaming(camera.get(), Settings({0, 0, 32, 32})));
  ASSERT_TRUE(camera->FollowsUsbHotplug());
  ASSERT_NE(source_, nullptr);
  source_->Emit(drivers::test::UsbArrived("LEFT01", 5));  // present at start
  source_->Emit(drivers::test::UsbArrived("RIGHT01", 6));
  source_->Emit(drivers::test::UsbArrived("KEYBOARD", 7, /*u3v=*/false));
  StereoFrame frame;
  ASSERT_TRUE(camera->Capture(milliseconds(2000), &frame).ok());

  // Unplugged: reported at once, without a call in progress.
  source_->Emit(drivers::test::UsbLeft(7));  // not a camera
  EXPECT_EQ(camera->state(), CameraState::kStreaming);
  source_->Emit(drivers::test::UsbLeft(6));
  EXPECT_EQ(camera->state(), CameraState::kLost);
  EXPECT_EQ(host.event_kinds(),
            (std::vector<DeviceEvent>{DeviceEvent::kConnected, DeviceEvent::kLost}));
  auto status = camera->Capture(milliseconds(2000), &frame);
  EXPECT_EQ(status.code, StatusCode::kDeviceLost);
  EXPECT_TRUE(Contains(status.message, "RIGHT01") && Contains(status.message, "unplugged"))
      << status.message;

  // Plugged in again during the 3rd slice (10 ms each) of the 60 s back-off.
  int slices = 0;
  host.OnSleep([&] {
    if (++slices == 3) source_->Emit(drivers::test::UsbArrived("RIGHT01", 9));
  });
  const std::int64_t before_ns = host.now_ns();
  const auto t0 = Clock::now();
  status = camera->Reconnect();
  host.OnSleep({});
  ASSERT_TRUE(status.ok()) << status.ToString();
  const double waited_ms = static_cast<double>(host.now_ns() - before_ns) / 1e6;
  EXPECT_LE(waited_ms, 30.0);  // 3 slices, not the 60 s back-off
  EXPECT_EQ(camera->state(), CameraState::kStreaming);
  status = camera->Capture(milliseconds(2000), &frame);
  ASSERT_TRUE(status.ok()) << status.ToString();
  const auto events = host.events();
  ASSERT_EQ(events.size(), 3u);
  EXPECT_EQ(events[2].event, DeviceEvent::kReconnected);
  EXPECT_EQ(events[2].attempt, 1);
  std::printf(
      "FIGURE recovery (USB re-plug, fake source): reconnect attempt %.0f ms (host clock) after "
      "Reconnect(), instead of the 60000 ms back-off; Reconnect() took %.0f ms real time\n",
      waited_ms, MsSince(t0));
  EXPECT_TRUE(camera->Close().ok());
  EXPECT_FALSE(camera->FollowsUsbHotplug());
}

TEST_F(AravisUsb, WhileUnpluggedAttemptsFailWithoutTouchingTheNetwork) {
  drivers::test::FakeHost host;
  auto camera = MakeFollowed(&host, 3);
  ASSERT_TRUE(camera);
  ASSERT_NO_FATAL_FAILURE(StartStreaming(camera.get(), Settings({0, 0, 32, 32})));
  source_->Emit(drivers::test::UsbArrived("LEFT01", 5));
  source_->Emit(drivers::test::UsbLeft(5));
  ASSERT_EQ(camera->state(), CameraState::kLost);
  const auto t0 = Clock::now();
  const auto status = camera->Reconnect();
  EXPECT_EQ(status.code, StatusCode::kDeviceLost);
  EXPECT_TRUE(Contains(status.message, "unplugged") && Contains(status.message, "LEFT01"))
      << status.message;
  EXPECT_LT(MsSince(t0), 1000);  // no Aravis timeouts: the monitor says it is gone
  EXPECT_EQ(host.event_kinds().back(), DeviceEvent::kGaveUp);
  EXPECT_EQ(camera->state(), CameraState::kLost);
}

TEST_F(AravisUsb, GigECamerasAreNotFollowedByDefault) {
  int sources = 0;
  auto camera = CreateAravisCamera(Config(), {}, nullptr, [&] {
    ++sources;
    return std::make_unique<drivers::test::FakeUsbEventSource>();
  });
  ASSERT_TRUE(camera);
  ASSERT_TRUE(camera->Open().ok());
  EXPECT_FALSE(camera->FollowsUsbHotplug());
  EXPECT_EQ(sources, 0);
}

}  // namespace
}  // namespace craftscan::aravis
