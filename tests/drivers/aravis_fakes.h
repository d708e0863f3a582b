// Aravis fake GigE Vision cameras for the driver tests (test_aravis.cc and the
// conformance suite): a private network namespace where lo carries 127.0.0.1
// and 127.0.0.2 (two fakes need two addresses), and a fake camera whose
// images are a known pattern, so frames can be checked bit-exact.
//
// Pattern: the sample at sensor pixel (X, Y) is p = 7X + 13Y + seed (mod 256),
// written per the pixel format the camera is set to:
//   Mono8     p
//   Mono16    (p << 8) | 0x5A        (little-endian, PFNC)
//   RGB8      R = p, G = p ^ 0x55, B = 255 − p
//   BayerRG8  a uniform colour R 200, G 100, B 50 laid out as an RGGB mosaic
#pragma once

#include <arv.h>
#include <sched.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <string>

#include <opencv2/core.hpp>

namespace craftscan::aravis::test {

inline bool WriteTextFile(const char* path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  return static_cast<bool>(out.flush());
}

// Moves this process into a private network namespace, once per process
// (as root: a plain one; otherwise inside a user namespace mapping us to
// root), with lo up and 127.0.0.2 added. Empty on success, else why not (the
// caller skips).
inline std::string EnterNetns() {
  static const std::string result = [] {
    if (unshare(CLONE_NEWNET) != 0) {
      const uid_t uid = getuid();
      const gid_t gid = getgid();
      if (unshare(CLONE_NEWUSER | CLONE_NEWNET) != 0) {
        return std::string("unshare(CLONE_NEWUSER|CLONE_NEWNET) failed");
      }
      WriteTextFile("/proc/self/setgroups", "deny");
      if (!WriteTextFile("/proc/self/uid_map", "0 " + std::to_string(uid) + " 1") ||
          !WriteTextFile("/proc/self/gid_map", "0 " + std::to_string(gid) + " 1")) {
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

inline std::uint8_t PatternSample(int x, int y, int seed) {
  return static_cast<std::uint8_t>(7 * x + 13 * y + seed);
}

// What the fill callback reads; owned by FakeCamera.
struct FakePattern {
  ArvFakeCamera* fake = nullptr;
  int seed = 0;
  std::atomic<std::int64_t> timestamp_skew_ns{0};  // added to each frame's timestamp
  std::atomic<int> skewed_frames_left{0};          // frames still skewed; < 0: all
  std::atomic<int> frames{0};                      // frames filled
};

inline void FillFakeFrame(ArvBuffer* buffer, void* data, guint32 /*exposure_us*/, guint32 /*gain*/,
                          ArvPixelFormat format) {
  auto* pattern = static_cast<FakePattern*>(data);
  guint32 w = 0, h = 0, x0 = 0, y0 = 0;
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_WIDTH, &w);
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_HEIGHT, &h);
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_X_OFFSET, &x0);
  arv_fake_camera_read_register(pattern->fake, ARV_FAKE_CAMERA_REGISTER_Y_OFFSET, &y0);
  // The buffer's received size is still 0 here: bound by the payload the
  // fake allocated instead.
  auto* bytes = static_cast<std::uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, nullptr)));
  const size_t size = arv_fake_camera_get_payload(pattern->fake);
  const int seed = pattern->seed;
  for (guint32 y = 0; y < h; ++y) {
    for (guint32 x = 0; x < w; ++x) {
      const size_t i = static_cast<size_t>(y) * w + x;
      const int sx = static_cast<int>(x + x0), sy = static_cast<int>(y + y0);
      const std::uint8_t p = PatternSample(sx, sy, seed);
      switch (format) {
        case ARV_PIXEL_FORMAT_MONO_8:
          if (i < size) bytes[i] = p;
          break;
        case ARV_PIXEL_FORMAT_MONO_16:
          if (2 * i + 1 < size) {
            bytes[2 * i] = 0x5A;  // low byte
            bytes[2 * i + 1] = p;
          }
          break;
        case ARV_PIXEL_FORMAT_RGB_8_PACKED:
          if (3 * i + 2 < size) {
            bytes[3 * i] = p;
            bytes[3 * i + 1] = static_cast<std::uint8_t>(p ^ 0x55);
            bytes[3 * i + 2] = static_cast<std::uint8_t>(255 - p);
          }
          break;
        case ARV_PIXEL_FORMAT_BAYER_RG_8:
          if (i < size) {
            const bool even_row = sy % 2 == 0, even_col = sx % 2 == 0;
            bytes[i] = even_row && even_col ? 200 : (!even_row && !even_col ? 50 : 100);
          }
          break;
        default:
          break;
      }
    }
  }
  const int left = pattern->skewed_frames_left.load();
  if (left != 0) {
    arv_buffer_set_timestamp(buffer, arv_buffer_get_timestamp(buffer) +
                                         static_cast<guint64>(pattern->timestamp_skew_ns.load()));
    if (left > 0) --pattern->skewed_frames_left;
  }
  ++pattern->frames;
}

struct FakeCameraOptions {
  cv::Size sensor{2048, 2048};  // the fake's default sensor
  // How often the fake polls its trigger register (Hz). Aravis's default,
  // 25 Hz, adds up to 40 ms to every triggered frame.
  double trigger_poll_hz = 25;
  std::string user_name;  // GigE Vision "user-defined name" (bootstrap 0xE8); empty: none
};

// One Aravis fake GigE Vision camera serving `address` (its GVCP port 3956).
class FakeCamera {
 public:
  FakeCamera(const char* address, const char* serial, int seed,
             const FakeCameraOptions& options = {}) {
    gv_ = arv_gv_fake_camera_new(address, serial);
    if (gv_ == nullptr || !arv_gv_fake_camera_is_running(gv_)) return;
    pattern_.fake = arv_gv_fake_camera_get_fake_camera(gv_);
    pattern_.seed = seed;
    ArvFakeCamera* fake = pattern_.fake;
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_SENSOR_WIDTH,
                                   static_cast<guint32>(options.sensor.width));
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_SENSOR_HEIGHT,
                                   static_cast<guint32>(options.sensor.height));
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_WIDTH,
                                   static_cast<guint32>(std::min(512, options.sensor.width)));
    arv_fake_camera_write_register(fake, ARV_FAKE_CAMERA_REGISTER_HEIGHT,
                                   static_cast<guint32>(std::min(512, options.sensor.height)));
    arv_fake_camera_set_trigger_frequency(fake, options.trigger_poll_hz);
    if (!options.user_name.empty()) {
      char name[16] = {};
      options.user_name.copy(name, sizeof(name) - 1);
      arv_fake_camera_write_memory(fake, 0xE8, sizeof(name), name);  // GVBS user-defined name
    }
    arv_fake_camera_set_fill_pattern(fake, FillFakeFrame, &pattern_);
  }
  FakeCamera(const FakeCamera&) = delete;
  FakeCamera& operator=(const FakeCamera&) = delete;
  ~FakeCamera() {
    if (gv_ != nullptr) g_object_unref(gv_);  // stops the fake's thread
  }

  bool running() const { return gv_ != nullptr && arv_gv_fake_camera_is_running(gv_); }
  ArvFakeCamera* fake() const { return pattern_.fake; }
  FakePattern& pattern() { return pattern_; }
  guint32 Register(guint32 address) const {
    guint32 value = 0;
    arv_fake_camera_read_register(pattern_.fake, address, &value);
    return value;
  }

 private:
  ArvGvFakeCamera* gv_ = nullptr;
  FakePattern pattern_;
};

// The Mono8 image the driver must deliver for `roi` (from Mono8 or Mono16).
inline cv::Mat ExpectedMono(cv::Rect roi, int seed) {
  cv::Mat m(roi.height, roi.width, CV_8UC1);
  for (int y = 0; y < roi.height; ++y) {
    for (int x = 0; x < roi.width; ++x) {
      m.at<std::uint8_t>(y, x) = PatternSample(x + roi.x, y + roi.y, seed);
    }
  }
  return m;
}

// The BGR image the driver must deliver for `roi` from RGB8.
inline cv::Mat ExpectedBgr(cv::Rect roi, int seed) {
  cv::Mat m(roi.height, roi.width, CV_8UC3);
  for (int y = 0; y < roi.height; ++y) {
    for (int x = 0; x < roi.width; ++x) {
      const std::uint8_t p = PatternSample(x + roi.x, y + roi.y, seed);
      m.at<cv::Vec3b>(y, x) =
          cv::Vec3b(static_cast<std::uint8_t>(255 - p), static_cast<std::uint8_t>(p ^ 0x55), p);
    }
  }
  return m;
}

inline bool SameImage(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  cv::Mat diff;
  cv::compare(a.reshape(1), b.reshape(1), diff, cv::CMP_NE);
  return cv::countNonZero(diff) == 0;
}

}  // namespace craftscan::aravis::test
