// The sim driver: a stereo camera pair and a turntable sharing one scene.
#include "devices.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <exception>
#include <memory>
#include <mutex>
#include <numbers>
#include <string>
#include <string_view>

#include <opencv2/imgproc.hpp>

#include "craftscan/drivers/reconnect.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "craftscan/sim/technician.h"

namespace craftscan::sim {
namespace {

using drivers::CameraSettings;
using drivers::CameraState;
using drivers::DriverStatus;
using drivers::StatusCode;
using drivers::TurntableState;

constexpr double kRadPerDeg = std::numbers::pi / 180;
// Longest single sleep of a simulated move, so Abort() and the deadline are
// noticed promptly.
constexpr std::int64_t kMoveSliceNs = 5'000'000;

DriverStatus Error(StatusCode code, std::string message) {
  return DriverStatus::Error(code, std::move(message));
}

// The options are valid (SimDriverOptionsFromConfig), so a mesh scene fails
// only for its file: name the driver's key rather than the scene option.
std::string MeshFileError(std::string why) {
  constexpr std::string_view kOption = "object.mesh: ";
  if (why.rfind(kOption, 0) == 0) why.erase(0, kOption.size());
  return "sim driver config key 'mesh': " + why;
}

// What the camera and the turntable of one instance share. `mutex` guards
// the scene: SetTurntableAngle must not run during a render.
struct Shared {
  SimDriverOptions options;
  drivers::HostServices host;
  std::mutex mutex;
  std::unique_ptr<Scene> scene;
};

// ------------------------------------------------------------------ camera --

class SimCamera final : public drivers::StereoCamera {
 public:
  explicit SimCamera(std::shared_ptr<Shared> shared)
      : shared_(std::move(shared)),
        reconnector_(shared_->options.reconnect, shared_->host, "sim/camera") {}

  CameraState state() const noexcept override { return state_.load(); }

  drivers::CameraInfo info() const noexcept override {
    return {"sim stereo pair", shared_->options.image_size};
  }

  DriverStatus Open() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kClosed) return WrongState("Open", "Closed");
    next_frame_id_ = 0;
    frames_this_connection_ = 0;
    state_ = CameraState::kOpen;
    reconnector_.ReportConnected();
    return DriverStatus::Ok();
  }

  DriverStatus Configure(const CameraSettings& settings) noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kOpen && state_ != CameraState::kConfigured) {
      return WrongState("Configure", "Open or Configured (Stop() first)");
    }
    return Apply(settings);
  }

  DriverStatus Start() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kConfigured) return WrongState("Start", "Configured");
    state_ = CameraState::kStreaming;
    return DriverStatus::Ok();
  }

  DriverStatus Capture(std::chrono::milliseconds timeout,
                       drivers::StereoFrame* frame) noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kStreaming) return WrongState("Capture", "Streaming");
    if (!frame) return Error(StatusCode::kInvalidArgument, "Capture: frame is null");
    const SimDriverOptions& o = shared_->options;
    if (o.disconnect_after > 0 && frames_this_connection_ >= o.disconnect_after) {
      state_before_loss_ = state_;
      state_ = CameraState::kLost;
      failures_left_ = o.reconnect_failures;
      const std::string why = "simulated disconnect after " + std::to_string(o.disconnect_after) +
                              " frames (disconnect_after)";
      reconnector_.ReportLost(why);
      return Error(StatusCode::kDeviceLost, "Capture: " + why + "; call Reconnect()");
    }
    if (o.stall_ms > 0) {
      const auto stall = std::chrono::milliseconds(o.stall_ms);
      shared_->host.sleep_ns(std::chrono::nanoseconds(std::min(stall, timeout)).count());
      if (stall > timeout) {
        return Error(StatusCode::kTimeout, "Capture: no frame within " +
                                               std::to_string(timeout.count()) + " ms (stall_ms " +
                                               std::to_string(o.stall_ms) + ")");
      }
    }
    std::uint64_t id = next_frame_id_++;
    if (o.drop_frame_every > 0 && id > 0 &&
        id % static_cast<std::uint64_t>(o.drop_frame_every) == 0) {
      id = next_frame_id_++;
    }
    frame->texture_left.release();
    try {
      StereoRender render;
      std::int64_t stamp = 0;
      if (o.scene == SimSceneType::kHeldBoard ||
          (o.scene == SimSceneType::kPlatterBoard && o.technician)) {
        // The board moved since the last frame: a scene of its own at the
        // shared scene's turntable angle (cheap: ~2 ms to place the board,
        // microseconds to build a board-only scene).
        cv::Vec2d blur_px{0, 0};
        const double seconds = static_cast<double>(id) / o.technician_fps;
        SceneOptions options;
        if (o.scene == SimSceneType::kPlatterBoard) {
          const PlatterTechnicianFrame technician = PlatterTechnicianAt(*station_, seconds);
          options = PlatterBoardScene(o.board, technician.centre_off_axis_mm, technician.yaw_rad);
          options.board.enabled = technician.board_visible;
          options.seed = o.seed;
          blur_px = technician.blur_px;
        } else if (o.technician) {
          const TechnicianFrame technician = TechnicianAt(*station_, o.board, seconds);
          options = HeldBoardScene(*station_, o.board, technician.rig_from_board);
          options.seed = o.seed;
          blur_px = technician.blur_px;
        } else {
          options = SimHeldBoardSceneOptions(o, *station_, id);
        }
        {
          std::lock_guard scene_lock(shared_->mutex);
          options.turntable_angle_rad = shared_->scene->turntable_angle_rad();
          stamp = shared_->host.now_ns();
          // The technician's frames are stamped in their own time, so that a
          // hold of 1.5 s lasts 1.5 s however long a render takes.
          if (o.technician) {
            if (technician_epoch_ns_ == 0) technician_epoch_ns_ = stamp;
            stamp = technician_epoch_ns_ + static_cast<std::int64_t>(seconds * 1e9);
          }
        }
        std::string error;
        const std::unique_ptr<Scene> scene = Scene::Create(options, &error);
        if (!scene) return Error(StatusCode::kFault, "Capture: held board scene: " + error);
        render = station_->Render(*scene, id, RenderOutputs::kImagesOnly);
        if (o.technician && render.IsUsable()) {
          ApplyMotionBlur(blur_px, &render.left);
          ApplyMotionBlur(blur_px, &render.right);
        }
      } else {
        std::lock_guard scene_lock(shared_->mutex);
        stamp = shared_->host.now_ns();
        render = station_->Render(*shared_->scene, id, RenderOutputs::kImagesOnly);
        if (render.IsUsable() && shared_->scene->SetProjectorOn(false)) {
          // The texture frame: the projector off for one more left exposure.
          const StereoRender texture =
              station_->Render(*shared_->scene, id, RenderOutputs::kLeftImageOnly);
          shared_->scene->SetProjectorOn(true);
          if (!texture.IsUsable())
            return Error(StatusCode::kFault, "Capture: texture render failed: " + texture.message);
          frame->texture_left = Convert(texture.left);
        }
      }
      if (!render.IsUsable())
        return Error(StatusCode::kFault, "Capture: render failed: " + render.message);
      frame->settings = settings_;
      frame->left = {Convert(render.left), stamp, id};
      frame->right = {Convert(render.right), stamp, id};
    } catch (const std::exception& e) {
      return Error(StatusCode::kFault, std::string("Capture: ") + e.what());
    }
    ++frames_this_connection_;
    return DriverStatus::Ok();
  }

  DriverStatus Stop() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kStreaming) return WrongState("Stop", "Streaming");
    state_ = CameraState::kConfigured;
    return DriverStatus::Ok();
  }

  DriverStatus Reconnect() noexcept override {
    std::lock_guard lock(mutex_);
    if (state_ != CameraState::kLost) {
      return drivers::CameraWrongState("Reconnect", state_, "Lost");
    }
    try {
      const DriverStatus status = reconnector_.Run([this] { return TryReconnect(); });
      if (!status.ok()) return status;
    } catch (const std::exception& e) {
      return Error(StatusCode::kFault, std::string("Reconnect: ") + e.what());
    }
    state_ = state_before_loss_;
    return DriverStatus::Ok();
  }

  DriverStatus Close() noexcept override {
    std::lock_guard lock(mutex_);
    state_ = CameraState::kClosed;
    station_.reset();
    return DriverStatus::Ok();
  }

 private:
  DriverStatus WrongState(std::string_view call, std::string_view needed) const {
    if (state_ == CameraState::kLost) {
      return Error(StatusCode::kDeviceLost,
                   std::string(call) + ": camera is Lost; call Reconnect() or Close()");
    }
    return drivers::CameraWrongState(call, state_, needed);
  }

  // Validates and applies settings (a new station when the exposure changes).
  DriverStatus Apply(const CameraSettings& settings) {
    std::string why;
    if (!settings.IsValid(&why)) return Error(StatusCode::kInvalidArgument, "Configure: " + why);
    const cv::Rect sensor({0, 0}, shared_->options.image_size);
    if (!settings.roi.empty() && (settings.roi & sensor) != settings.roi) {
      return Error(StatusCode::kInvalidArgument, "Configure: roi lies outside the " +
                                                     std::to_string(sensor.width) + "x" +
                                                     std::to_string(sensor.height) + " sensor");
    }
    if (SimExposure(settings) > 100) {
      return Error(StatusCode::kInvalidArgument,
                   "Configure: exposure_us · 10^(gain_db/20) / 10000 must be <= 100");
    }
    try {
      if (!station_ || SimExposure(settings) != station_->options().exposure) {
        std::string error;
        auto station = SimStation::Create(SimRigOptions(shared_->options, settings), &error);
        if (!station) return Error(StatusCode::kInvalidArgument, "Configure: " + error);
        station_ = std::move(station);
      }
    } catch (const std::exception& e) {
      return Error(StatusCode::kFault, std::string("Configure: ") + e.what());
    }
    settings_ = settings;
    configured_ = true;
    state_ = CameraState::kConfigured;
    return DriverStatus::Ok();
  }

  // One reconnect attempt: the simulated device comes back after
  // reconnect_failures failed attempts; the last settings are re-applied.
  DriverStatus TryReconnect() {
    if (failures_left_ > 0) {
      --failures_left_;
      return Error(StatusCode::kDeviceLost, "sim camera still unplugged (reconnect_failures)");
    }
    frames_this_connection_ = 0;
    if (configured_) {
      const CameraState before = state_before_loss_;
      const DriverStatus status = Apply(settings_);
      state_ = CameraState::kLost;  // until Run reports success
      state_before_loss_ = before;
      if (!status.ok()) return status;
    }
    return DriverStatus::Ok();
  }

  cv::Mat Convert(const cv::Mat& bgr) const {
    cv::Mat image = settings_.roi.empty() ? bgr : bgr(settings_.roi).clone();
    if (settings_.pixel_format == drivers::PixelFormat::kMono8) {
      cv::Mat mono;
      cv::cvtColor(image, mono, cv::COLOR_BGR2GRAY);
      return mono;
    }
    return image;
  }

  const std::shared_ptr<Shared> shared_;
  const drivers::Reconnector reconnector_;
  std::mutex mutex_;  // serialises the calls; guards everything below
  std::atomic<CameraState> state_{CameraState::kClosed};
  CameraState state_before_loss_ = CameraState::kClosed;
  CameraSettings settings_;
  bool configured_ = false;
  std::unique_ptr<SimStation> station_;
  std::uint64_t next_frame_id_ = 0;
  std::int64_t technician_epoch_ns_ = 0;  // host time of the technician's first frame
  int frames_this_connection_ = 0;
  int failures_left_ = 0;
};

// --------------------------------------------------------------- turntable --

class SimTurntable final : public drivers::Turntable {
 public:
  explicit SimTurntable(std::shared_ptr<Shared> shared)
      : shared_(std::move(shared)),
        reconnector_(shared_->options.reconnect, shared_->host, "sim/turntable") {}

  drivers::TurntableStatus Status() const noexcept override {
    std::lock_guard lock(mutex_);
    return status_;
  }

  DriverStatus Open() noexcept override {
    std::lock_guard lock(mutex_);
    if (status_.state != TurntableState::kClosed) return WrongState("Open", "Closed");
    status_ = {TurntableState::kUnhomed, AngleDeg(), false, {}};
    reconnector_.ReportConnected();
    return DriverStatus::Ok();
  }

  DriverStatus Home(std::chrono::milliseconds /*timeout*/) noexcept override {
    std::lock_guard lock(mutex_);
    const TurntableState s = status_.state;
    if (s != TurntableState::kUnhomed && s != TurntableState::kReady &&
        s != TurntableState::kFault) {
      return WrongState("Home", "Unhomed, Ready or Fault");
    }
    SetSceneAngle(0);  // the sim homes instantly to its index mark at 0°
    status_ = {TurntableState::kReady, 0, true, {}};
    return DriverStatus::Ok();
  }

  DriverStatus MoveTo(double angle_deg, std::chrono::milliseconds timeout) noexcept override {
    double from_deg = 0;
    {
      std::lock_guard lock(mutex_);
      if (status_.state != TurntableState::kReady) {
        return WrongState("MoveTo", status_.homed ? "Ready" : "Ready (Home() first)");
      }
      if (!std::isfinite(angle_deg)) {
        return Error(StatusCode::kInvalidArgument, "MoveTo: angle_deg must be finite");
      }
      if (shared_->options.turntable_alarm) {
        return FaultLocked(StatusCode::kFault,
                           "ALARM: simulated turntable alarm (turntable_alarm)");
      }
      from_deg = status_.angle_deg;
      status_.state = TurntableState::kMoving;
      abort_requested_ = false;
    }
    const drivers::HostServices& host = shared_->host;
    const SimDriverOptions& o = shared_->options;
    const std::int64_t start_ns = host.now_ns();
    const std::int64_t deadline_ns =
        start_ns + std::chrono::duration_cast<std::chrono::nanoseconds>(timeout).count();
    const double span_deg = angle_deg - from_deg;
    const std::int64_t duration_ns =
        o.turntable_speed_deg_s > 0
            ? static_cast<std::int64_t>(std::abs(span_deg) / o.turntable_speed_deg_s * 1e9)
            : 0;
    for (;;) {
      const std::int64_t now_ns = host.now_ns();
      const std::int64_t elapsed_ns = now_ns - start_ns;
      const double fraction =
          o.turntable_stall ? 0.0
                            : (duration_ns > 0 ? std::min(1.0, static_cast<double>(elapsed_ns) /
                                                                   static_cast<double>(duration_ns))
                                               : 1.0);
      const double current_deg = from_deg + fraction * span_deg;
      std::unique_lock lock(mutex_);
      SetSceneAngle(current_deg);
      status_.angle_deg = current_deg;
      if (abort_requested_) {
        status_.state = TurntableState::kReady;
        moved_.notify_all();
        return Error(StatusCode::kAborted,
                     "MoveTo: aborted at " + std::to_string(current_deg) + "°");
      }
      if (fraction >= 1.0) {
        status_.angle_deg = angle_deg;
        status_.state = TurntableState::kReady;
        moved_.notify_all();
        return DriverStatus::Ok();
      }
      if (now_ns >= deadline_ns) {
        const DriverStatus status = FaultLocked(
            StatusCode::kTimeout, "move to " + std::to_string(angle_deg) + "° not done within " +
                                      std::to_string(timeout.count()) + " ms; stopped at " +
                                      std::to_string(current_deg) + "°" +
                                      (o.turntable_stall ? " (turntable_stall)" : ""));
        moved_.notify_all();
        return status;
      }
      // Sleep without the lock so Status() and Abort() stay responsive.
      const std::int64_t wait_ns =
          std::min({kMoveSliceNs, deadline_ns - now_ns,
                    o.turntable_stall ? kMoveSliceNs : duration_ns - elapsed_ns});
      lock.unlock();
      host.sleep_ns(std::max<std::int64_t>(wait_ns, 1));
    }
  }

  DriverStatus Abort() noexcept override {
    std::lock_guard lock(mutex_);
    if (status_.state == TurntableState::kClosed) return WrongState("Abort", "not Closed");
    if (status_.state == TurntableState::kMoving) abort_requested_ = true;
    return DriverStatus::Ok();
  }

  DriverStatus Close() noexcept override {
    std::unique_lock lock(mutex_);
    if (status_.state == TurntableState::kMoving) {
      abort_requested_ = true;
      moved_.wait(lock, [this] { return status_.state != TurntableState::kMoving; });
    }
    status_ = {TurntableState::kClosed, status_.angle_deg, false, {}};
    return DriverStatus::Ok();
  }

 private:
  DriverStatus WrongState(std::string_view call, std::string_view needed) const {
    return drivers::TurntableWrongState(call, status_.state, needed);
  }

  DriverStatus FaultLocked(StatusCode code, const std::string& reason) {
    status_.state = TurntableState::kFault;
    status_.fault_reason = reason;
    shared_->host.log(drivers::LogLevel::kError, "sim/turntable: " + reason);
    return Error(code, "MoveTo: " + reason);
  }

  double AngleDeg() const {
    std::lock_guard scene_lock(shared_->mutex);
    return shared_->scene->turntable_angle_rad() / kRadPerDeg;
  }

  void SetSceneAngle(double angle_deg) {
    std::lock_guard scene_lock(shared_->mutex);
    shared_->scene->SetTurntableAngle(angle_deg * kRadPerDeg);
  }

  const std::shared_ptr<Shared> shared_;
  const drivers::Reconnector reconnector_;
  mutable std::mutex mutex_;       // guards status_ and abort_requested_
  std::condition_variable moved_;  // a move ended
  drivers::TurntableStatus status_;
  bool abort_requested_ = false;
};

// ---------------------------------------------------------------- instance --

class SimInstance final : public drivers::DriverInstance {
 public:
  explicit SimInstance(std::shared_ptr<Shared> shared) : shared_(std::move(shared)) {}

  std::unique_ptr<drivers::StereoCamera> CreateCamera(DriverStatus* status) noexcept override {
    return Make<SimCamera>(status);
  }
  std::unique_ptr<drivers::Turntable> CreateTurntable(DriverStatus* status) noexcept override {
    return Make<SimTurntable>(status);
  }

 private:
  template <typename Device>
  std::unique_ptr<Device> Make(DriverStatus* status) noexcept {
    try {
      auto device = std::make_unique<Device>(shared_);
      if (status) *status = DriverStatus::Ok();
      return device;
    } catch (const std::exception& e) {
      if (status) *status = Error(StatusCode::kFault, e.what());
      return nullptr;
    }
  }

  std::shared_ptr<Shared> shared_;
};

}  // namespace

drivers::DriverInstance* CreateSimInstance(const drivers::DriverConfig& config,
                                           const drivers::HostServices& host,
                                           DriverStatus* status) noexcept {
  try {
    auto shared = std::make_shared<Shared>();
    std::string why;
    if (!SimDriverOptionsFromConfig(config, &shared->options, &why)) {
      *status = Error(StatusCode::kInvalidArgument, why);
      return nullptr;
    }
    shared->host = host.WithDefaults();
    const SceneOptions scene = SimSceneOptions(shared->options);
    shared->scene = Scene::Create(scene, &why);
    if (!shared->scene) {
      *status =
          Error(StatusCode::kInvalidArgument,
                scene.object.type == ObjectType::kMesh ? MeshFileError(why) : "scene: " + why);
      return nullptr;
    }
    *status = DriverStatus::Ok();
    return new SimInstance(std::move(shared));
  } catch (const std::exception& e) {
    *status = Error(StatusCode::kFault, e.what());
    return nullptr;
  }
}

}  // namespace craftscan::sim
