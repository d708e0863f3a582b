// The GRBL serial turntable driver against the PTY turntable emulator: real
// termios I/O, real timing. Every wait is bounded by the driver's configured
// timeouts; each test takes well under 2 s.
#include "craftscan/drivers/serial_turntable/grbl_turntable.h"
#include "turntable_emulator.h"

#include <poll.h>
#include <pty.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <future>
#include <string>
#include <thread>

#include <gtest/gtest.h>

namespace craftscan::serial_turntable {
namespace {

using craftscan::testing::EmulatorOptions;
using craftscan::testing::TurntableEmulator;
using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;
using State = GrblTurntable::State;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

class SerialTurntable : public ::testing::Test {
 protected:
  // Fast settings: 3600 deg/min = 60 deg/s, short timeouts.
  GrblTurntableOptions DriverOptions(const std::string& path) {
    GrblTurntableOptions o;
    o.port_path = path;
    o.feed_deg_per_min = 3600;
    o.banner_timeout = milliseconds(300);
    o.command_timeout = milliseconds(300);
    o.homing_timeout = milliseconds(1000);
    o.move_timeout_margin = milliseconds(300);
    o.status_poll_interval = milliseconds(10);
    return o;
  }

  void StartEmulator(EmulatorOptions options = {}) {
    std::string error;
    emu_ = TurntableEmulator::Start(options, &error);
    ASSERT_TRUE(emu_) << error;
  }

  // Emulator + driver, connected and homed.
  void StartReady(EmulatorOptions emu_options = {}) {
    StartEmulator(emu_options);
    table_ = std::make_unique<GrblTurntable>(DriverOptions(emu_->slave_path()));
    Status s = table_->Connect();
    ASSERT_TRUE(s.ok()) << ToString(s);
    s = table_->Home();
    ASSERT_TRUE(s.ok()) << ToString(s);
    ASSERT_EQ(table_->state(), State::kReady);
  }

  std::unique_ptr<TurntableEmulator> emu_;
  std::unique_ptr<GrblTurntable> table_;
};

TEST_F(SerialTurntable, ConnectsAndChecksTheBanner) {
  StartEmulator();
  GrblTurntable table(DriverOptions(emu_->slave_path()));
  EXPECT_EQ(table.state(), State::kClosed);
  Status s = table.Connect();
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_EQ(table.state(), State::kUnhomed);
  EXPECT_EQ(table.firmware_version(), "1.1h");
  EXPECT_EQ(emu_->resets_received(), 0);  // the start banner was enough
  EXPECT_TRUE(std::isnan(table.angle_deg()));
  // Wrong state: no second Connect, no move before homing.
  EXPECT_EQ(table.Connect().code, StatusCode::kWrongState);
  s = table.MoveTo(10);
  EXPECT_EQ(s.code, StatusCode::kWrongState);
  EXPECT_TRUE(Contains(s.message, "MoveTo() not allowed in state Unhomed")) << s.message;
  table.Close();
  EXPECT_EQ(table.state(), State::kClosed);
  EXPECT_EQ(table.Home().code, StatusCode::kWrongState);
  EXPECT_EQ(table.Abort().code, StatusCode::kWrongState);
  EXPECT_EQ(table.Reconnect().code, StatusCode::kWrongState);
}

TEST_F(SerialTurntable, ResetsWhenNoBannerComes) {
  EmulatorOptions o;
  o.banner_on_start = false;  // controller already running when the port opens
  StartEmulator(o);
  GrblTurntable table(DriverOptions(emu_->slave_path()));
  const auto start = Clock::now();
  Status s = table.Connect();
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_EQ(emu_->resets_received(), 1);
  EXPECT_GE(SecondsSince(start), 0.3);  // waited one banner timeout first
  EXPECT_LT(SecondsSince(start), 0.6);
}

TEST_F(SerialTurntable, RejectsOtherFirmwareVersions) {
  EmulatorOptions o;
  o.version = "0.9j";
  StartEmulator(o);
  GrblTurntable table(DriverOptions(emu_->slave_path()));
  Status s = table.Connect();
  EXPECT_EQ(s.code, StatusCode::kProtocolError);
  EXPECT_TRUE(Contains(s.message, "unsupported firmware 'Grbl 0.9j'")) << s.message;
  EXPECT_EQ(table.state(), State::kClosed);
}

TEST_F(SerialTurntable, OpenErrorsNameThePath) {
  GrblTurntable table(DriverOptions("/nonexistent/ttyGRBL"));
  Status s = table.Connect();
  EXPECT_EQ(s.code, StatusCode::kIoError);
  EXPECT_TRUE(Contains(s.message, "/nonexistent/ttyGRBL")) << s.message;
  EXPECT_TRUE(Contains(s.message, "No such file")) << s.message;
  EXPECT_EQ(table.state(), State::kClosed);

  GrblTurntable not_a_tty(DriverOptions("/dev/null"));
  s = not_a_tty.Connect();
  EXPECT_EQ(s.code, StatusCode::kIoError);
  EXPECT_TRUE(Contains(s.message, "/dev/null")) << s.message;

  GrblTurntableOptions bad = DriverOptions("/dev/null");
  bad.feed_deg_per_min = 0;
  s = GrblTurntable(bad).Connect();
  EXPECT_EQ(s.code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(Contains(s.message, "feed_deg_per_min")) << s.message;
}

TEST_F(SerialTurntable, HomesAndMovesWithRealisticTiming) {
  EmulatorOptions o;
  o.start_position_deg = 123;
  o.homing_time = milliseconds(150);
  StartEmulator(o);
  table_ = std::make_unique<GrblTurntable>(DriverOptions(emu_->slave_path()));
  ASSERT_TRUE(table_->Connect().ok());
  auto start = Clock::now();
  Status s = table_->Home();
  const double homing_s = SecondsSince(start);
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_GE(homing_s, 0.15);
  EXPECT_LT(homing_s, 0.25);
  EXPECT_EQ(table_->angle_deg(), 0.0);
  EXPECT_NEAR(emu_->machine_position_deg(), 0.0, 1e-9);

  // 30 deg at 60 deg/s: 0.5 s nominal.
  start = Clock::now();
  s = table_->MoveTo(30);
  const double move_s = SecondsSince(start);
  ASSERT_TRUE(s.ok()) << ToString(s);
  RecordProperty("move_30deg_s", std::to_string(move_s));
  EXPECT_GE(move_s, 0.5);
  EXPECT_LT(move_s, 0.5 + 0.08);  // poll interval, PTY latency
  EXPECT_EQ(table_->state(), State::kReady);
  EXPECT_EQ(table_->angle_deg(), 30.0);
  EXPECT_NEAR(emu_->machine_position_deg(), 30.0, 1e-9);
  EXPECT_EQ(emu_->state(), "Idle");

  // Backwards and negative: 45 deg = 0.75 s.
  start = Clock::now();
  s = table_->MoveTo(-15);
  const double back_s = SecondsSince(start);
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_GE(back_s, 0.75);
  EXPECT_LT(back_s, 0.75 + 0.08);
  EXPECT_NEAR(emu_->machine_position_deg(), -15.0, 1e-9);
  std::printf("timing: homing %.3f s (150 ms), 30 deg %.3f s (0.500), 45 deg %.3f s (0.750)\n",
              homing_s, move_s, back_s);

  // A zero-length move returns at once.
  start = Clock::now();
  ASSERT_TRUE(table_->MoveTo(-15).ok());
  EXPECT_LT(SecondsSince(start), 0.05);
  EXPECT_EQ(table_->MoveTo(std::nan("")).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(table_->state(), State::kReady);  // a rejected argument changes nothing
}

TEST_F(SerialTurntable, SettleTimeIsWaitedAfterTheMove) {
  StartEmulator();
  GrblTurntableOptions o = DriverOptions(emu_->slave_path());
  o.settle_time = milliseconds(200);
  GrblTurntable table(o);
  ASSERT_TRUE(table.Connect().ok());
  ASSERT_TRUE(table.Home().ok());
  const auto start = Clock::now();
  ASSERT_TRUE(table.MoveTo(6).ok());  // 0.1 s + 0.2 s settle
  EXPECT_GE(SecondsSince(start), 0.3);
  EXPECT_LT(SecondsSince(start), 0.4);
}

TEST_F(SerialTurntable, WithoutLimitSwitchHomeSetsZeroHere) {
  EmulatorOptions eo;
  eo.homing_enabled = false;
  eo.start_position_deg = 37.5;
  eo.start_in_alarm = true;  // "$X" unlocks
  StartEmulator(eo);
  GrblTurntableOptions o = DriverOptions(emu_->slave_path());
  o.homing_enabled = false;
  GrblTurntable table(o);
  ASSERT_TRUE(table.Connect().ok());
  Status s = table.Home();
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_EQ(table.angle_deg(), 0.0);
  s = table.MoveTo(10);
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_NEAR(emu_->machine_position_deg(), 47.5, 1e-9);  // work 10 = machine 37.5 + 10
}

TEST_F(SerialTurntable, HomingCycleOnAControllerWithoutIt) {
  EmulatorOptions eo;
  eo.homing_enabled = false;
  StartEmulator(eo);
  GrblTurntable table(DriverOptions(emu_->slave_path()));
  ASSERT_TRUE(table.Connect().ok());
  Status s = table.Home();
  EXPECT_EQ(s.code, StatusCode::kDeviceError);
  EXPECT_TRUE(Contains(s.message,
                       "error:5 (homing cycle is not enabled via settings) in reply "
                       "to '$H'"))
      << s.message;
  EXPECT_EQ(table.state(), State::kFault);
  EXPECT_EQ(table.last_error().code, StatusCode::kDeviceError);
}

TEST_F(SerialTurntable, ErrorReplyIsMappedAndHomeRecovers) {
  StartReady();
  emu_->RaiseAlarm(1);  // while idle: the next G-code is locked out
  std::this_thread::sleep_for(milliseconds(20));
  Status s = table_->MoveTo(10);
  EXPECT_EQ(s.code, StatusCode::kDeviceError);
  EXPECT_TRUE(Contains(s.message,
                       "error:9 (G-code locked out during alarm or jog state) in "
                       "reply to 'G90 G1 X10.000 F3600.0' on /dev/pts/"))
      << s.message;
  EXPECT_EQ(table_->state(), State::kFault);
  EXPECT_TRUE(std::isnan(table_->angle_deg()));
  EXPECT_EQ(table_->MoveTo(10).code, StatusCode::kWrongState);
  // Home() from Fault: soft reset, $H, then moves work again.
  s = table_->Home();
  ASSERT_TRUE(s.ok()) << ToString(s);
  ASSERT_TRUE(table_->MoveTo(3).ok());
  EXPECT_NEAR(emu_->machine_position_deg(), 3.0, 1e-9);
}

TEST_F(SerialTurntable, AlarmDuringMoveFaultsWithTheAlarmText) {
  StartReady();
  auto move = std::async(std::launch::async, [&] { return table_->MoveTo(60); });  // 1 s
  std::this_thread::sleep_for(milliseconds(200));
  EXPECT_EQ(table_->state(), State::kMoving);
  const auto alarm_at = Clock::now();
  emu_->RaiseAlarm(1);
  ASSERT_EQ(move.wait_for(std::chrono::seconds(2)), std::future_status::ready);
  const double reaction_s = SecondsSince(alarm_at);
  Status s = move.get();
  EXPECT_EQ(s.code, StatusCode::kAlarm);
  EXPECT_TRUE(Contains(s.message, "ALARM:1 (hard limit triggered")) << s.message;
  EXPECT_LT(reaction_s, 0.1);
  EXPECT_EQ(table_->state(), State::kFault);
  EXPECT_LT(emu_->machine_position_deg(), 30);  // really stopped
}

TEST_F(SerialTurntable, SilenceTimesOutWithinTheBoundThenDeviceIsLost) {
  StartEmulator();
  GrblTurntableOptions o = DriverOptions(emu_->slave_path());
  o.timeouts_until_lost = 2;
  table_ = std::make_unique<GrblTurntable>(o);
  ASSERT_TRUE(table_->Connect().ok());
  ASSERT_TRUE(table_->Home().ok());
  emu_->SetSilent(true);
  auto start = Clock::now();
  Status s = table_->MoveTo(10);
  const double first_s = SecondsSince(start);
  EXPECT_EQ(s.code, StatusCode::kTimeout);
  EXPECT_TRUE(Contains(s.message, "no reply to 'G90 G1 X10.000 F3600.0' on /dev/pts/"))
      << s.message;
  EXPECT_TRUE(Contains(s.message, "within 300 ms")) << s.message;
  EXPECT_GE(first_s, 0.3);
  EXPECT_LT(first_s, 0.3 + 0.1);
  EXPECT_EQ(table_->state(), State::kFault);
  // Second timeout in a row (Home's soft reset gets no banner): device lost.
  start = Clock::now();
  s = table_->Home();
  const double second_s = SecondsSince(start);
  EXPECT_EQ(s.code, StatusCode::kDeviceLost);
  EXPECT_TRUE(Contains(s.message, "2 timeout(s) in a row")) << s.message;
  EXPECT_LT(second_s, 0.3 + 0.1);
  EXPECT_EQ(table_->state(), State::kDeviceLost);
  std::printf("silence: timeout after %.3f s and %.3f s (bound 0.300 s)\n", first_s, second_s);
  // The device comes back: Reconnect on the same PTY.
  emu_->SetSilent(false);
  s = table_->Reconnect();
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_EQ(table_->state(), State::kUnhomed);
}

TEST_F(SerialTurntable, SilenceDuringMovePollingTimesOut) {
  StartReady();
  auto move = std::async(std::launch::async, [&] { return table_->MoveTo(60); });
  std::this_thread::sleep_for(milliseconds(100));
  emu_->SetSilent(true);
  const auto start = Clock::now();
  ASSERT_EQ(move.wait_for(std::chrono::seconds(2)), std::future_status::ready);
  Status s = move.get();
  EXPECT_EQ(s.code, StatusCode::kTimeout);
  EXPECT_TRUE(Contains(s.message, "no status report")) << s.message;
  EXPECT_LT(SecondsSince(start), 0.3 + 0.1);
}

TEST_F(SerialTurntable, GarbageIsToleratedAndReported) {
  StartReady();
  emu_->InjectGarbage(std::string("\xff\xfe\x00#%garbage!\r\n", 14) + std::string(5000, 'Z') +
                      "\r\n");
  Status s = table_->MoveTo(6);
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_EQ(table_->unknown_lines(), 2);  // the garbage line and the overlong one
  EXPECT_NEAR(emu_->machine_position_deg(), 6, 1e-9);

  // Only garbage and no answer: the timeout says what came instead.
  emu_->SetSilent(true);
  emu_->InjectGarbage("#%garbage!\r\n");
  s = table_->MoveTo(7);
  EXPECT_EQ(s.code, StatusCode::kTimeout);
  EXPECT_TRUE(Contains(s.message, "unrecognized line(s) received, last: '#%garbage!'"))
      << s.message;
}

TEST_F(SerialTurntable, WrongReportedPositionIsAMismatchFault) {
  StartReady();
  emu_->SetPositionOffset(2.5);
  Status s = table_->MoveTo(30);
  EXPECT_EQ(s.code, StatusCode::kPositionMismatch);
  EXPECT_TRUE(Contains(s.message, "position mismatch: commanded 30.000 deg, reported 32.500 deg"))
      << s.message;
  EXPECT_EQ(table_->state(), State::kFault);
  // Within the tolerance is fine.
  emu_->SetPositionOffset(0.02);
  ASSERT_TRUE(table_->Home().ok());
  s = table_->MoveTo(3);
  EXPECT_TRUE(s.ok()) << ToString(s);
}

TEST_F(SerialTurntable, HangUpIsDeviceLostAndReconnectWorksOnANewPty) {
  StartReady();
  auto move = std::async(std::launch::async, [&] { return table_->MoveTo(60); });
  std::this_thread::sleep_for(milliseconds(150));
  const auto start = Clock::now();
  emu_->HangUp();
  ASSERT_EQ(move.wait_for(std::chrono::seconds(2)), std::future_status::ready);
  Status s = move.get();
  EXPECT_LT(SecondsSince(start), 0.1);
  EXPECT_EQ(s.code, StatusCode::kDeviceLost);
  EXPECT_TRUE(Contains(s.message, "/dev/pts/")) << s.message;
  EXPECT_EQ(table_->state(), State::kDeviceLost);
  EXPECT_EQ(table_->MoveTo(1).code, StatusCode::kWrongState);
  EXPECT_EQ(table_->Home().code, StatusCode::kWrongState);
  EXPECT_EQ(table_->Abort().code, StatusCode::kWrongState);

  // Reconnecting to the dead PTY fails clearly and stays DeviceLost.
  s = table_->Reconnect();
  EXPECT_FALSE(s.ok());
  EXPECT_EQ(table_->state(), State::kDeviceLost);

  const std::string old_path = emu_->slave_path();
  emu_.reset();
  StartEmulator();  // restarted: a new PTY
  s = table_->Reconnect(emu_->slave_path());
  ASSERT_TRUE(s.ok()) << ToString(s);
  EXPECT_EQ(table_->state(), State::kUnhomed);  // homing required again
  EXPECT_EQ(table_->MoveTo(1).code, StatusCode::kWrongState);
  ASSERT_TRUE(table_->Home().ok());
  ASSERT_TRUE(table_->MoveTo(2).ok());
  EXPECT_NEAR(emu_->machine_position_deg(), 2, 1e-9);
}

TEST_F(SerialTurntable, ReconnectThroughASymlinkTheEmulatorUpdates) {
  const std::string link = ::testing::TempDir() + "craftscan-ttyGRBL-" + std::to_string(::getpid());
  EmulatorOptions eo;
  eo.link_path = link;
  StartEmulator(eo);
  table_ = std::make_unique<GrblTurntable>(DriverOptions(link));
  ASSERT_TRUE(table_->Connect().ok());
  ASSERT_TRUE(table_->Home().ok());
  emu_->HangUp();
  EXPECT_EQ(table_->MoveTo(5).code, StatusCode::kDeviceLost);
  emu_.reset();
  StartEmulator(eo);  // new PTY, same link
  Status s = table_->Reconnect();
  ASSERT_TRUE(s.ok()) << ToString(s);
  ASSERT_TRUE(table_->Home().ok());
  ASSERT_TRUE(table_->MoveTo(5).ok());
  emu_.reset();
  std::filesystem::remove(link);
}

TEST_F(SerialTurntable, AbortDuringMoveStopsIt) {
  StartReady();
  auto move = std::async(std::launch::async, [&] { return table_->MoveTo(60); });  // 1 s
  std::this_thread::sleep_for(milliseconds(250));
  const auto abort_at = Clock::now();
  Status a = table_->Abort();
  EXPECT_TRUE(a.ok()) << ToString(a);
  ASSERT_EQ(move.wait_for(std::chrono::seconds(2)), std::future_status::ready);
  const double reaction_s = SecondsSince(abort_at);
  Status s = move.get();
  EXPECT_EQ(s.code, StatusCode::kAborted);
  EXPECT_TRUE(Contains(s.message, "move to 60.000 deg aborted")) << s.message;
  EXPECT_LT(reaction_s, 0.05);
  EXPECT_EQ(table_->state(), State::kUnhomed);
  std::this_thread::sleep_for(milliseconds(50));
  const double stopped_at = emu_->machine_position_deg();
  EXPECT_GT(stopped_at, 10);
  EXPECT_LT(stopped_at, 25);          // ~15 deg after 0.25 s at 60 deg/s
  EXPECT_EQ(emu_->state(), "Alarm");  // GRBL: ALARM:3 after a reset in motion
  std::this_thread::sleep_for(milliseconds(100));
  EXPECT_EQ(emu_->machine_position_deg(), stopped_at);  // not moving any more
  std::printf("abort: returned after %.3f s, stopped at %.3f deg\n", reaction_s, stopped_at);
  // Homing again (through the pending reset banner) makes it usable.
  Status h = table_->Home();
  ASSERT_TRUE(h.ok()) << ToString(h);
  ASSERT_TRUE(table_->MoveTo(5).ok());
}

// A controller scripted on a raw PTY, so replies land exactly where a test
// wants them: an ALARM:N arriving in the same read as the reply a call was
// waiting for ("ok", a status report) must not be dropped with the rest of
// that read, or only "Alarm state" is left without the reason.
class ScriptedController {
 public:
  // `after_move`: what the controller sends, in one write, for the first '?'
  // (status == true) or in place of the "ok" (status == false) once a G1
  // line came.
  ScriptedController(std::string after_move, bool status)
      : after_move_(std::move(after_move)), status_(status) {
    if (::openpty(&master_, &slave_, nullptr, nullptr, nullptr) != 0) return;
    path_ = ::ttyname(slave_);
    thread_ = std::thread([this] { Serve(); });
  }
  ~ScriptedController() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
    if (master_ >= 0) ::close(master_);
    if (slave_ >= 0) ::close(slave_);
  }
  const std::string& path() const { return path_; }

 private:
  void Send(const std::string& text) {
    if (::write(master_, text.data(), text.size()) != static_cast<ssize_t>(text.size()))
      stop_ = true;
  }
  void Serve() {
    std::string line;
    bool moving = false, sent = false;
    while (!stop_) {
      pollfd pfd{master_, POLLIN, 0};
      if (::poll(&pfd, 1, 5) <= 0 || !(pfd.revents & POLLIN)) continue;
      char buf[256];
      const ssize_t n = ::read(master_, buf, sizeof(buf));
      for (ssize_t k = 0; k < n; ++k) {
        const char c = buf[k];
        if (c == 0x18) {
          Send("\r\nGrbl 1.1h ['$' for help]\r\n");
        } else if (c == '?') {
          const bool first = moving && status_ && !sent;
          sent = sent || first;
          Send(first ? after_move_
                     : (moving ? "<Alarm|MPos:1.000,0.000,0.000|FS:0,0>\r\n"
                               : "<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\n"));
        } else if (c == '\n') {
          const bool g1 = line.rfind("G90 G1", 0) == 0;
          moving = moving || g1;
          Send(g1 && !status_ ? after_move_ : "ok\r\n");
          line.clear();
        } else if (c != '\r') {
          line.push_back(c);
        }
      }
    }
  }

  std::string after_move_;
  bool status_;
  int master_ = -1, slave_ = -1;
  std::string path_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

TEST(GrblTurntableReplies, AnAlarmBehindTheAwaitedReplyIsNotLost) {
  struct Case {
    std::string bytes;
    bool status;
  };
  for (const Case& c : {Case{"<Run|MPos:1.000,0.000,0.000|FS:3600,0>\r\nALARM:1\r\n", true},
                        Case{"ok\r\nALARM:2\r\n", false}}) {
    ScriptedController controller(c.bytes, c.status);
    ASSERT_FALSE(controller.path().empty());
    GrblTurntableOptions o;
    o.port_path = controller.path();
    o.homing_enabled = false;  // $X, G92 X0
    o.banner_timeout = milliseconds(100);
    o.command_timeout = milliseconds(300);
    GrblTurntable table(o);
    Status s = table.Connect();
    ASSERT_TRUE(s.ok()) << ToString(s);
    s = table.Home();
    ASSERT_TRUE(s.ok()) << ToString(s);
    s = table.MoveTo(10);
    EXPECT_EQ(s.code, StatusCode::kAlarm) << ToString(s);
    EXPECT_TRUE(Contains(s.message, c.status ? "ALARM:1 (hard limit" : "ALARM:2 (soft limit"))
        << s.message;
    EXPECT_EQ(table.state(), State::kFault);
  }
}

}  // namespace
}  // namespace craftscan::serial_turntable
