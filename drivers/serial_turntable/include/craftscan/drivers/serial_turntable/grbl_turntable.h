// A turntable driven by a GRBL 1.1 controller over a serial port; the
// turntable axis is GRBL's X axis, in degrees (GRBL's "mm" = 1°).
//
//   GrblTurntableOptions options;
//   options.port_path = "/dev/ttyUSB0";
//   GrblTurntable table(options);
//   Status s = table.Connect();   // Closed -> Unhomed
//   s = table.Home();             // Unhomed -> Ready ($H, or G92 X0 without a switch)
//   s = table.MoveTo(60.0);       // Ready -> Moving -> Ready, returns once settled
//
// State machine (checked at every call; a call in the wrong state returns
// kWrongState and changes nothing):
//
//                Connect()              Home()                  MoveTo()
//     Closed ─────────────> Unhomed ─────────────> Ready ─────────────────> Moving
//       ^                     ^  ^                 ^  ^                       │
//       │ Close()             │  │ Abort()         │  └── Idle at target, ────┤
//       │ (any state)         │  └──────(reset)────┼───── settled             │
//       │                     │                    │ Home()                   │ error:N,
//       │          Reconnect()│                  Fault <──────────────────────┘ ALARM:N,
//       │                     │                    ^                            timeout,
//    DeviceLost <─────────────┴── I/O error, hang-up or N timeouts in a row     position
//    (from any open state)                                                      mismatch
//
//   Closed      port closed. Connect().
//   Unhomed     connected, banner seen, version 1.1; angle unknown. Home().
//   Ready       angle known (the shadow angle_deg()). MoveTo(), Home().
//   Moving      inside MoveTo() (visible to other threads). Abort(): with
//               AbortMode::kReset -> Unhomed at once; with kFeedHold the
//               move is stopped keeping the position -> Ready (Unhomed if
//               the hold fails).
//   Fault       the last command failed (message in last_error()); the angle
//               is unknown. Home() (soft-resets first), Reconnect(), Close().
//   DeviceLost  the port failed (EIO/ENXIO/hang-up) or `timeouts_until_lost`
//               commands timed out in a row. Reconnect() (-> Unhomed), Close().
//
// Errors: every call returns a Status; messages name the port and say what
// was sent and what came back ("error:9 (G-code locked out during alarm or
// jog state) in reply to 'G90 G1 X60.000 F3600.0' on /dev/pts/3").
//
// Thread-safety: one thread drives the turntable (Connect, Home, MoveTo,
// Reconnect, Close; these are serialized by an internal mutex). Abort(),
// state() and angle_deg() may be called from any thread at any time.
#pragma once

#include <atomic>
#include <chrono>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "craftscan/drivers/serial_turntable/grbl_reply_parser.h"
#include "craftscan/drivers/serial_turntable/serial_port.h"
#include "craftscan/drivers/serial_turntable/status.h"

namespace craftscan::serial_turntable {

struct GrblTurntableOptions {
  std::string port_path;  // device or PTY path (a symlink is fine; resolved at each open)
  int baud = 115200;      // GRBL 1.1 default
  // true: Home() runs GRBL's homing cycle ($H). false (no limit switch):
  // Home() unlocks ($X) and declares the current position zero (G92 X0).
  bool homing_enabled = true;
  double feed_deg_per_min = 3600;                   // G1 feed rate (deg/min), > 0
  double position_tolerance_deg = 0.05;             // |reported − commanded| allowed after a move
  std::chrono::milliseconds banner_timeout{2000};   // per attempt at Connect()/reset
  std::chrono::milliseconds command_timeout{1000};  // from sending a line to its ok/error
  std::chrono::milliseconds homing_timeout{30000};  // $H until its ok
  // A move may take its nominal time (distance / feed) times this factor plus
  // `move_timeout_margin` before it is declared timed out.
  double move_timeout_factor = 1.5;
  std::chrono::milliseconds move_timeout_margin{1000};
  std::chrono::milliseconds status_poll_interval{20};  // between '?' during a move
  std::chrono::milliseconds settle_time{0};            // wait after the move ends (vibration)
  int timeouts_until_lost = 3;  // consecutive timeouts that mean the device is gone, >= 1
  // How Abort() stops a move. kReset: soft reset (0x18) at once; GRBL
  // halts and loses the position (ALARM:3), so the table is Unhomed.
  // kFeedHold: feed hold ('!'), wait for Hold:0, then the soft reset that
  // flushes the rest of the move (GRBL keeps the position after a completed
  // hold), then "G92 X<angle>" to restore the work offset: Ready where the
  // platter stopped.
  enum class AbortMode { kReset, kFeedHold };
  AbortMode abort_mode = AbortMode::kReset;
  std::chrono::milliseconds hold_timeout{2000};  // feed hold: '!' until Hold:0

  bool IsValid(std::string* why) const;
};

class GrblTurntable {
 public:
  enum class State { kClosed, kUnhomed, kReady, kMoving, kFault, kDeviceLost };

  explicit GrblTurntable(GrblTurntableOptions options);
  ~GrblTurntable();  // closes the port
  GrblTurntable(const GrblTurntable&) = delete;
  GrblTurntable& operator=(const GrblTurntable&) = delete;

  // Closed -> Unhomed. Opens the port, waits up to banner_timeout for the
  // "Grbl 1.1x" banner; without one sends a soft reset (0x18) and waits once
  // more. kTimeout without a banner, kProtocolError for a version other than
  // 1.1 (the port is closed again on failure).
  Status Connect();

  // Unhomed/Ready/Fault -> Ready. From Fault, soft-resets first. Homing:
  // "$H" (homing_timeout); without a switch: "$X" then "G92 X0". Then checks
  // the controller reports Idle and records the reported origin. The shadow
  // angle becomes 0. `timeout` > 0 also bounds the homing command and the
  // final status query (the shorter limit wins); when it expires the homing
  // cycle is stopped (soft reset): kTimeout, Fault, and it does not count
  // towards timeouts_until_lost (the controller may just be slow).
  Status Home(std::chrono::milliseconds timeout = std::chrono::milliseconds(0));

  // Ready -> Moving -> Ready. Sends "G90 G1 X<angle_deg> F<feed>", waits for
  // ok, polls '?' until Idle, checks the reported position against the
  // commanded one within position_tolerance_deg, then waits settle_time.
  // `angle_deg` is absolute (work coordinates, 0 = home), any finite value.
  // Failures -> Fault (kDeviceError, kAlarm, kTimeout, kPositionMismatch) or
  // DeviceLost; Abort() -> kAborted and Unhomed (kReset) or Ready at the
  // angle where it stopped (kFeedHold). `timeout` > 0 bounds the move
  // together with the configured limit (the shorter wins). A move that does
  // not finish in time is stopped (soft reset): kTimeout, Fault.
  Status MoveTo(double angle_deg, std::chrono::milliseconds timeout = std::chrono::milliseconds(0));

  // Stops now. AbortMode::kReset, or outside a move: sends GRBL's soft reset
  // (0x18), which halts motion; GRBL then needs homing (ALARM:3 if it was
  // moving); any open state -> Unhomed. kFeedHold during a move: sends the
  // feed hold ('!') and returns; the MoveTo() in progress completes the stop
  // (see AbortMode) and returns kAborted. Closed/DeviceLost: kWrongState.
  // Callable from any thread.
  Status Abort();

  // Any state but Closed -> Unhomed: closes and reopens the port, then as
  // Connect(). `path` replaces options.port_path when not empty (a restarted
  // emulator or re-enumerated adapter may have a new path). Homing is required
  // again afterwards. On failure the state is DeviceLost.
  Status Reconnect(const std::string& path = "");

  // Any state -> Closed.
  void Close();

  State state() const { return state_.load(); }
  // Host-side shadow of the turntable angle in work coordinates (deg): the
  // last commanded angle that the controller confirmed. NaN unless Ready.
  double angle_deg() const;
  const Status& last_error() const { return last_error_; }          // driving thread only
  const std::string& firmware_version() const { return version_; }  // "1.1h"
  // Lines received that were not understood (garbage, noise), since Connect().
  int unknown_lines() const { return unknown_lines_; }
  const GrblTurntableOptions& options() const { return options_; }

 private:
  enum class Step { kContinue, kDone };
  using Clock = std::chrono::steady_clock;

  Status OpenAndGreet();
  Status WaitForBanner(std::chrono::milliseconds timeout);
  Status Write(std::string_view bytes);
  Status Command(const std::string& line, std::chrono::milliseconds timeout);
  Status QueryStatus(std::chrono::milliseconds timeout, GrblStatusReport* report);
  Status ReadReplies(Clock::time_point deadline, std::vector<GrblReply>* replies);
  Status BeginCall();  // clears a stale abort, consumes a pending reset, drains input
  // Records; moves to Fault, DeviceLost or (aborted) Unhomed. A kTimeout
  // counts towards timeouts_until_lost unless `silence` is false.
  Status Fail(Status status, bool silence = true);
  // Halts motion with a soft reset whose answer ReadReplies() will consume.
  void StopWithReset();
  // Feed hold requested by Abort(): waits for the stop, flushes the move,
  // restores the work offset; *stopped_deg = the angle where it stopped.
  Status CompleteHold(const std::string& target, double* stopped_deg);
  bool SetStateUnlessAborted(State state);
  Status WrongState(std::string_view call) const;
  std::string UnknownSummary() const;

  GrblTurntableOptions options_;
  std::mutex command_mutex_;  // one driving call at a time
  std::mutex write_mutex_;    // port writes and open/close vs Abort()
  SerialPort port_;
  GrblReplyParser parser_;
  std::atomic<State> state_{State::kClosed};
  std::atomic<bool> abort_requested_{false};
  std::atomic<bool> hold_requested_{false};  // Abort() sent '!' (kFeedHold)
  std::atomic<bool> reset_pending_{false};   // Abort() sent 0x18; banner not consumed yet
  std::atomic<double> angle_deg_;
  double origin_x_ = 0;  // reported machine X at angle 0
  Status last_error_;
  std::string version_;
  int unknown_lines_ = 0;
  int consecutive_timeouts_ = 0;
  std::string last_unknown_;
};

std::string_view ToString(GrblTurntable::State state);

}  // namespace craftscan::serial_turntable
