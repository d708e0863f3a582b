#include "craftscan/daemon/devices.h"

#include <cstdio>
#include <thread>
#include <utility>

#include "craftscan/pipeline/stereo/exposure_merge.h"

namespace craftscan::daemon {
namespace {

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

drivers::DriverStatus Error(drivers::StatusCode code, std::string message) {
  return drivers::DriverStatus::Error(code, std::move(message));
}

std::string FormatMultiple(double multiple) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", multiple);
  return text;
}

}  // namespace

DeviceManager::DeviceManager(DeviceSetup setup,
                             std::function<void(drivers::LogLevel, std::string_view)> log,
                             std::function<void()> on_change)
    : setup_(std::move(setup)),
      log_(std::move(log)),
      on_change_(std::move(on_change)),
      loader_(setup_.plugin_path),
      camera_settings_(setup_.camera_settings) {}

DeviceManager::~DeviceManager() { Close(); }

void DeviceManager::Note(const std::string& device, const std::string& message) {
  {
    std::lock_guard lock(mutex_);
    (device == "camera" ? camera_message_ : turntable_message_) = message;
  }
  if (on_change_) on_change_();
}

bool DeviceManager::Open(std::string* error) {
  return OpenLocked(setup_.camera, setup_.turntable, error);
}

bool DeviceManager::OpenLocked(const DeviceSpec& camera_spec, const DeviceSpec& turntable_spec,
                               std::string* error) {
  Close();
  drivers::HostServices host;
  host.log = [this](drivers::LogLevel level, std::string_view message) {
    if (log_) log_(level, message);
  };
  host.events = [this](const drivers::DeviceEventInfo& event) {
    const bool is_camera = event.device.find("camera") != std::string::npos;
    std::string text = std::string(drivers::ToString(event.event));
    if (event.attempt > 0) text += " (attempt " + std::to_string(event.attempt) + ")";
    if (!event.message.empty()) text += ": " + event.message;
    Note(is_camera ? "camera" : "turntable", text);
    if (log_) log_(drivers::LogLevel::kInfo, event.device + ": " + text);
  };

  auto create = [&](const DeviceSpec& spec, std::unique_ptr<drivers::DriverInstance>* instance) {
    std::shared_ptr<const drivers::Plugin> plugin;
    drivers::DriverStatus s = loader_.Load(spec.driver, &plugin);
    if (!s.ok()) return Fail(error, "driver '" + spec.driver + "': " + s.ToString());
    s = plugin->CreateInstance(spec.config, host, instance);
    if (!s.ok()) return Fail(error, "driver '" + spec.driver + "': " + s.ToString());
    return true;
  };
  if (!create(camera_spec, &camera_instance_)) return false;
  drivers::DriverInstance* turntable_source = camera_instance_.get();
  if (turntable_spec.driver != camera_spec.driver || turntable_spec.config != camera_spec.config) {
    if (!create(turntable_spec, &turntable_instance_)) return false;
    turntable_source = turntable_instance_.get();
  }
  drivers::DriverStatus s;
  auto camera = camera_instance_->CreateCamera(&s);
  if (!camera) return Fail(error, "camera (driver '" + camera_spec.driver + "'): " + s.ToString());
  auto turntable = turntable_source->CreateTurntable(&s);
  if (!turntable)
    return Fail(error, "turntable (driver '" + turntable_spec.driver + "'): " + s.ToString());

  if (s = camera->Open(); !s.ok()) return Fail(error, "camera: " + s.ToString());
  const drivers::CameraSettings settings = camera_settings();
  if (s = camera->Configure(settings); !s.ok()) return Fail(error, "camera: " + s.ToString());
  if (s = camera->Start(); !s.ok()) return Fail(error, "camera: " + s.ToString());
  if (s = turntable->Open(); !s.ok()) return Fail(error, "turntable: " + s.ToString());
  if (s = turntable->Home(setup_.home_timeout); !s.ok())
    return Fail(error, "turntable: " + s.ToString());
  {
    std::lock_guard devices_lock(devices_mutex_);
    std::lock_guard lock(mutex_);
    camera_ = std::move(camera);
    turntable_ = std::move(turntable);
    camera_message_ = "connected";
    turntable_message_ = "connected, homed";
  }
  open_ = true;
  if (on_change_) on_change_();
  return true;
}

void DeviceManager::Close() {
  std::unique_ptr<drivers::StereoCamera> camera;
  std::unique_ptr<drivers::Turntable> turntable;
  {
    std::lock_guard lock(devices_mutex_);
    camera = std::move(camera_);
    turntable = std::move(turntable_);
  }
  open_ = false;
  if (camera) {
    if (camera->state() == drivers::CameraState::kStreaming) camera->Stop();
    camera->Close();
  }
  if (turntable) turntable->Close();
  camera.reset();
  turntable.reset();
  camera_instance_.reset();
  turntable_instance_.reset();
}

std::vector<DeviceReport> DeviceManager::Reports() const {
  std::string camera_state = "absent", turntable_state = "absent";
  {
    std::lock_guard lock(devices_mutex_);
    if (camera_) camera_state = std::string(drivers::ToString(camera_->state()));
    if (turntable_) turntable_state = std::string(drivers::ToString(turntable_->Status().state));
  }
  std::lock_guard lock(mutex_);
  return {{"camera", "stereo_camera", setup_.camera.driver, camera_state, camera_message_},
          {"turntable", "turntable", setup_.turntable.driver, turntable_state, turntable_message_}};
}

bool DeviceManager::IsSim() const { return setup_.camera.driver == "sim"; }

drivers::CameraSettings DeviceManager::camera_settings() const {
  std::lock_guard lock(mutex_);
  return camera_settings_;
}

drivers::DriverStatus DeviceManager::ShowCalibrationTarget(CalibrationTarget target,
                                                           const BoardSpec& board) {
  return SwitchScene(target == CalibrationTarget::kHeldBoard ? "held_board" : "platter_board",
                     &board);
}

drivers::DriverStatus DeviceManager::ShowObject() { return SwitchScene("object", nullptr); }

drivers::DriverStatus DeviceManager::ShowTurn(int turn) {
  if (!IsSim() || (scene_ == "object" && turn == turn_)) return drivers::DriverStatus::Ok();
  drivers::DriverConfig config = setup_.camera.config;
  if (turn > 1) config["turn"] = std::to_string(turn);
  if (drivers::DriverStatus s = ReopenSim(config); !s.ok())
    return Error(s.code, "turn " + std::to_string(turn) + ": " + s.message);
  scene_ = "object";
  turn_ = turn;
  return drivers::DriverStatus::Ok();
}

drivers::DriverStatus DeviceManager::SwitchScene(const std::string& scene, const BoardSpec* board) {
  if (!IsSim() || (scene == scene_ && scene == "object" && turn_ == 1))
    return drivers::DriverStatus::Ok();
  drivers::DriverConfig config = setup_.camera.config;
  if (scene != "object") {
    config["scene"] = scene;
    if (board) {
      config["board_type"] = std::string(ToString(board->type));
      config["board_cols"] = std::to_string(board->cols);
      config["board_rows"] = std::to_string(board->rows);
      config["board_square_mm"] = std::to_string(board->square_mm);
      if (board->type == BoardSpec::Type::kCharuco) {
        config["board_marker_mm"] = std::to_string(board->marker_mm);
        config["board_dictionary"] = std::to_string(board->aruco_dictionary);
      }
    }
  }
  if (drivers::DriverStatus s = ReopenSim(config); !s.ok()) return s;
  scene_ = scene;
  turn_ = 1;
  return drivers::DriverStatus::Ok();
}

drivers::DriverStatus DeviceManager::ReopenSim(const drivers::DriverConfig& camera_config) {
  DeviceSpec camera = setup_.camera, turntable = setup_.turntable;
  const bool shared = camera.driver == turntable.driver && camera.config == turntable.config;
  camera.config = camera_config;
  if (shared) turntable = camera;
  std::string error;
  if (!OpenLocked(camera, turntable, &error)) {
    std::string ignored;
    OpenLocked(setup_.camera, setup_.turntable, &ignored);  // back to the object, turn 1
    scene_ = "object";
    turn_ = 1;
    return Error(drivers::StatusCode::kIoError, error);
  }
  return drivers::DriverStatus::Ok();
}

drivers::DriverStatus DeviceManager::Capture(drivers::StereoFrame* frame,
                                             const std::atomic<bool>& cancel) {
  if (!camera_) return Error(drivers::StatusCode::kWrongState, "camera: not open");
  std::string last;
  drivers::StatusCode last_code = drivers::StatusCode::kTimeout;
  for (int attempt = 0; attempt < setup_.capture_retries; ++attempt) {
    if (cancel) return Error(drivers::StatusCode::kAborted, "camera: capture cancelled");
    drivers::DriverStatus s = camera_->Capture(setup_.capture_timeout, frame);
    if (s.ok()) return s;
    last = s.ToString();
    last_code = s.code;
    Note("camera", last);
    if (s.code == drivers::StatusCode::kDeviceLost ||
        camera_->state() == drivers::CameraState::kLost) {
      if (log_) log_(drivers::LogLevel::kWarning, "camera lost: " + last + "; reconnecting");
      const drivers::DriverStatus r = camera_->Reconnect();
      if (!r.ok()) {
        return Error(drivers::StatusCode::kDeviceLost,
                     "camera lost and not recovered: " + r.ToString());
      }
      continue;
    }
    if (s.code != drivers::StatusCode::kTimeout && s.code != drivers::StatusCode::kIoError) {
      return Error(s.code, "camera: " + last);
    }
    if (log_) log_(drivers::LogLevel::kWarning, "capture failed: " + last + "; trying again");
  }
  return Error(last_code, "camera: " + std::to_string(setup_.capture_retries) +
                              " captures failed; last: " + last);
}

drivers::DriverStatus DeviceManager::CaptureBracketed(const std::vector<double>& bracket,
                                                      drivers::StereoFrame* frame,
                                                      const std::atomic<bool>& cancel) {
  const drivers::DriverStatus s = Capture(frame, cancel);
  if (!s.ok()) return s;
  return AddExposures(bracket, frame, cancel);
}

drivers::DriverStatus DeviceManager::AddExposures(const std::vector<double>& bracket,
                                                  drivers::StereoFrame* frame,
                                                  const std::atomic<bool>& cancel) {
  drivers::DriverStatus s;
  if (bracket.empty()) return s;
  const drivers::CameraSettings reference = camera_settings();
  std::vector<cv::Mat> left{frame->left.image}, right{frame->right.image};
  std::vector<double> exposure{1.0};
  for (const double multiple : bracket) {
    drivers::CameraSettings longer = reference;
    longer.exposure_us = reference.exposure_us * multiple;
    std::string error;
    drivers::StereoFrame extra;
    if (!ApplyCameraSettings(longer, &error)) {
      s = Error(drivers::StatusCode::kInvalidArgument,
                "exposure bracket x" + FormatMultiple(multiple) + ": " + error);
    } else {
      s = Capture(&extra, cancel);
    }
    if (!s.ok()) break;
    left.push_back(extra.left.image);
    right.push_back(extra.right.image);
    exposure.push_back(multiple);
  }
  std::string error;
  if (!ApplyCameraSettings(reference, &error)) {
    const std::string why = "exposure bracket: the exposure could not be set back: " + error;
    if (log_) log_(drivers::LogLevel::kError, why);
    if (s.ok()) s = Error(drivers::StatusCode::kIoError, why);
  }
  if (!s.ok()) return s;
  const ExposureMergeOptions options;
  if (!MergeExposures(left, exposure, options, &frame->left.image, &error) ||
      !MergeExposures(right, exposure, options, &frame->right.image, &error)) {
    return Error(drivers::StatusCode::kInvalidArgument, "camera: " + error);
  }
  return s;
}

drivers::DriverStatus DeviceManager::MoveTo(double angle_deg) {
  if (!turntable_) return Error(drivers::StatusCode::kWrongState, "turntable: not open");
  const drivers::DriverStatus s = turntable_->MoveTo(angle_deg, setup_.move_timeout);
  if (!s.ok()) {
    Note("turntable", s.ToString());
    return Error(s.code, "turntable: " + s.ToString());
  }
  return s;
}

drivers::DriverStatus DeviceManager::Home() {
  if (!turntable_) return Error(drivers::StatusCode::kWrongState, "turntable: not open");
  const drivers::DriverStatus s = turntable_->Home(setup_.home_timeout);
  if (!s.ok()) {
    Note("turntable", s.ToString());
    return Error(s.code, "turntable: " + s.ToString());
  }
  Note("turntable", "homed");
  return s;
}

bool DeviceManager::MoveTo(double angle_deg, std::string* error) {
  const drivers::DriverStatus s = MoveTo(angle_deg);
  return s.ok() || Fail(error, s.message);
}

bool DeviceManager::Home(std::string* error) {
  const drivers::DriverStatus s = Home();
  return s.ok() || Fail(error, s.message);
}

drivers::DriverStatus DeviceManager::PrepareTurntable() {
  if (!turntable_) return Error(drivers::StatusCode::kWrongState, "turntable: not open");
  const drivers::TurntableStatus status = turntable_->Status();
  if (status.state == drivers::TurntableState::kReady) return drivers::DriverStatus::Ok();
  std::string why = "turntable is " + std::string(drivers::ToString(status.state));
  if (!status.fault_reason.empty()) why += " (" + status.fault_reason + ")";
  if (log_) log_(drivers::LogLevel::kInfo, why + ": homing it before the job");
  Note("turntable", why + "; homing");
  const drivers::DriverStatus home = Home();
  if (!home.ok()) return Error(home.code, why + "; homing failed: " + home.message);
  return home;
}

bool DeviceManager::AbortMove() { return turntable_ && turntable_->Abort().ok(); }

drivers::TurntableStatus DeviceManager::TurntableStatusNow() const {
  std::lock_guard lock(devices_mutex_);
  return turntable_ ? turntable_->Status() : drivers::TurntableStatus{};
}

bool DeviceManager::ApplyCameraSettings(const drivers::CameraSettings& settings,
                                        std::string* error) {
  std::string why;
  if (!settings.IsValid(&why)) return Fail(error, "camera settings: " + why);
  if (!camera_) return Fail(error, "camera: not open");
  const drivers::CameraSettings old = camera_settings();
  if (camera_->state() == drivers::CameraState::kStreaming) camera_->Stop();
  drivers::DriverStatus s = camera_->Configure(settings);
  if (!s.ok()) {
    camera_->Configure(old);
    camera_->Start();
    return Fail(error, "camera: " + s.ToString());
  }
  if (s = camera_->Start(); !s.ok()) return Fail(error, "camera: " + s.ToString());
  std::lock_guard lock(mutex_);
  camera_settings_ = settings;
  return true;
}

}  // namespace craftscan::daemon
