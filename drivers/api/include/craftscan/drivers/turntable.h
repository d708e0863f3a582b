// Turntable: a motorised platter turned to absolute angles.
//
// State machine (checked at every call; a call in another state returns
// kWrongState and changes nothing):
//
//            Open()             Home()               MoveTo()
//   Closed ─────────► Unhomed ─────────► Ready ────────────────► Moving
//     ▲                  │                ▲  ▲ ◄──────────────── │
//     │ Close()          │ homing         │  │  done, or Abort() │ alarm, stall,
//     │ from any         │ fails          │  │                   │ timeout, I/O error
//     │ state            ▼                │  └─ Home() (re-home) │
//     │                Fault ─────────────┘                      │
//     │                  ▲      Home()                           │
//     │                  └───────────────────────────────────────┘
//
// - Open: Closed → Unhomed. Reports DeviceEvent::kConnected.
// - Home(timeout): Unhomed|Ready|Fault → (homing) → Ready; clears a fault.
//   Blocks until homed. Failure: kTimeout/kFault/kDeviceLost, state Fault.
// - MoveTo(angle_deg, timeout): Ready only (before homing: kWrongState).
//   Blocks while Moving until the platter is at angle_deg (absolute, degrees,
//   finite; otherwise kInvalidArgument), then Ready. A move that does not
//   finish within `timeout` is stopped: kTimeout, state Fault. An alarm from
//   the device: kFault, state Fault, reason in Status().fault_reason.
// - Abort(): any state but Closed. Stops a move in progress from another
//   thread: that MoveTo returns kAborted and the state is Ready at the angle
//   where it stopped (Unhomed if the driver lost its position). Outside a
//   move it does nothing and returns kOk. Closed: kWrongState.
// - Status(): any state, any thread, never blocks on a move.
// - Close: any state → Closed (stops a move first).
//
// Thread safety: Status() and Abort() may be called from any thread at any
// time, including while MoveTo() or Home() blocks in another; other calls are
// serialised by the driver. No method throws.
#pragma once

#include <chrono>
#include <string>
#include <string_view>

#include "craftscan/drivers/status.h"

namespace craftscan::drivers {

enum class TurntableState { kClosed, kUnhomed, kReady, kMoving, kFault };
std::string_view ToString(TurntableState state);  // "Closed", "Unhomed", ...

struct TurntableStatus {
  TurntableState state = TurntableState::kClosed;
  double angle_deg = 0;  // current platter angle (degrees); meaningful once homed
  bool homed = false;
  std::string fault_reason;  // why the state is Fault; empty otherwise
};

class Turntable {
 public:
  virtual ~Turntable() = default;

  virtual TurntableStatus Status() const noexcept = 0;

  virtual DriverStatus Open() noexcept = 0;
  virtual DriverStatus Home(std::chrono::milliseconds timeout) noexcept = 0;
  virtual DriverStatus MoveTo(double angle_deg, std::chrono::milliseconds timeout) noexcept = 0;
  virtual DriverStatus Abort() noexcept = 0;
  virtual DriverStatus Close() noexcept = 0;
};

// The standard wrong-state error: "<call>: turntable is <state>, needs <needed>".
DriverStatus TurntableWrongState(std::string_view call, TurntableState state,
                                 std::string_view needed);

}  // namespace craftscan::drivers
