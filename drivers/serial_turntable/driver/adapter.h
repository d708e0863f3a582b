// The serial turntable behind the driver API (implementation header of the
// craftscan-driver-serial_turntable.so plugin): a craftscan::drivers::Turntable
// wrapping craftscan::serial_turntable::GrblTurntable.
//
// Config keys (DriverConfig; unknown keys are refused, naming the key):
//   port                    required: device or PTY path (/dev/ttyUSB0)
//   baud                    115200
//   feed_deg_min            3600    G1 feed rate (deg/min), > 0
//   homing                  true    true: $H homing cycle; false: $X + G92 X0
//   settle_ms               0       wait after each move (vibration)
//   position_tolerance_deg  0.05    |reported - commanded| allowed after a move
//   banner_timeout_ms       2000    per attempt at Open()/reset
//   command_timeout_ms      1000    from a sent line to its ok/error
//   homing_timeout_ms       30000   $H until its ok
//   move_timeout_margin_ms  1000    a move may take distance/feed * factor + margin
//   move_timeout_factor     1.5
//   status_poll_ms          20      between '?' status queries during a move
//   timeouts_until_lost     3       consecutive timeouts that mean the device is gone
//   abort                   feed_hold  how Abort() stops a move: feed_hold keeps the
//                                      position (Ready), reset loses it (Unhomed)
//   hold_timeout_ms         2000    feed hold: '!' until the controller reports Hold:0
//
// Mapping onto the API (turntable.h):
// - States: GrblTurntable's DeviceLost is reported as Fault (fault_reason
//   says "device lost: ..."); Home() from there reconnects first.
// - Codes: DeviceError/Alarm/PositionMismatch -> kFault, ProtocolError ->
//   kIoError (the message keeps the original code name); the others 1:1.
// - Abort() outside a move does nothing (GRBL's soft reset would lose the
//   position). During a move, abort=feed_hold: GRBL's feed hold ('!')
//   decelerates the platter; once the controller reports Hold:0 a soft reset
//   flushes the rest of the move (GRBL keeps the position after a completed
//   hold) and "G92 X<angle>" restores the work offset: MoveTo returns
//   kAborted, the state is Ready at the reported angle. If the hold fails
//   (no Hold:0 within hold_timeout_ms, an alarm) or with abort=reset, a soft
//   reset halts it at once: Unhomed (the position is lost).
// - Per-call timeouts (> 0, else kInvalidArgument): Home(timeout) and
//   MoveTo(angle, timeout) are bounded by the shorter of the call's timeout
//   and the configured ones. A move or homing cut short by it is stopped
//   (soft reset): kTimeout, state Fault (fault_reason says why); it does not
//   count towards timeouts_until_lost. The waits run on the real clock
//   (serial I/O), not HostServices.
#pragma once

#include <string>

#include "craftscan/drivers/plugin.h"
#include "craftscan/drivers/serial_turntable/grbl_turntable.h"

namespace craftscan::serial_turntable {

// Parses the config keys above. False and *why (naming the key) on a missing
// `port`, an unknown key or a bad value.
bool SerialTurntableOptionsFromConfig(const drivers::DriverConfig& config,
                                      GrblTurntableOptions* options, std::string* why);

// Maps a serial turntable status onto the driver API's.
drivers::DriverStatus ToDriverStatus(const Status& status);

// Factory of the plugin: null and *status (kInvalidArgument) on a bad config.
drivers::DriverInstance* CreateSerialTurntableInstance(const drivers::DriverConfig& config,
                                                       const drivers::HostServices& host,
                                                       drivers::DriverStatus* status) noexcept;

}  // namespace craftscan::serial_turntable
