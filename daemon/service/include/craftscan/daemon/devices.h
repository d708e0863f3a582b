// DeviceManager: the station's hardware as the daemon sees it. Loads the
// configured driver plugins (the sim station when none is configured), opens
// the stereo camera and the turntable, follows their connect / loss /
// recovery events for StationStatus, and wraps captures and moves with the
// recovery the jobs need (reconnect on loss, bounded retries on timeouts).
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/host.h"
#include "craftscan/drivers/plugin_loader.h"
#include "craftscan/drivers/turntable.h"
#include "craftscan/pipeline/calib/calibration.h"

namespace craftscan::daemon {

struct DeviceSpec {
  std::string driver = "sim";  // plugin name: craftscan-driver-<driver>.so
  drivers::DriverConfig config;
};

struct DeviceSetup {
  std::string plugin_path;       // directories separated by ':'
  DeviceSpec camera, turntable;  // same driver + same config → one shared instance
  drivers::CameraSettings camera_settings;
  std::chrono::milliseconds capture_timeout{5000};
  std::chrono::milliseconds home_timeout{60000};
  std::chrono::milliseconds move_timeout{60000};
  int capture_retries = 3;  // consecutive timeouts/dropped captures before giving up
};

// One device's line in StationStatus.
struct DeviceReport {
  std::string name;  // "camera", "turntable"
  std::string kind;  // "stereo_camera", "turntable"
  std::string driver;
  std::string state;    // the driver state ("Streaming", "Ready", "Lost", ...) or "absent"
  std::string message;  // last event or error
};

// What the cameras are shown for a calibration job.
enum class CalibrationTarget {
  kHeldBoard,     // a board held in front of the cameras (stereo calibration)
  kPlatterBoard,  // a board lying on the platter, turning with it (turntable axis)
};

// Thread-safety: Open/Close/ShowCalibrationTarget/ShowObject/ApplyCameraSettings from one thread
// (the job thread or the service's start-up); Reports() from any thread;
// Capture/MoveTo/Home/PrepareTurntable from the job thread only. Reports()
// never waits for a device call in progress (a reconnect may take seconds)
// as long as the drivers' state()/Status() do not.
class DeviceManager {
 public:
  // `log` and `on_change` may be empty; on_change is called (from any thread)
  // whenever a device event arrives so the service can republish its status.
  DeviceManager(DeviceSetup setup, std::function<void(drivers::LogLevel, std::string_view)> log,
                std::function<void()> on_change);
  ~DeviceManager();

  // Loads the plugins, creates and opens both devices, configures and starts
  // the camera and homes the turntable. False with *error naming the device.
  bool Open(std::string* error);
  void Close();
  bool IsOpen() const { return open_.load(); }

  std::vector<DeviceReport> Reports() const;
  bool IsSim() const;  // the camera's driver is "sim"
  drivers::CameraSettings camera_settings() const;

  // Before a calibration job: has `target` showing `board` put in front of
  // the cameras. On the simulated station the sim driver is reopened with
  // that scene (the mapping lives here, in devices.cc); on a real station the
  // operator presents the board and this returns ok without changing
  // anything. An error names the device.
  drivers::DriverStatus ShowCalibrationTarget(CalibrationTarget target, const BoardSpec& board);
  // After a calibration job (also after a failed one): back to the object on
  // the turntable.
  drivers::DriverStatus ShowObject();
  // Before capturing turn `turn` (≥ 1) of a scan: the object as the
  // operator laid it for that turn. On the simulated station the sim driver
  // is reopened with its `turn` key set (its turn_rotations_deg say the
  // pose; nothing happens when it already shows that turn); on a real
  // station the operator has moved the object and this returns ok. An
  // error names the device; the devices are then back at turn 1.
  drivers::DriverStatus ShowTurn(int turn);

  // One stereo pair. Loss → Reconnect() (the driver's back-off) and retry;
  // timeouts and transport errors (kIoError: e.g. a GigE frame with missing
  // packets, common just after a reconnect) → up to capture_retries tries.
  // `cancel` is polled between tries: set, the capture ends with kAborted.
  // Other errors keep the driver's code (kDeviceLost once reconnecting gave
  // up); the message names the camera and the cause.
  drivers::DriverStatus Capture(drivers::StereoFrame* frame, const std::atomic<bool>& cancel);
  // Exposure bracketing: Capture at the current settings, then once more per
  // multiple of their exposure time in `bracket` (ascending, > 1; each by
  // ApplyCameraSettings, so a real camera stops and restarts streaming), the
  // settings restored afterwards in any case; the pairs merged by
  // MergeExposures into frame->left/right (the reference exposure's
  // timestamps, frame ids, settings and texture). An empty bracket is
  // Capture. Errors as Capture's, or kInvalidArgument for a merge or a
  // setting the camera refuses (the message names the exposure).
  drivers::DriverStatus CaptureBracketed(const std::vector<double>& bracket,
                                         drivers::StereoFrame* frame,
                                         const std::atomic<bool>& cancel);
  // The second half of CaptureBracketed: `frame` was captured at the current
  // settings; the bracket's exposures are captured and merged into it.
  // (Automatic bracketing looks at the first capture before it asks.)
  drivers::DriverStatus AddExposures(const std::vector<double>& bracket,
                                     drivers::StereoFrame* frame, const std::atomic<bool>& cancel);
  // A move stopped by AbortMove() ends with kAborted; a fault (alarm) with
  // kFault, a move that does not arrive with kTimeout. Messages start
  // "turntable: ".
  drivers::DriverStatus MoveTo(double angle_deg);
  drivers::DriverStatus Home();
  // The same for callers that only show the message (the command handler).
  bool MoveTo(double angle_deg, std::string* error);
  bool Home(std::string* error);
  // Before a job turns the table: homes it unless it is Ready, i.e. after a
  // fault an earlier job left (alarm, timeout, position mismatch, a lost
  // link: drivers reconnect in Home) or an abort. The operator asked for the
  // new job; a fault in the middle of a job still ends that job. An error
  // names the turntable and why it is not ready.
  drivers::DriverStatus PrepareTurntable();
  bool AbortMove();
  drivers::TurntableStatus TurntableStatusNow() const;
  // Stop, Configure with the new settings, Start; on failure the old ones are restored.
  bool ApplyCameraSettings(const drivers::CameraSettings& settings, std::string* error);

 private:
  bool OpenLocked(const DeviceSpec& camera, const DeviceSpec& turntable, std::string* error);
  void Note(const std::string& device, const std::string& message);
  // Reopens the sim driver with its `scene` key set ("object", "held_board",
  // "platter_board") showing `board` (null for "object"); true without a
  // change on a real station.
  drivers::DriverStatus SwitchScene(const std::string& scene, const BoardSpec* board);
  // Reopens the sim driver with `camera_config` (the turntable too when it
  // shares the camera's instance); on failure back to the configured devices.
  drivers::DriverStatus ReopenSim(const drivers::DriverConfig& camera_config);

  DeviceSetup setup_;
  std::function<void(drivers::LogLevel, std::string_view)> log_;
  std::function<void()> on_change_;
  drivers::PluginLoader loader_;
  std::unique_ptr<drivers::DriverInstance> camera_instance_, turntable_instance_;
  std::unique_ptr<drivers::StereoCamera> camera_;
  std::unique_ptr<drivers::Turntable> turntable_;
  std::atomic<bool> open_{false};
  std::string scene_ = "object";
  int turn_ = 1;  // the sim's `turn` (ShowTurn)
  // Two locks, so a driver's event callback (Note, from inside a device
  // call) never waits behind Reports() asking the same driver for its state.
  mutable std::mutex devices_mutex_;  // guards the device pointers' swap against Reports()
  mutable std::mutex mutex_;          // guards the messages and camera_settings_
  std::string camera_message_, turntable_message_;
  drivers::CameraSettings camera_settings_;
};

}  // namespace craftscan::daemon
