// A GRBL 1.1 turntable on a pseudo-terminal, for testing the serial turntable
// driver without hardware. Runs on its own thread; the standalone program
// (main.cc) wraps it.
//
//   EmulatorOptions options;
//   options.homing_time = std::chrono::milliseconds(100);
//   std::string error;
//   auto emu = TurntableEmulator::Start(options, &error);
//   // open emu->slave_path() (e.g. /dev/pts/7) with the driver
//   emu->RaiseAlarm(1);  // faults on demand
//
// Speaks: banner "Grbl 1.1h ['$' for help]" on start and after a soft reset
// (0x18); real-time '?' (status report <Idle|MPos:x,0.000,0.000|FS:f,0>, with
// the interpolated position and Idle/Run/Hold:1/Hold:0/Home/Alarm), '!' (feed
// hold: a move decelerates at hold_decel_deg_s2 to a stop, Hold:1 while
// slowing, Hold:0 once stopped), '~' (cycle start: a held move resumes), 0x18
// (reset: halts motion, ALARM:3 if it was moving or still slowing down in a
// hold; after Hold:0 the position is kept and no alarm is raised, as GRBL);
// lines "$H" (homing takes homing_time;
// MPos becomes 0), "$X" (unlock), "$$"/"$I"/"$G"/"$#" (ok), "G90", "G91",
// "G92 X<v>", "G0/G1 X<v> F<deg/min>", combinations on one line (moves queue).
// Motion is at constant speed: time = distance / feed. Malformed lines get
// error:N with GRBL's codes (1, 2, 3, 4, 5, 8, 9, 11, 20, 21, 22, 25, 26); G-code in the Alarm
// state gets error:9. The X axis is the turntable angle in degrees.
#pragma once

#include <chrono>
#include <memory>
#include <string>

namespace craftscan::testing {

struct EmulatorOptions {
  std::chrono::milliseconds homing_time{100};  // duration of "$H"
  bool homing_enabled = true;        // false: "$H" -> error:5 (a turntable without switch)
  bool banner_on_start = true;       // false: the banner only comes after a soft reset
  bool start_in_alarm = false;       // like GRBL with homing enabled at power-up: "$H"/"$X" needed
  double start_position_deg = 0;     // MPos at start (deg)
  double rapid_deg_per_min = 36000;  // G0 speed (deg/min)
  double hold_decel_deg_s2 = 3600;   // deceleration of a feed hold (deg/s²), > 0
  std::string version = "1.1h";      // banner version, e.g. "0.9j" to test the check
  // If not empty: a symlink made to point at the PTY slave (replaced
  // atomically), so a client can reopen the same path after a restart.
  std::string link_path;
};

class TurntableEmulator {
 public:
  // Opens a PTY (openpty, raw mode) and starts serving it. nullptr and
  // *error on failure.
  static std::unique_ptr<TurntableEmulator> Start(const EmulatorOptions& options,
                                                  std::string* error);
  ~TurntableEmulator();  // Stop()
  TurntableEmulator(const TurntableEmulator&) = delete;
  TurntableEmulator& operator=(const TurntableEmulator&) = delete;

  const std::string& slave_path() const;
  // Stops the thread and closes the PTY (a connected client sees a hang-up).
  void Stop();

  // ---- faults (any thread) ----
  void InjectGarbage(const std::string& bytes);  // written as is, now (even when silent)
  void SetSilent(bool silent);                   // stop answering (input is read and ignored)
  void RaiseAlarm(int code);                     // halts motion, Alarm state, sends "ALARM:<code>"
  void SetPositionOffset(double offset_deg);     // added to every reported position
  void HangUp();  // closes the PTY master now: the client gets EIO/POLLHUP

  // ---- introspection (any thread) ----
  double machine_position_deg();  // current, interpolated
  std::string state();            // "Idle", "Run", "Hold", "Home", "Alarm"
  int lines_received();
  int resets_received();
  bool hung_up();

 private:
  struct Impl;
  explicit TurntableEmulator(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace craftscan::testing
