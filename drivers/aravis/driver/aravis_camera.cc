// The Aravis stereo camera driver (aravis_camera.h).
#include "aravis_camera.h"

#include <arpa/inet.h>
#include <arv.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include "craftscan/drivers/reconnect.h"
#include "pairing.h"
#include "pixel_conversion.h"

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
using SteadyClock = std::chrono::steady_clock;

constexpr const char* kDevice = "aravis/camera";
// Frames are waited for in slices this long, so a control-lost signal or a
// USB departure ends a Capture() promptly.
constexpr auto kPopSlice = std::chrono::milliseconds(20);
// Software trigger, frame ids out of step: how long to wait for the lagging
// camera's frame before re-triggering.
constexpr auto kResyncGrace = std::chrono::milliseconds(100);

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

std::string Str(const char* text) { return text != nullptr ? text : ""; }

std::string Fixed(double value, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, value);
  return buf;
}

bool ParseInt(const std::string& text, long min, long max, long* value) {
  long v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || v < min || v > max) return false;
  *value = v;
  return true;
}

bool ParseDouble(const std::string& text, double* value) {
  double v = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
  if (ec != std::errc() || end != text.data() + text.size() || !std::isfinite(v)) return false;
  *value = v;
  return true;
}

bool IsIpv4(const std::string& text) {
  in_addr address{};
  return inet_pton(AF_INET, text.c_str(), &address) == 1;
}

bool EqualsIgnoringCase(const std::string& a, const std::string& b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return std::tolower(static_cast<unsigned char>(x)) ==
                  std::tolower(static_cast<unsigned char>(y));
         });
}

DriverStatus Invalid(std::string message) {
  return DriverStatus::Error(StatusCode::kInvalidArgument, std::move(message));
}

enum class Trigger { kSoftware, kHardware };
enum class UsbMode { kAuto, kOn, kOff };

struct Options {
  std::string left, right;
  long packet_size = 0;  // 0: keep
  long buffers = 4;
  double frame_rate_hz = 0;                     // 0: keep
  const CameraFormat* camera_format = nullptr;  // null: auto
  Trigger trigger = Trigger::kSoftware;
  std::string trigger_source = "Line0";
  std::string trigger_activation = "RisingEdge";
  bool activation_explicit = false;
  Pairing pairing = Pairing::kFrameId;
  std::int64_t pair_tolerance_ns = 1'000'000;
  int pair_retries = 2;
  UsbMode usb = UsbMode::kAuto;
  drivers::ReconnectPolicy policy;
};

std::string CameraFormatNames() {
  std::string names;
  for (const CameraFormat& f : CameraFormats())
    names += (names.empty() ? "" : ", ") + std::string(f.name);
  return names;
}

DriverStatus ParseConfig(const DriverConfig& config, Options* o) {
  bool hardware_keys = false;
  for (const auto& [key, value] : config) {
    long v = 0;
    double d = 0;
    const auto bad = [&](const std::string& expected) {
      return Invalid("config '" + key + "': expected " + expected + ", got '" + value + "'");
    };
    if (key == "left" || key == "right") {
      if (value.empty()) return Invalid("config '" + key + "' is empty");
      (key == "left" ? o->left : o->right) = value;
    } else if (key == "packet_size") {
      if (!ParseInt(value, 220, 65000, &v)) return bad("220..65000");
      o->packet_size = v;
    } else if (key == "buffers") {
      if (!ParseInt(value, 1, 64, &v)) return bad("1..64");
      o->buffers = v;
    } else if (key == "frame_rate_hz") {
      if (!ParseDouble(value, &d) || !(d > 0) || d > 1e6) return bad("a frame rate in Hz > 0");
      o->frame_rate_hz = d;
    } else if (key == "camera_pixel_format") {
      o->camera_format = value == "auto" ? nullptr : FindCameraFormat(value);
      if (value != "auto" && o->camera_format == nullptr) {
        return bad("auto or one of " + CameraFormatNames());
      }
    } else if (key == "trigger") {
      if (value != "software" && value != "hardware") return bad("software or hardware");
      o->trigger = value == "software" ? Trigger::kSoftware : Trigger::kHardware;
    } else if (key == "trigger_source" || key == "trigger_activation") {
      if (value.empty()) return bad("a GenICam enumeration entry");
      if (key == "trigger_source") {
        o->trigger_source = value;
      } else {
        o->trigger_activation = value;
        o->activation_explicit = true;
      }
      hardware_keys = true;
    } else if (key == "pairing") {
      if (value != "frame_id" && value != "timestamp") return bad("frame_id or timestamp");
      o->pairing = value == "frame_id" ? Pairing::kFrameId : Pairing::kTimestamp;
    } else if (key == "pair_tolerance_us") {
      if (!ParseInt(value, 0, 10'000'000, &v)) return bad("0..10000000 (µs)");
      o->pair_tolerance_ns = static_cast<std::int64_t>(v) * 1000;
    } else if (key == "pair_retries") {
      if (!ParseInt(value, 0, 100, &v)) return bad("0..100");
      o->pair_retries = static_cast<int>(v);
    } else if (key == "usb_hotplug") {
      if (value != "auto" && value != "on" && value != "off") return bad("auto, on or off");
      o->usb = value == "auto" ? UsbMode::kAuto : (value == "on" ? UsbMode::kOn : UsbMode::kOff);
    } else if (key == "reconnect_attempts") {
      if (!ParseInt(value, 1, 1000, &v)) return bad("1..1000");
      o->policy.max_attempts = static_cast<int>(v);
    } else if (key == "reconnect_delay_ms") {
      if (!ParseInt(value, 0, 60000, &v)) return bad("0..60000");
      o->policy.initial_delay = std::chrono::milliseconds(v);
      o->policy.max_delay = std::max(o->policy.max_delay, o->policy.initial_delay);
    } else {
      return Invalid("unknown config key '" + key + "'");
    }
  }
  if (o->left.empty() || o->right.empty()) {
    return Invalid("config needs both 'left' and 'right' (address, device id, serial or name)");
  }
  if (hardware_keys && o->trigger != Trigger::kHardware) {
    return Invalid("config 'trigger_source'/'trigger_activation' need trigger=hardware");
  }
  std::string why;
  if (!o->policy.IsValid(&why)) return Invalid("reconnect policy: " + why);
  return DriverStatus::Ok();
}

void OnControlLost(ArvDevice* /*device*/, gpointer data) {
  static_cast<std::atomic<bool>*>(data)->store(true);
}

// One camera of the pair: owns its ArvCamera and ArvStream references.
struct Cam {
  std::string name;      // "left" / "right"
  std::string selector;  // the config value
  ArvCamera* camera = nullptr;
  ArvStream* stream = nullptr;
  gulong lost_handler = 0;
  std::atomic<bool> control_lost{false};
  std::atomic<bool> unplugged{false};  // a USB departure of its serial, no arrival since
  bool is_gv = false, is_usb = false;
  CameraIdentity identity;
  std::string discovered;                // what the last discovery saw (for messages)
  std::vector<std::uint32_t> formats;    // pixel formats the camera offers
  const CameraFormat* format = nullptr;  // in use since Configure
  FrameIdCounter ids;
  std::uint64_t next_frame_id = 0;  // StereoFrame frame id of the next frame
  std::uint64_t id_offset = 0;      // hardware trigger: frame id of count 0
  std::int64_t trigger_ns = 0;
  StreamStatistics last_stats;

  Cam(std::string n, std::string s) : name(std::move(n)), selector(std::move(s)) {}
  ~Cam() { Release(); }
  Cam(const Cam&) = delete;
  Cam& operator=(const Cam&) = delete;

  std::string Label() const { return name + " camera '" + selector + "'"; }

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
};

// A failed control transaction. A value the camera refuses (GenICam error:
// out of range, not writable) is kInvalidArgument; anything else means the
// camera is gone.
DriverStatus CameraError(const Cam& c, GError** error, std::string_view what) {
  const bool refused = *error != nullptr && (*error)->domain == ARV_GC_ERROR;
  return DriverStatus::Error(refused ? StatusCode::kInvalidArgument : StatusCode::kDeviceLost,
                             Take(error, c.Label() + ": " + std::string(what)));
}

// What to give arv_camera_new for a config selector (see the config keys).
// *fresh: whether Aravis's device list was updated during this connect (a
// discovery takes ~1 s; one serves both cameras).
DriverStatus Resolve(const std::string& selector, bool* fresh, std::string* open_as,
                     std::string* discovered) {
  discovered->clear();
  if (IsIpv4(selector)) {
    *open_as = selector;
    return DriverStatus::Ok();
  }
  if (!*fresh) arv_update_device_list();
  *fresh = true;
  std::vector<std::string> matches;
  const unsigned n = arv_get_n_devices();
  for (unsigned i = 0; i < n; ++i) {
    const std::string id = Str(arv_get_device_id(i));
    const std::string serial = Str(arv_get_device_serial_nbr(i));
    const std::string physical = Str(arv_get_device_physical_id(i));
    const std::string address = Str(arv_get_device_address(i));
    *discovered += (discovered->empty() ? "" : "; ") + id + " (serial " + serial + ", " +
                   (address.empty() ? physical : address) + ")";
    if (selector == id || selector == serial || selector == address ||
        (!physical.empty() && EqualsIgnoringCase(selector, physical))) {
      matches.push_back(id);
    }
  }
  if (matches.size() > 1) {
    std::string list;
    for (const std::string& m : matches) list += (list.empty() ? "" : ", ") + m;
    return Invalid("camera '" + selector + "' is ambiguous: it matches " +
                   std::to_string(matches.size()) + " devices (" + list + "); use a device id");
  }
  // No discovery match: Aravis's own lookup (user-defined name, ...).
  *open_as = matches.empty() ? selector : matches.front();
  return DriverStatus::Ok();
}

// Creates a fresh ArvCamera (never reuses an old one) and reads what it
// offers. *fresh: as Resolve.
DriverStatus Connect(Cam& c, bool* fresh) {
  c.Release();
  std::string open_as;
  DriverStatus s = Resolve(c.selector, fresh, &open_as, &c.discovered);
  if (!s.ok()) return s;
  GError* error = nullptr;
  c.camera = arv_camera_new(open_as.c_str(), &error);
  if (c.camera == nullptr) {
    std::string message = Take(&error, "cannot open " + c.Label());
    if (!IsIpv4(c.selector)) {
      message += " (discovered: " + (c.discovered.empty() ? "no cameras" : c.discovered) + ")";
    }
    return DriverStatus::Error(StatusCode::kDeviceLost, message);
  }
  g_clear_error(&error);
  c.is_gv = arv_camera_is_gv_device(c.camera);
  c.is_usb = arv_camera_is_uv_device(c.camera);
  if (!c.is_gv && !c.is_usb) {
    c.Release();
    return DriverStatus::Error(StatusCode::kUnsupported,
                               c.Label() + " is neither a GigE Vision nor a USB3 Vision device");
  }
  // An acquisition left running by an earlier connection (a lost one is
  // never stopped) would keep streaming to that connection's dead stream
  // port: stop it, so the next AcquisitionStart uses the new stream.
  arv_camera_stop_acquisition(c.camera, &error);
  if (error != nullptr) return CameraError(c, &error, "AcquisitionStop");
  const char* serial = arv_camera_get_device_serial_number(c.camera, &error);
  if (error != nullptr) return CameraError(c, &error, "serial number");
  c.identity = {open_as, Str(serial), c.is_gv ? "GigE Vision" : "USB3 Vision", ""};
  guint n = 0;
  gint64* formats = arv_camera_dup_available_pixel_formats(c.camera, &n, &error);
  if (error != nullptr) return CameraError(c, &error, "PixelFormat entries");
  c.formats.clear();
  for (guint i = 0; i < n; ++i) c.formats.push_back(static_cast<std::uint32_t>(formats[i]));
  g_free(formats);
  c.format = nullptr;
  ArvDevice* device = arv_camera_get_device(c.camera);
  c.lost_handler =
      g_signal_connect(device, "control-lost", G_CALLBACK(OnControlLost), &c.control_lost);
  return DriverStatus::Ok();
}

// Entries of a GenICam enumeration, "a, b, c".
std::string EnumerationEntries(ArvCamera* camera, const char* feature) {
  GError* error = nullptr;
  guint n = 0;
  const char** entries =
      arv_camera_dup_available_enumerations_as_strings(camera, feature, &n, &error);
  g_clear_error(&error);
  std::string list;
  for (guint i = 0; entries != nullptr && i < n; ++i) list += (i > 0 ? ", " : "") + Str(entries[i]);
  g_free(entries);
  return list.empty() ? "none" : list;
}

class AravisCameraImpl final : public AravisStereoCamera {
 public:
  AravisCameraImpl(Options options, const HostServices& host, UsbSourceFactory usb_source)
      : options_(std::move(options)),
        host_(host.WithDefaults()),
        reconnector_(options_.policy, host_, kDevice),
        usb_source_(std::move(usb_source)),
        left_("left", options_.left),
        right_("right", options_.right) {}

  ~AravisCameraImpl() override {
    std::lock_guard lock(mutex_);
    CloseLocked();
  }

  // Without the lock: a Capture or Reconnect holds it for seconds, and the
  // host asks for the state meanwhile (status reports).
  CameraState state() const noexcept override { return state_.load(); }
  CameraInfo info() const noexcept override {
    std::lock_guard lock(mutex_);
    return info_;
  }
  StreamStatistics Statistics(bool left) const noexcept override {
    std::lock_guard lock(mutex_);
    return (left ? left_ : right_).Stats();
  }
  PairingStatistics Pairing() const noexcept override {
    std::lock_guard lock(mutex_);
    return pairing_;
  }
  CameraIdentity Identity(bool left) const noexcept override {
    std::lock_guard lock(mutex_);
    return (left ? left_ : right_).identity;
  }
  bool FollowsUsbHotplug() const noexcept override {
    std::lock_guard lock(mutex_);
    return usb_monitor_ != nullptr;
  }

  DriverStatus Open() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kClosed) {
      return drivers::CameraWrongState("Open", state_, "Closed");
    }
    try {
      DriverStatus status = ConnectBoth();
      if (status.ok()) status = CheckCapabilities();
      if (status.ok()) status = StartUsbFollowing();
      if (!status.ok()) {
        StopUsbFollowing();
        left_.Release();
        right_.Release();
        // The pair never appeared: an I/O error, not a loss (Closed stays Closed).
        if (status.code == StatusCode::kDeviceLost) status.code = StatusCode::kIoError;
        Log(LogLevel::kError, status.message);
        return status;
      }
    } catch (const std::exception& e) {
      return DriverStatus::Error(StatusCode::kIoError, std::string("Open: ") + e.what());
    }
    for (Cam* c : {&left_, &right_}) c->next_frame_id = 0;
    pairing_ = {};
    state_ = CameraState::kOpen;
    reconnector_.ReportConnected(info_.model + " " + Describe(left_) + " + " + Describe(right_));
    return DriverStatus::Ok();
  }

  DriverStatus Configure(const CameraSettings& settings) noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ == CameraState::kLost) return LostStatus("Configure");
    if (state_ != CameraState::kOpen && state_ != CameraState::kConfigured) {
      return drivers::CameraWrongState("Configure", state_, "Open or Configured");
    }
    if (DriverStatus s = CheckUnplugged(); !s.ok()) return s;
    std::string why;
    if (!settings.IsValid(&why)) return Invalid(why);
    const cv::Rect sensor({0, 0}, info_.sensor_size);
    if (!settings.roi.empty() && (settings.roi & sensor) != settings.roi) {
      return Invalid("roi lies outside the " + std::to_string(sensor.width) + "x" +
                     std::to_string(sensor.height) + " sensor");
    }
    try {
      const CameraFormat* formats[2] = {nullptr, nullptr};
      DriverStatus status = ChooseFormats(settings, formats);
      if (status.ok()) status = ApplyBoth(settings, formats);
      if (!status.ok()) return Fail(std::move(status));
    } catch (const std::exception& e) {
      return DriverStatus::Error(StatusCode::kIoError, std::string("Configure: ") + e.what());
    }
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
    if (DriverStatus s = CheckUnplugged(); !s.ok()) return s;
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
    if (frame == nullptr) return Invalid("Capture: frame is null");
    if (DriverStatus s = CheckUnplugged(); !s.ok()) return s;
    try {
      return Fail(CaptureLocked(timeout, frame));
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
    if (DriverStatus s = CheckUnplugged(); !s.ok()) return s;
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
    try {
      DriverStatus status = reconnector_.Run(
          [&]() -> DriverStatus {
            for (Cam* c : {&left_, &right_}) {
              if (c->unplugged) {
                return DriverStatus::Error(StatusCode::kDeviceLost,
                                           c->Label() + " (serial " + c->identity.serial +
                                               ") is unplugged; waiting for it to come back");
              }
            }
            // Drop every stale object first, then start from scratch.
            left_.Release();
            right_.Release();
            DriverStatus s = ConnectBoth();
            if (s.ok() &&
                (target == CameraState::kConfigured || target == CameraState::kStreaming)) {
              const CameraFormat* formats[2] = {nullptr, nullptr};
              s = ChooseFormats(settings_, formats);
              if (s.ok()) s = ApplyBoth(settings_, formats);
            }
            if (s.ok() && target == CameraState::kStreaming) s = StartBoth();
            return s;
          },
          usb_monitor_ != nullptr ? &wake_ : nullptr);
      if (!status.ok()) return status;
    } catch (const std::exception& e) {
      return DriverStatus::Error(StatusCode::kIoError, std::string("Reconnect: ") + e.what());
    }
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

  static std::string Describe(const Cam& c) {
    return c.identity.opened_as + " (serial " + c.identity.serial + ", " + c.identity.transport +
           ")";
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

  // A USB departure seen by the hot-plug monitor is a loss (Open..Streaming).
  DriverStatus CheckUnplugged() {
    if (state_ != CameraState::kOpen && state_ != CameraState::kConfigured &&
        state_ != CameraState::kStreaming) {
      return DriverStatus::Ok();
    }
    for (const Cam* c : {&left_, &right_}) {
      if (c->unplugged) {
        return Fail(DriverStatus::Error(
            StatusCode::kDeviceLost,
            c->Label() + " (serial " + c->identity.serial + ") was unplugged (USB hot-plug)"));
      }
    }
    return DriverStatus::Ok();
  }

  // ---- USB hot-plug ----

  DriverStatus StartUsbFollowing() {
    const bool any_usb = left_.is_usb || right_.is_usb;
    if (options_.usb == UsbMode::kOff || (options_.usb == UsbMode::kAuto && !any_usb)) {
      return DriverStatus::Ok();
    }
    {
      std::lock_guard lock(follow_mutex_);
      int i = 0;
      for (Cam* c : {&left_, &right_}) {
        c->unplugged = false;
        followed_[i++] = options_.usb == UsbMode::kOn || c->is_usb ? c->identity.serial : "";
      }
    }
    std::unique_ptr<drivers::UsbEventSource> source =
        usb_source_ ? usb_source_() : drivers::MakeLibusbEventSource();
    usb_monitor_ = std::make_unique<drivers::UsbHotplugMonitor>(
        std::move(source), [this](const drivers::UsbDeviceEvent& e) { OnUsbEvent(e); });
    const DriverStatus s = usb_monitor_->Start();
    if (!s.ok()) {
      usb_monitor_.reset();
      if (options_.usb == UsbMode::kOn) {
        return DriverStatus::Error(s.code, "config usb_hotplug=on: " + s.message);
      }
      Log(LogLevel::kWarning, "USB hot-plug monitoring unavailable (" + s.message +
                                  "): a re-plugged camera is found by the reconnect back-off only");
    }
    return DriverStatus::Ok();
  }

  void StopUsbFollowing() {
    if (usb_monitor_ != nullptr) usb_monitor_->Stop();  // no listener call after this
    usb_monitor_.reset();
    std::lock_guard lock(follow_mutex_);
    followed_[0].clear();
    followed_[1].clear();
  }

  // On the event source's thread. Departures come only from there (libusb's
  // event thread; the devices present at Start are reported as arrivals), so
  // the try_lock never runs on a thread that holds mutex_.
  void OnUsbEvent(const drivers::UsbDeviceEvent& event) {
    Cam* cams[2] = {&left_, &right_};
    bool departed = false;
    std::string arrived;
    {
      std::lock_guard lock(follow_mutex_);
      for (int i = 0; i < 2; ++i) {
        if (followed_[i].empty() || event.serial != followed_[i]) continue;
        if (event.kind == drivers::UsbDeviceEvent::Kind::kLeft) {
          cams[i]->unplugged = true;
          departed = true;
        } else if (cams[i]->unplugged.exchange(false)) {
          arrived = followed_[i];
        }
      }
    }
    if (!arrived.empty()) {
      Log(LogLevel::kInfo, "camera with serial " + arrived + " plugged in again: reconnecting now");
      wake_.Notify();
    }
    if (departed) {
      // Reported now when no call is in progress; else that call reports it
      // (Capture notices within a pop slice).
      std::unique_lock lock(mutex_, std::try_to_lock);
      if (lock.owns_lock()) CheckUnplugged();
    }
  }

  // ---- helpers, called with mutex_ held ----

  void CloseLocked() {
    StopUsbFollowing();
    if (left_.stream != nullptr || right_.stream != nullptr) LogStats();
    if (state_ == CameraState::kStreaming) {
      for (Cam* c : {&left_, &right_}) {
        if (c->camera != nullptr && !c->control_lost && !c->unplugged) {
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
                               std::to_string(s.resent) + ", missing " + std::to_string(s.missing));
    }
  }

  DriverStatus ConnectBoth() {
    bool fresh = false;
    for (Cam* c : {&left_, &right_}) {
      DriverStatus s = Connect(*c, &fresh);
      if (!s.ok()) return s;
    }
    GError* error = nullptr;
    const char* model = arv_camera_get_model_name(left_.camera, &error);
    if (error != nullptr) return CameraError(left_, &error, "model name");
    gint w = 0, h = 0;
    arv_camera_get_sensor_size(left_.camera, &w, &h, &error);
    if (error != nullptr) return CameraError(left_, &error, "sensor size");
    gint rw = 0, rh = 0;
    arv_camera_get_sensor_size(right_.camera, &rw, &rh, &error);
    if (error != nullptr) return CameraError(right_, &error, "sensor size");
    if (rw != w || rh != h) {
      return DriverStatus::Error(StatusCode::kUnsupported,
                                 "left and right sensors differ (" + std::to_string(w) + "x" +
                                     std::to_string(h) + " vs " + std::to_string(rw) + "x" +
                                     std::to_string(rh) + ")");
    }
    info_.model = (model != nullptr ? std::string(model) : "camera") + " (aravis stereo pair)";
    info_.sensor_size = cv::Size(w, h);
    return DriverStatus::Ok();
  }

  // What the config asks of the cameras, checked once they are open.
  DriverStatus CheckCapabilities() {
    for (Cam* c : {&left_, &right_}) {
      GError* error = nullptr;
      if (options_.frame_rate_hz > 0) {
        const gboolean available = arv_camera_is_frame_rate_available(c->camera, &error);
        if (error != nullptr) return CameraError(*c, &error, "AcquisitionFrameRate");
        if (!available) {
          return DriverStatus::Error(
              StatusCode::kUnsupported,
              "config 'frame_rate_hz': the " + c->Label() + " has no AcquisitionFrameRate");
        }
        double min = 0, max = 0;
        arv_camera_get_frame_rate_bounds(c->camera, &min, &max, &error);
        if (error != nullptr) return CameraError(*c, &error, "AcquisitionFrameRate bounds");
        if (options_.frame_rate_hz < min || options_.frame_rate_hz > max) {
          return Invalid("config 'frame_rate_hz': " + Fixed(options_.frame_rate_hz, 3) +
                         " Hz is outside the " + c->Label() + "'s range " + Fixed(min, 3) + ".." +
                         Fixed(max, 3) + " Hz");
        }
      }
      if (options_.camera_format != nullptr &&
          std::find(c->formats.begin(), c->formats.end(), options_.camera_format->pfnc) ==
              c->formats.end()) {
        return Invalid(
            "config 'camera_pixel_format': " + std::string(options_.camera_format->name) +
            " is not offered by the " + c->Label() + " (offers " + FormatNames(c->formats) + ")");
      }
      if (options_.trigger == Trigger::kSoftware) {
        const gboolean software = arv_camera_is_software_trigger_supported(c->camera, &error);
        if (error != nullptr) return CameraError(*c, &error, "TriggerSoftware");
        if (!software) {
          return DriverStatus::Error(
              StatusCode::kUnsupported,
              "the " + c->Label() + " has no software trigger (use trigger=hardware)");
        }
        continue;
      }
      const gboolean source = arv_camera_is_enumeration_entry_available(
          c->camera, "TriggerSource", options_.trigger_source.c_str(), &error);
      g_clear_error(&error);
      if (!source) {
        return Invalid("config 'trigger_source': " + options_.trigger_source +
                       " is not offered by the " + c->Label() + " (offers " +
                       EnumerationEntries(c->camera, "TriggerSource") + ")");
      }
      const gboolean has_activation =
          arv_camera_is_feature_available(c->camera, "TriggerActivation", &error);
      g_clear_error(&error);
      if (!has_activation) {
        if (options_.activation_explicit) {
          return DriverStatus::Error(
              StatusCode::kUnsupported,
              "config 'trigger_activation': the " + c->Label() + " has no TriggerActivation");
        }
        continue;
      }
      const gboolean activation = arv_camera_is_enumeration_entry_available(
          c->camera, "TriggerActivation", options_.trigger_activation.c_str(), &error);
      g_clear_error(&error);
      if (!activation && options_.activation_explicit) {
        return Invalid("config 'trigger_activation': " + options_.trigger_activation +
                       " is not offered by the " + c->Label() + " (offers " +
                       EnumerationEntries(c->camera, "TriggerActivation") + ")");
      }
    }
    return DriverStatus::Ok();
  }

  // The camera format of each camera for `settings`.
  DriverStatus ChooseFormats(const CameraSettings& settings, const CameraFormat* formats[2]) const {
    const Cam* cams[2] = {&left_, &right_};
    for (int i = 0; i < 2; ++i) {
      const CameraFormat* f = options_.camera_format != nullptr
                                  ? options_.camera_format
                                  : ChooseCameraFormat(cams[i]->formats, settings.pixel_format);
      if (f == nullptr) {
        return DriverStatus::Error(StatusCode::kUnsupported,
                                   "pixel_format " + std::string(ToString(settings.pixel_format)) +
                                       ": the " + cams[i]->Label() +
                                       " offers no format the driver converts to it (offers " +
                                       FormatNames(cams[i]->formats) + ")");
      }
      std::string why;
      if (!CanConvert(*f, settings.pixel_format, &why)) {
        return DriverStatus::Error(
            StatusCode::kUnsupported,
            why + (options_.camera_format != nullptr ? " (config camera_pixel_format)" : ""));
      }
      formats[i] = f;
    }
    return DriverStatus::Ok();
  }

  DriverStatus ApplyBoth(const CameraSettings& settings, const CameraFormat* const formats[2]) {
    const cv::Rect roi = settings.roi.empty() ? cv::Rect({0, 0}, info_.sensor_size) : settings.roi;
    const bool hardware = options_.trigger == Trigger::kHardware;
    Cam* cams[2] = {&left_, &right_};
    for (int i = 0; i < 2; ++i) {
      Cam* c = cams[i];
      ArvCamera* cam = c->camera;
      GError* error = nullptr;
      // Every setting is written explicitly: a camera keeps its state across
      // connections. The frame rate first: arv_camera_set_frame_rate turns
      // triggering off, which is set again below.
      if (options_.frame_rate_hz > 0) {
        arv_camera_set_frame_rate(cam, options_.frame_rate_hz, &error);
        if (error != nullptr) return CameraError(*c, &error, "AcquisitionFrameRate");
      }
      arv_camera_set_pixel_format(cam, formats[i]->pfnc, &error);
      if (error != nullptr)
        return CameraError(*c, &error, "PixelFormat " + std::string(formats[i]->name));
      // Region first at origin so any width/height fits.
      arv_camera_set_region(cam, 0, 0, roi.width, roi.height, &error);
      if (error != nullptr) return CameraError(*c, &error, "region size");
      arv_camera_set_region(cam, roi.x, roi.y, roi.width, roi.height, &error);
      if (error != nullptr) return CameraError(*c, &error, "region");
      arv_camera_set_exposure_time(cam, settings.exposure_us, &error);
      if (error != nullptr) return CameraError(*c, &error, "exposure time");
      arv_camera_set_gain(cam, settings.gain_db, &error);
      if (error != nullptr) return CameraError(*c, &error, "gain");
      arv_camera_set_acquisition_mode(cam, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
      if (error != nullptr) return CameraError(*c, &error, "AcquisitionMode");
      arv_camera_set_string(cam, "TriggerSelector", "FrameStart", &error);
      g_clear_error(&error);  // optional feature
      arv_camera_set_string(cam, "TriggerMode", "On", &error);
      if (error != nullptr) return CameraError(*c, &error, "TriggerMode On");
      const std::string source = hardware ? options_.trigger_source : "Software";
      arv_camera_set_string(cam, "TriggerSource", source.c_str(), &error);
      if (error != nullptr) return CameraError(*c, &error, "TriggerSource " + source);
      if (hardware && arv_camera_is_enumeration_entry_available(
                          cam, "TriggerActivation", options_.trigger_activation.c_str(), &error)) {
        arv_camera_set_string(cam, "TriggerActivation", options_.trigger_activation.c_str(),
                              &error);
        if (error != nullptr) {
          return CameraError(*c, &error, "TriggerActivation " + options_.trigger_activation);
        }
      }
      g_clear_error(&error);
      if (options_.packet_size > 0 && c->is_gv) {
        arv_camera_gv_set_packet_size(cam, static_cast<gint>(options_.packet_size), &error);
        if (error != nullptr) return CameraError(*c, &error, "packet size");
      }
      if (options_.frame_rate_hz > 0) {
        const double rate = arv_camera_get_frame_rate(cam, &error);
        if (error != nullptr) return CameraError(*c, &error, "AcquisitionFrameRate");
        Log(LogLevel::kInfo, c->name + " camera: AcquisitionFrameRate " + Fixed(rate, 3) + " Hz");
      }
      c->format = formats[i];
      c->identity.pixel_format = std::string(formats[i]->name);
    }
    return DriverStatus::Ok();
  }

  DriverStatus StartBoth() {
    for (Cam* c : {&left_, &right_}) {
      GError* error = nullptr;
      c->DropStream();
      const guint payload = arv_camera_get_payload(c->camera, &error);
      if (error != nullptr) return CameraError(*c, &error, "payload");
      c->stream = arv_camera_create_stream(c->camera, nullptr, nullptr, &error);
      if (c->stream == nullptr) return CameraError(*c, &error, "create stream");
      g_clear_error(&error);
      for (long i = 0; i < options_.buffers; ++i) {
        arv_stream_push_buffer(c->stream, arv_buffer_new(payload, nullptr));
      }
      arv_camera_start_acquisition(c->camera, &error);
      if (error != nullptr) return CameraError(*c, &error, "AcquisitionStart");
      c->ids.Reset();
      c->id_offset = c->next_frame_id;
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
      if (error != nullptr && result.ok()) result = CameraError(*c, &error, "AcquisitionStop");
      g_clear_error(&error);
      c->DropStream();
    }
    return result;
  }

  // Is the camera still there? (control-lost signal, else a register read)
  static bool Alive(Cam& c, std::string* why) {
    if (c.control_lost) {
      *why = c.Label() + ": control lost";
      return false;
    }
    GError* error = nullptr;
    arv_camera_get_integer(c.camera, "Width", &error);
    if (error != nullptr) {
      *why = Take(&error, c.Label() + " does not answer");
      return false;
    }
    return true;
  }

  struct Received {
    ArvBuffer* buffer = nullptr;
    FrameStamp stamp;
  };

  void Release(Cam& c, Received* r) {
    if (r->buffer != nullptr) arv_stream_push_buffer(c.stream, r->buffer);
    r->buffer = nullptr;
  }

  // The next complete frame of `c`, waiting until `deadline` in slices.
  DriverStatus PopFrame(Cam& c, SteadyClock::time_point deadline, std::chrono::milliseconds timeout,
                        Received* out) {
    for (;;) {
      if (c.control_lost) {
        return DriverStatus::Error(StatusCode::kDeviceLost,
                                   "Capture: " + c.Label() + ": control lost");
      }
      if (c.unplugged) {
        return DriverStatus::Error(StatusCode::kDeviceLost, "Capture: " + c.Label() + " (serial " +
                                                                c.identity.serial +
                                                                ") was unplugged (USB hot-plug)");
      }
      const auto now = SteadyClock::now();
      if (now >= deadline) {
        std::string why;
        if (!Alive(c, &why)) return DriverStatus::Error(StatusCode::kDeviceLost, "Capture: " + why);
        std::string message = "Capture: no frame from the " + c.name + " camera within " +
                              std::to_string(timeout.count()) + " ms";
        if (options_.trigger == Trigger::kHardware) {
          message += " (trigger=hardware on " + options_.trigger_source + ": no trigger pulse?)";
        }
        return DriverStatus::Error(StatusCode::kTimeout, message);
      }
      const auto slice = std::min<SteadyClock::duration>(deadline - now, kPopSlice);
      const auto slice_us = std::chrono::duration_cast<std::chrono::microseconds>(slice).count();
      ArvBuffer* buffer = arv_stream_timeout_pop_buffer(
          c.stream, static_cast<guint64>(std::max<std::int64_t>(1, slice_us)));
      if (buffer == nullptr) continue;
      if (arv_buffer_get_status(buffer) != ARV_BUFFER_STATUS_SUCCESS) {
        const int status = static_cast<int>(arv_buffer_get_status(buffer));
        arv_stream_push_buffer(c.stream, buffer);
        return DriverStatus::Error(StatusCode::kIoError, "Capture: incomplete frame from the " +
                                                             c.name + " camera (buffer status " +
                                                             std::to_string(status) + ")");
      }
      out->buffer = buffer;
      out->stamp.count = c.ids.Count(arv_buffer_get_frame_id(buffer));
      const guint64 device_ns = arv_buffer_get_timestamp(buffer);
      out->stamp.device_ns = static_cast<std::int64_t>(
          device_ns != 0 ? device_ns : arv_buffer_get_system_timestamp(buffer));
      return DriverStatus::Ok();
    }
  }

  // Frames queued before a capture are stale: back to the streams' pools.
  void DrainBoth() {
    for (Cam* c : {&left_, &right_}) {
      while (ArvBuffer* stale = arv_stream_try_pop_buffer(c->stream)) {
        arv_stream_push_buffer(c->stream, stale);
      }
    }
  }

  DriverStatus TriggerBoth() {
    for (Cam* c : {&left_, &right_}) {
      GError* error = nullptr;
      c->trigger_ns = host_.now_ns();
      arv_camera_software_trigger(c->camera, &error);
      if (error != nullptr) return CameraError(*c, &error, "TriggerSoftware");
      ++c->next_frame_id;
    }
    return DriverStatus::Ok();
  }

  DriverStatus CaptureLocked(std::chrono::milliseconds timeout, drivers::StereoFrame* frame) {
    Cam* cams[2] = {&left_, &right_};
    const auto deadline = SteadyClock::now() + timeout;
    const bool software = options_.trigger == Trigger::kSoftware;
    if (resync_) {
      // After a failed capture a frame may be missing on one side: count
      // frames afresh from the next pair.
      for (Cam* c : cams) {
        c->ids.Reset();
        c->id_offset = c->next_frame_id;
      }
      resync_ = false;
    }
    Received got[2];
    const auto release_all = [&] {
      for (int i = 0; i < 2; ++i) Release(*cams[i], &got[i]);
    };
    DriverStatus status;
    for (int tries = 1;; ++tries) {
      DrainBoth();
      if (software) status = TriggerBoth();
      for (int i = 0; i < 2 && status.ok(); ++i)
        status = PopFrame(*cams[i], deadline, timeout, &got[i]);
      std::string refusal;  // why this pair is refused and re-triggered
      while (status.ok()) {
        const PairDecision decision = DecidePair(got[0].stamp, got[1].stamp, options_.pairing,
                                                 options_.pair_tolerance_ns, !software);
        if (decision == PairDecision::kPair) break;
        if (decision == PairDecision::kMismatch) {
          refusal = "left and right timestamps differ by " +
                    Fixed(std::abs(got[0].stamp.device_ns - got[1].stamp.device_ns) / 1e6, 3) +
                    " ms (> " + Fixed(static_cast<double>(options_.pair_tolerance_ns) / 1e6, 3) +
                    " ms, config pair_tolerance_us)";
          break;
        }
        // Frame ids (or, streaming, timestamps) out of step: the older frame
        // is stale; its partner should follow.
        const int drop = decision == PairDecision::kDropLeft ? 0 : 1;
        const std::string counts = "left #" + std::to_string(got[0].stamp.count) + ", right #" +
                                   std::to_string(got[1].stamp.count);
        Release(*cams[drop], &got[drop]);
        ++pairing_.dropped;
        // One software trigger makes one frame per camera: if none follows
        // soon, a frame was missing or extra on one side (a missed or
        // spurious trigger), so count afresh and re-trigger.
        const auto wait_until =
            software ? std::min(deadline, SteadyClock::now() + kResyncGrace) : deadline;
        status = PopFrame(*cams[drop], wait_until, timeout, &got[drop]);
        if (software && status.code == StatusCode::kTimeout && SteadyClock::now() < deadline) {
          status = DriverStatus::Ok();
          refusal = "frame ids out of step (" + counts + ")";
          for (Cam* c : cams) c->ids.Reset();
          break;
        }
      }
      if (!status.ok() || refusal.empty()) break;
      release_all();
      if (tries > options_.pair_retries) {
        return DriverStatus::Error(StatusCode::kIoError,
                                   "Capture: no matching pair in " + std::to_string(tries) +
                                       " tries (config pair_retries " +
                                       std::to_string(options_.pair_retries) + "): " + refusal);
      }
      ++pairing_.refused;
      Log(LogLevel::kDebug, "pair refused, re-triggering: " + refusal);
    }
    if (!status.ok()) {
      release_all();
      resync_ = true;
      return status;
    }
    drivers::CameraImage* images[2] = {&frame->left, &frame->right};
    for (int i = 0; i < 2 && status.ok(); ++i) {
      Cam& c = *cams[i];
      ArvBuffer* buffer = got[i].buffer;
      const CameraFormat* format = FindCameraFormat(arv_buffer_get_image_pixel_format(buffer));
      if (format == nullptr) {
        status = DriverStatus::Error(StatusCode::kUnsupported,
                                     "Capture: the " + c.name + " camera sent pixel format " +
                                         FormatNames({arv_buffer_get_image_pixel_format(buffer)}));
        break;
      }
      size_t size = 0;
      const void* data = arv_buffer_get_data(buffer, &size);
      const int w = arv_buffer_get_image_width(buffer);
      const int h = arv_buffer_get_image_height(buffer);
      gint x_padding = 0, y_padding = 0;
      arv_buffer_get_image_padding(buffer, &x_padding, &y_padding);
      const size_t stride = static_cast<size_t>(std::max(0, w)) * format->bytes_per_pixel +
                            static_cast<size_t>(std::max(0, x_padding));
      std::string why;
      if (!ConvertImage(data, size, w, h, stride, *format, settings_.pixel_format,
                        &images[i]->image, &why)) {
        status = DriverStatus::Error(StatusCode::kIoError, "Capture: malformed frame from the " +
                                                               c.name + " camera: " + why);
        break;
      }
      if (software) {
        images[i]->timestamp_ns = c.trigger_ns;
        images[i]->frame_id = c.next_frame_id - 1;
      } else {
        // Arrival of the frame's leader (Aravis's system timestamp, real
        // time) moved onto the host clock.
        const std::int64_t age_ns =
            static_cast<std::int64_t>(g_get_real_time()) * 1000 -
            static_cast<std::int64_t>(arv_buffer_get_system_timestamp(buffer));
        images[i]->timestamp_ns = host_.now_ns() - std::max<std::int64_t>(0, age_ns);
        images[i]->frame_id = c.id_offset + got[i].stamp.count;
        c.next_frame_id = images[i]->frame_id + 1;
      }
    }
    if (status.ok()) {
      frame->settings = in_force_;
      ++pairing_.pairs;
      pairing_.max_difference_ns = std::max(
          pairing_.max_difference_ns, std::abs(got[0].stamp.device_ns - got[1].stamp.device_ns));
    } else {
      resync_ = true;
    }
    release_all();
    return status;
  }

  mutable std::mutex mutex_;
  const Options options_;
  const HostServices host_;
  const drivers::Reconnector reconnector_;
  const UsbSourceFactory usb_source_;
  Cam left_, right_;
  std::atomic<CameraState> state_{CameraState::kClosed};  // written under mutex_
  CameraState before_loss_ = CameraState::kClosed;
  std::string lost_message_;
  CameraInfo info_;
  CameraSettings settings_;  // last applied (re-applied by Reconnect)
  CameraSettings in_force_;  // as read back at Start
  PairingStatistics pairing_;
  bool resync_ = false;
  // USB hot-plug: the monitor (Open..Close), the serials it follows (index 0
  // left, 1 right; empty: not followed) and the wake for Reconnect.
  std::unique_ptr<drivers::UsbHotplugMonitor> usb_monitor_;
  std::mutex follow_mutex_;
  std::string followed_[2];
  drivers::ReconnectWake wake_;
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
                                                       DriverStatus* status,
                                                       UsbSourceFactory usb_source) noexcept {
  try {
    Options options;
    DriverStatus s = ParseConfig(config, &options);
    if (status != nullptr) *status = s;
    if (!s.ok()) return nullptr;
    return std::make_unique<AravisCameraImpl>(std::move(options), host, std::move(usb_source));
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
