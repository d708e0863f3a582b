// The Aravis stereo camera driver (aravis_camera.h).
#include "aravis_camera.h"

#include <arv.h>

#include <algorithm>
#include <atomic>
#include <charconv>
#include <mutex>
#include <string>
#include <utility>

#include "craftscan/drivers/reconnect.h"

namespace craftscan::aravis {
namespace {

using drivers::CameraInfo;
using drivers::CameraSettings;
using drivers::CameraState;
using drivers::DriverConfig;
using drivers::DriverStatus;
using drivers::HostServices;
using drivers::LogLevel;
using drivers::StatusCode;

constexpr const char* kDevice = "aravis/camera";

// Returns the message of *error ("what: message") and frees it.
std::string Take(GError** error, std::string_view what) {
  std::string message(what);
  if (*error != nullptr) {
    message += ": ";
    message += (*error)->message;
    g_clear_error(error);
  }
  return message;
}

bool ParseInt(const std::string& text, long min, long max, long* value) {
  long v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < min || v > max) return false;
  *value = v;
  return true;
}

struct Options {
  std::string left, right;
  long packet_size = 0;  // 0: keep
  long buffers = 4;
  drivers::ReconnectPolicy policy;
};

DriverStatus ParseConfig(const DriverConfig& config, Options* options) {
  for (const auto& [key, value] : config) {
    long v = 0;
    if (key == "left" || key == "right") {
      if (value.empty()) {
        return DriverStatus::Error(StatusCode::kInvalidArgument, "config '" + key + "' is empty");
      }
      (key == "left" ? options->left : options->right) = value;
    } else if (key == "packet_size") {
      if (!ParseInt(value, 220, 65000, &v)) {
        return DriverStatus::Error(StatusCode::kInvalidArgument,
                                   "config 'packet_size': expected 220..65000, got '" + value + "'");
      }
      options->packet_size = v;
    } else if (key == "buffers") {
      if (!ParseInt(value, 1, 64, &v)) {
        return DriverStatus::Error(StatusCode::kInvalidArgument,
                                   "config 'buffers': expected 1..64, got '" + value + "'");
      }
      options->buffers = v;
    } else if (key == "reconnect_attempts") {
      if (!ParseInt(value, 1, 1000, &v)) {
        return DriverStatus::Error(StatusCode::kInvalidArgument,
                                   "config 'reconnect_attempts': expected 1..1000, got '" + value + "'");
      }
      options->policy.max_attempts = static_cast<int>(v);
    } else if (key == "reconnect_delay_ms") {
      if (!ParseInt(value, 0, 60000, &v)) {
        return DriverStatus::Error(StatusCode::kInvalidArgument,
                                   "config 'reconnect_delay_ms': expected 0..60000, got '" + value + "'");
      }
      options->policy.initial_delay = std::chrono::milliseconds(v);
      options->policy.max_delay = std::max(options->policy.max_delay, options->policy.initial_delay);
    } else {
      return DriverStatus::Error(StatusCode::kInvalidArgument, "unknown config key '" + key + "'");
    }
  }
  if (options->left.empty() || options->right.empty()) {
    return DriverStatus::Error(StatusCode::kInvalidArgument,
                               "config needs both 'left' and 'right' (device id or IP address)");
  }
  std::string why;
  if (!options->policy.IsValid(&why)) {
    return DriverStatus::Error(StatusCode::kInvalidArgument, "reconnect policy: " + why);
  }
  return DriverStatus::Ok();
}

void OnControlLost(ArvDevice* /*device*/, gpointer data) {
  static_cast<std::atomic<bool>*>(data)->store(true);
}

// One camera of the pair: owns its ArvCamera and ArvStream references.
struct Cam {
  std::string name;  // "left" / "right"
  std::string id;    // address or device id
  ArvCamera* camera = nullptr;
  ArvStream* stream = nullptr;
  gulong lost_handler = 0;
  std::atomic<bool> control_lost{false};
  std::uint64_t next_frame_id = 0;
  std::int64_t trigger_ns = 0;
  StreamStatistics last_stats;

  Cam(std::string n, std::string i) : name(std::move(n)), id(std::move(i)) {}
  ~Cam() { Release(); }
  Cam(const Cam&) = delete;
  Cam& operator=(const Cam&) = delete;

  StreamStatistics Stats() const {
    if (stream == nullptr) return last_stats;
    StreamStatistics s;
    guint64 completed = 0, failures = 0, underruns = 0;
    arv_stream_get_statistics(stream, &completed, &failures, &underruns);
    s.completed = completed;
    s.failures = failures;
    s.underruns = underruns;
    if (ARV_IS_GV_STREAM(stream)) {
      guint64 resent = 0, missing = 0;
      arv_gv_stream_get_statistics(ARV_GV_STREAM(stream), &resent, &missing);
      s.resent = resent;
      s.missing = missing;
    }
    return s;
  }

  void DropStream() {
    if (stream == nullptr) return;
    last_stats = Stats();
    g_object_unref(stream);
    stream = nullptr;
  }

  void Release() {
    DropStream();
    if (camera != nullptr) {
      if (lost_handler != 0) {
        ArvDevice* device = arv_camera_get_device(camera);
        if (device != nullptr) g_signal_handler_disconnect(device, lost_handler);
        lost_handler = 0;
      }
      g_object_unref(camera);
      camera = nullptr;
    }
    control_lost = false;
  }

  // Creates a fresh ArvCamera (never reuses an old one).
  DriverStatus Connect() {
    Release();
    GError* error = nullptr;
    camera = arv_camera_new(id.c_str(), &error);
    if (camera == nullptr) {
      return DriverStatus::Error(StatusCode::kDeviceLost,
                                 Take(&error, "cannot open " + name + " camera '" + id + "'"));
    }
    g_clear_error(&error);
    if (!arv_camera_is_gv_device(camera)) {
      Release();
      return DriverStatus::Error(StatusCode::kUnsupported,
                                 name + " camera '" + id + "' is not a GigE Vision device");
    }
    ArvDevice* device = arv_camera_get_device(camera);
    lost_handler =
        g_signal_connect(device, "control-lost", G_CALLBACK(OnControlLost), &control_lost);
    return DriverStatus::Ok();
  }
};

class AravisCameraImpl final : public AravisStereoCamera {
 public:
  AravisCameraImpl(Options options, const HostServices& host)
      : options_(std::move(options)),
        host_(host.WithDefaults()),
        reconnector_(options_.policy, host_, kDevice),
        left_("left", options_.left),
        right_("right", options_.right) {}

  ~AravisCameraImpl() override { CloseLocked(); }

  CameraState state() const noexcept override {
    std::lock_guard lock(mutex_);
    return state_;
  }
  CameraInfo info() const noexcept override {
    std::lock_guard lock(mutex_);
    return info_;
  }
  StreamStatistics Statistics(bool left) const noexcept override {
    std::lock_guard lock(mutex_);
    return (left ? left_ : right_).Stats();
  }

  DriverStatus Open() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kClosed) {
      return drivers::CameraWrongState("Open", state_, "Closed");
    }
    DriverStatus status = ConnectBoth();
    if (!status.ok()) {
      left_.Release();
      right_.Release();
      // The pair never appeared: an I/O error, not a loss (Closed stays Closed).
      if (status.code == StatusCode::kDeviceLost) status.code = StatusCode::kIoError;
      Log(LogLevel::kError, status.message);
      return status;
    }
    left_.next_frame_id = right_.next_frame_id = 0;
    state_ = CameraState::kOpen;
    reconnector_.ReportConnected(info_.model + " " + options_.left + " + " + options_.right);
    return DriverStatus::Ok();
  }

  DriverStatus Configure(const CameraSettings& settings) noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ == CameraState::kLost) return LostStatus("Configure");
    if (state_ != CameraState::kOpen && state_ != CameraState::kConfigured) {
      return drivers::CameraWrongState("Configure", state_, "Open or Configured");
    }
    std::string why;
    if (!settings.IsValid(&why)) return DriverStatus::Error(StatusCode::kInvalidArgument, why);
    if (settings.pixel_format != drivers::PixelFormat::kMono8) {
      return DriverStatus::Error(StatusCode::kUnsupported,
                                 "pixel_format " + std::string(ToString(settings.pixel_format)) +
                                     ": the aravis driver supports mono8 only");
    }
    const cv::Rect sensor({0, 0}, info_.sensor_size);
    if (!settings.roi.empty() && (settings.roi & sensor) != settings.roi) {
      return DriverStatus::Error(StatusCode::kInvalidArgument, "roi lies outside the sensor");
    }
    DriverStatus status = ApplyBoth(settings);
    if (!status.ok()) return Fail(status);
    settings_ = settings;
    state_ = CameraState::kConfigured;
    return DriverStatus::Ok();
  }

  DriverStatus Start() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ == CameraState::kLost) return LostStatus("Start");
    if (state_ != CameraState::kConfigured) {
      return drivers::CameraWrongState("Start", state_, "Configured");
    }
    DriverStatus status = StartBoth();
    if (!status.ok()) return Fail(status);
    state_ = CameraState::kStreaming;
    return DriverStatus::Ok();
  }

  DriverStatus Capture(std::chrono::milliseconds timeout,
                       drivers::StereoFrame* frame) noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ == CameraState::kLost) return LostStatus("Capture");
    if (state_ != CameraState::kStreaming) {
      return drivers::CameraWrongState("Capture", state_, "Streaming");
    }
    if (frame == nullptr) {
      return DriverStatus::Error(StatusCode::kInvalidArgument, "Capture: frame is null");
    }
    try {
      return CaptureLocked(timeout, frame);
    } catch (const std::exception& e) {
      return DriverStatus::Error(StatusCode::kIoError, std::string("Capture: ") + e.what());
    }
  }

  DriverStatus Stop() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ == CameraState::kLost) return LostStatus("Stop");
    if (state_ != CameraState::kStreaming) {
      return drivers::CameraWrongState("Stop", state_, "Streaming");
    }
    DriverStatus status = StopBoth();
    if (!status.ok()) return Fail(status);
    state_ = CameraState::kConfigured;
    return DriverStatus::Ok();
  }

  DriverStatus Reconnect() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kLost) {
      return drivers::CameraWrongState("Reconnect", state_, "Lost");
    }
    const CameraState target = before_loss_;
    DriverStatus status = reconnector_.Run([&]() -> DriverStatus {
      // Drop every stale object first, then start from scratch.
      left_.Release();
      right_.Release();
      DriverStatus s = ConnectBoth();
      if (s.ok() && (target == CameraState::kConfigured || target == CameraState::kStreaming)) {
        s = ApplyBoth(settings_);
      }
      if (s.ok() && target == CameraState::kStreaming) s = StartBoth();
      return s;
    });
    if (!status.ok()) return status;
    state_ = target;
    return DriverStatus::Ok();
  }

  DriverStatus Close() noexcept override {
    std::lock_guard lock(mutex_);
    CloseLocked();
    return DriverStatus::Ok();
  }

 private:
  void Log(LogLevel level, std::string_view message) const {
    host_.log(level, std::string("aravis: ").append(message));
  }

  DriverStatus LostStatus(std::string_view call) const {
    return DriverStatus::Error(StatusCode::kDeviceLost,
                               std::string(call) + ": camera is Lost (" + lost_message_ + ")");
  }

  // A failed call: a loss moves to Lost and reports it; other errors pass.
  DriverStatus Fail(DriverStatus status) {
    if (status.code != StatusCode::kDeviceLost) return status;
    before_loss_ = state_;
    state_ = CameraState::kLost;
    lost_message_ = status.message;
    reconnector_.ReportLost(status.message);
    return status;
  }

  void CloseLocked() {
    if (left_.stream != nullptr || right_.stream != nullptr) LogStats();
    if (state_ == CameraState::kStreaming) {
      for (Cam* c : {&left_, &right_}) {
        if (c->camera != nullptr && !c->control_lost) {
          GError* error = nullptr;
          arv_camera_stop_acquisition(c->camera, &error);
          g_clear_error(&error);
        }
      }
    }
    left_.Release();
    right_.Release();
    state_ = CameraState::kClosed;
  }

  void LogStats() const {
    for (const Cam* c : {&left_, &right_}) {
      const StreamStatistics s = c->Stats();
      Log(LogLevel::kInfo, c->name + " stream: completed " + std::to_string(s.completed) +
                               ", failures " + std::to_string(s.failures) + ", underruns " +
                               std::to_string(s.underruns) + ", resent " +
                               std::to_string(s.resent) + ", missing " +
                               std::to_string(s.missing));
    }
  }

  DriverStatus ConnectBoth() {
    for (Cam* c : {&left_, &right_}) {
      DriverStatus s = c->Connect();
      if (!s.ok()) return s;
    }
    GError* error = nullptr;
    const char* model = arv_camera_get_model_name(left_.camera, &error);
    if (error != nullptr) return Lost(left_, &error, "model name");
    gint w = 0, h = 0;
    arv_camera_get_sensor_size(left_.camera, &w, &h, &error);
    if (error != nullptr) return Lost(left_, &error, "sensor size");
    gint rw = 0, rh = 0;
    arv_camera_get_sensor_size(right_.camera, &rw, &rh, &error);
    if (error != nullptr) return Lost(right_, &error, "sensor size");
    if (rw != w || rh != h) {
      return DriverStatus::Error(StatusCode::kUnsupported,
                                 "left and right sensors differ (" + std::to_string(w) + "x" +
                                     std::to_string(h) + " vs " + std::to_string(rw) + "x" +
                                     std::to_string(rh) + ")");
    }
    info_.model = model != nullptr ? model : "GigE Vision camera";
    info_.model += " (aravis stereo pair)";
    info_.sensor_size = cv::Size(w, h);
    return DriverStatus::Ok();
  }

  // A failed control transaction: the camera is treated as gone.
  static DriverStatus Lost(const Cam& c, GError** error, std::string_view what) {
    return DriverStatus::Error(StatusCode::kDeviceLost,
                               Take(error, c.name + " camera '" + c.id + "': " + std::string(what)));
  }

  DriverStatus ApplyBoth(const CameraSettings& settings) {
    const cv::Rect roi =
        settings.roi.empty() ? cv::Rect({0, 0}, info_.sensor_size) : settings.roi;
    for (Cam* c : {&left_, &right_}) {
      ArvCamera* cam = c->camera;
      GError* error = nullptr;
      // Every setting is written explicitly: a camera keeps its state across
      // connections. Region first at origin so any width/height fits.
      arv_camera_set_pixel_format(cam, ARV_PIXEL_FORMAT_MONO_8, &error);
      if (error != nullptr) return Lost(*c, &error, "PixelFormat Mono8");
      arv_camera_set_region(cam, 0, 0, roi.width, roi.height, &error);
      if (error != nullptr) return Lost(*c, &error, "region size");
      arv_camera_set_region(cam, roi.x, roi.y, roi.width, roi.height, &error);
      if (error != nullptr) return Lost(*c, &error, "region");
      arv_camera_set_exposure_time(cam, settings.exposure_us, &error);
      if (error != nullptr) return Lost(*c, &error, "exposure time");
      arv_camera_set_gain(cam, settings.gain_db, &error);
      if (error != nullptr) return Lost(*c, &error, "gain");
      arv_camera_set_acquisition_mode(cam, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
      if (error != nullptr) return Lost(*c, &error, "AcquisitionMode");
      arv_camera_set_string(cam, "TriggerSelector", "FrameStart", &error);
      g_clear_error(&error);  // optional feature
      arv_camera_set_string(cam, "TriggerMode", "On", &error);
      if (error != nullptr) return Lost(*c, &error, "TriggerMode On");
      arv_camera_set_string(cam, "TriggerSource", "Software", &error);
      if (error != nullptr) return Lost(*c, &error, "TriggerSource Software");
      if (options_.packet_size > 0) {
        arv_camera_gv_set_packet_size(cam, static_cast<gint>(options_.packet_size), &error);
        if (error != nullptr) return Lost(*c, &error, "packet size");
      }
    }
    return DriverStatus::Ok();
  }

  DriverStatus StartBoth() {
    for (Cam* c : {&left_, &right_}) {
      GError* error = nullptr;
      c->DropStream();
      const guint payload = arv_camera_get_payload(c->camera, &error);
      if (error != nullptr) return Lost(*c, &error, "payload");
      c->stream = arv_camera_create_stream(c->camera, nullptr, nullptr, &error);
      if (c->stream == nullptr) return Lost(*c, &error, "create stream");
      g_clear_error(&error);
      for (long i = 0; i < options_.buffers; ++i) {
        arv_stream_push_buffer(c->stream, arv_buffer_new(payload, nullptr));
      }
      arv_camera_start_acquisition(c->camera, &error);
      if (error != nullptr) return Lost(*c, &error, "AcquisitionStart");
    }
    in_force_ = settings_;
    GError* error = nullptr;
    const double exposure = arv_camera_get_exposure_time(left_.camera, &error);
    if (error == nullptr) in_force_.exposure_us = exposure;
    g_clear_error(&error);
    const double gain = arv_camera_get_gain(left_.camera, &error);
    if (error == nullptr) in_force_.gain_db = gain;
    g_clear_error(&error);
    return DriverStatus::Ok();
  }

  DriverStatus StopBoth() {
    LogStats();
    DriverStatus result;
    for (Cam* c : {&left_, &right_}) {
      GError* error = nullptr;
      arv_camera_stop_acquisition(c->camera, &error);
      if (error != nullptr && result.ok()) result = Lost(*c, &error, "AcquisitionStop");
      g_clear_error(&error);
      c->DropStream();
    }
    return result;
  }

  // Is the camera still there? (control-lost signal, else a register read)
  bool Alive(Cam& c, std::string* why) {
    if (c.control_lost) {
      *why = c.name + " camera '" + c.id + "': control lost";
      return false;
    }
    GError* error = nullptr;
    arv_camera_get_integer(c.camera, "Width", &error);
    if (error != nullptr) {
      *why = Take(&error, c.name + " camera '" + c.id + "' does not answer");
      return false;
    }
    return true;
  }

  DriverStatus CaptureLocked(std::chrono::milliseconds timeout, drivers::StereoFrame* frame) {
    Cam* cams[2] = {&left_, &right_};
    for (Cam* c : cams) {
      if (c->control_lost) {
        return Fail(DriverStatus::Error(StatusCode::kDeviceLost,
                                        c->name + " camera '" + c->id + "': control lost"));
      }
      // Drop stale frames (from an earlier timed-out capture).
      while (ArvBuffer* stale = arv_stream_try_pop_buffer(c->stream)) {
        arv_stream_push_buffer(c->stream, stale);
      }
    }
    for (Cam* c : cams) {
      GError* error = nullptr;
      c->trigger_ns = host_.now_ns();
      arv_camera_software_trigger(c->camera, &error);
      if (error != nullptr) return Fail(Lost(*c, &error, "TriggerSoftware"));
      ++c->next_frame_id;
    }
    const std::int64_t deadline =
        host_.now_ns() + std::chrono::duration_cast<std::chrono::nanoseconds>(timeout).count();
    ArvBuffer* buffers[2] = {nullptr, nullptr};
    DriverStatus status;
    for (int i = 0; i < 2 && status.ok(); ++i) {
      const std::int64_t left_ns = std::max<std::int64_t>(0, deadline - host_.now_ns());
      buffers[i] = arv_stream_timeout_pop_buffer(cams[i]->stream, static_cast<guint64>(left_ns / 1000));
      if (buffers[i] == nullptr) {
        std::string why;
        if (!Alive(*cams[i], &why)) {
          status = DriverStatus::Error(StatusCode::kDeviceLost, "Capture: " + why);
        } else {
          status = DriverStatus::Error(StatusCode::kTimeout,
                                       "Capture: no frame from the " + cams[i]->name +
                                           " camera within " + std::to_string(timeout.count()) +
                                           " ms");
        }
      } else if (arv_buffer_get_status(buffers[i]) != ARV_BUFFER_STATUS_SUCCESS) {
        status = DriverStatus::Error(
            StatusCode::kIoError, "Capture: incomplete frame from the " + cams[i]->name +
                                      " camera (buffer status " +
                                      std::to_string(static_cast<int>(arv_buffer_get_status(buffers[i]))) + ")");
      } else if (arv_buffer_get_image_pixel_format(buffers[i]) != ARV_PIXEL_FORMAT_MONO_8) {
        status = DriverStatus::Error(StatusCode::kUnsupported,
                                     "Capture: the " + cams[i]->name + " camera sent a non-Mono8 frame");
      }
    }
    if (status.ok()) {
      drivers::CameraImage* images[2] = {&frame->left, &frame->right};
      for (int i = 0; i < 2 && status.ok(); ++i) {
        size_t size = 0;
        const void* data = arv_buffer_get_data(buffers[i], &size);
        const int w = arv_buffer_get_image_width(buffers[i]);
        const int h = arv_buffer_get_image_height(buffers[i]);
        gint x_padding = 0, y_padding = 0;
        arv_buffer_get_image_padding(buffers[i], &x_padding, &y_padding);
        const size_t stride = static_cast<size_t>(w) + static_cast<size_t>(std::max(0, x_padding));
        if (data == nullptr || w <= 0 || h <= 0 ||
            size < stride * static_cast<size_t>(h - 1) + static_cast<size_t>(w)) {
          status = DriverStatus::Error(StatusCode::kIoError,
                                       "Capture: malformed frame from the " + cams[i]->name + " camera");
          break;
        }
        images[i]->image =
            cv::Mat(h, w, CV_8UC1, const_cast<void*>(data), stride).clone();
        images[i]->timestamp_ns = cams[i]->trigger_ns;
        images[i]->frame_id = cams[i]->next_frame_id - 1;
      }
      frame->settings = in_force_;
    }
    for (int i = 0; i < 2; ++i) {
      if (buffers[i] != nullptr) arv_stream_push_buffer(cams[i]->stream, buffers[i]);
    }
    return Fail(std::move(status));
  }

  mutable std::mutex mutex_;
  const Options options_;
  const HostServices host_;
  const drivers::Reconnector reconnector_;
  Cam left_, right_;
  CameraState state_ = CameraState::kClosed;
  CameraState before_loss_ = CameraState::kClosed;
  std::string lost_message_;
  CameraInfo info_;
  CameraSettings settings_;  // last applied (re-applied by Reconnect)
  CameraSettings in_force_;  // as read back at Start
};

class AravisInstance final : public drivers::DriverInstance {
 public:
  AravisInstance(DriverConfig config, const HostServices& host)
      : config_(std::move(config)), host_(host) {}
  std::unique_ptr<drivers::StereoCamera> CreateCamera(DriverStatus* status) noexcept override {
    return CreateAravisCamera(config_, host_, status);
  }
  std::unique_ptr<drivers::Turntable> CreateTurntable(DriverStatus* status) noexcept override {
    if (status != nullptr) {
      *status = DriverStatus::Error(StatusCode::kUnsupported, "the aravis driver has no turntable");
    }
    return nullptr;
  }

 private:
  DriverConfig config_;
  HostServices host_;
};

}  // namespace

std::unique_ptr<AravisStereoCamera> CreateAravisCamera(const DriverConfig& config,
                                                       const HostServices& host,
                                                       DriverStatus* status) noexcept {
  try {
    Options options;
    DriverStatus s = ParseConfig(config, &options);
    if (status != nullptr) *status = s;
    if (!s.ok()) return nullptr;
    return std::make_unique<AravisCameraImpl>(std::move(options), host);
  } catch (const std::exception& e) {
    if (status != nullptr) *status = DriverStatus::Error(StatusCode::kIoError, e.what());
    return nullptr;
  }
}

drivers::DriverInstance* CreateAravisInstance(const DriverConfig& config, const HostServices& host,
                                              DriverStatus* status) noexcept {
  try {
    Options options;
    DriverStatus s = ParseConfig(config, &options);
    if (status != nullptr) *status = s;
    if (!s.ok()) return nullptr;
    return new AravisInstance(config, host);
  } catch (const std::exception& e) {
    if (status != nullptr) *status = DriverStatus::Error(StatusCode::kIoError, e.what());
    return nullptr;
  }
}

}  // namespace craftscan::aravis
