// craftscand with the serial turntable driver: GRBL over a pseudo-terminal
// served by the turntable emulator of tests/tools (the same code as the
// craftscan-turntable-emulator program, run in-process so the test can read
// its position and state), with the sim camera. Each fault is injected in
// the middle of a move, after at least one acknowledged capture: an alarm,
// silence, garbage bytes, a hang-up. In every case the reason reaches the
// job, its progress and StationStatus, nothing acknowledged is lost, the
// daemon stays idle and serving, and `resume` completes the session.
//
// The sim camera renders its own turntable, which stays at 0 here: every
// view shows the same image. Capture, storage and matching are real; the
// registration is what a station with a stuck platter would give.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "daemon_devices.h"
#include "turntable_emulator.h"

namespace craftscan::testing {
namespace {

constexpr int kViews = 4;

class SerialStation {
 public:
  // Starts the emulator (a symlink in the daemon's root points at its PTY)
  // and craftscand driving it. False (and the test failed) if either does
  // not come up.
  bool Start() {
    link_ = daemon.fixture.root() + "/ttyGRBL";
    if (!StartEmulator()) return false;
    // 3600 deg/min: a 90-degree step takes 1.5 s, long enough to inject a
    // fault in the middle of it.
    return daemon.Start("  camera: {driver: sim, config: {image_size: 320x256, threads: " +
                        std::to_string(TestThreads()) +
                        "}}\n"
                        "  turntable: {driver: serial_turntable, config: {port: " +
                        link_ +
                        ", feed_deg_min: 3600, command_timeout_ms: 500, banner_timeout_ms: 1000, "
                        "homing_timeout_ms: 5000}}\n");
  }

  // A new emulator on the same symlink (after a hang-up).
  bool StartEmulator() {
    EmulatorOptions options;
    options.homing_time = std::chrono::milliseconds(50);
    options.link_path = link_;
    std::string error;
    emu = TurntableEmulator::Start(options, &error);
    if (!emu) ADD_FAILURE() << "emulator: " << error;
    return emu != nullptr;
  }

  // Starts a scan and waits until view 0 is acknowledged and the platter
  // is on its way to view 1: the moment every fault is injected. The scan's
  // {id, session}, or null (the test failed).
  nlohmann::json ScanUntilMidMove(const std::string& object) {
    nlohmann::json scan = daemon.ScanUntilFirstCapture(object, kViews);
    if (scan.is_null()) return scan;
    // Mid-move: the platter has turned 15 of the 90 degrees (0.25 of the
    // 1.5 s the step takes).
    const auto deadline = std::chrono::steady_clock::now() + 20s;
    while (emu->state() != "Run" || std::fmod(emu->machine_position_deg(), 90) < 15) {
      if (std::chrono::steady_clock::now() > deadline) {
        ADD_FAILURE() << "the platter never moved after view 0 (emulator " << emu->state() << " at "
                      << emu->machine_position_deg() << " deg)";
        return nullptr;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    return scan;
  }

  RunningDaemon daemon;
  std::unique_ptr<TurntableEmulator> emu;

 private:
  std::string link_;
};

// The common end of the failing cases: the job failed for `reason`, the
// session is interrupted with everything acknowledged intact, the daemon
// reports it and serves; `before_resume` repairs the fault; resume finishes.
void ExpectInterruptedThenResumed(SerialStation& s, const nlohmann::json& scan,
                                  const std::vector<std::string>& reason,
                                  const std::function<void()>& before_resume) {
  RunningDaemon& d = s.daemon;
  const std::string session = scan["session"];
  const nlohmann::json job = WaitForJobEnd(d.client, kObserverToken, scan["id"], 120s);
  ASSERT_EQ(job.value("state", ""), "failed") << job.dump() << "\n" << d.fixture.Log();
  const std::vector<CaptureRecord> acknowledged = d.Acknowledged(session);
  ASSERT_GE(acknowledged.size(), 1u);
  EXPECT_LT(acknowledged.size(), static_cast<std::size_t>(kViews));
  EXPECT_EQ(d.SessionStateOf(session), daemon::SessionState::kInterrupted);
  const std::vector<int> durable = d.ExpectNothingLost(session, acknowledged);
  EXPECT_EQ(durable.size(), acknowledged.size());
  d.ExpectFailureReported(job, "turntable", reason);
  EXPECT_TRUE(d.watcher.WaitForDeviceState("turntable", "Fault"))
      << StatusWatcher::Device(d.watcher.Last(), "turntable").state;
  std::printf("  %zu of %d captures acknowledged before the fault, all intact\n",
              acknowledged.size(), kViews);

  before_resume();
  const nlohmann::json resume = d.Resume(session);
  ASSERT_FALSE(resume.is_null());
  d.ExpectResumed(session, resume["id"], kViews, acknowledged);
  EXPECT_TRUE(d.watcher.WaitForDeviceState("turntable", "Ready"));
}

TEST(DaemonSerialTurntable, AlarmMidMoveInterruptsTheScanAndResumeHomesAndFinishesIt) {
  SerialStation s;
  ASSERT_TRUE(s.Start());
  const nlohmann::json scan = s.ScanUntilMidMove("alarm");
  ASSERT_FALSE(scan.is_null());
  s.emu->RaiseAlarm(1);
  ExpectInterruptedThenResumed(s, scan, {"turntable", "ALARM:1"}, [] {});
}

// A silent controller: the move times out after command_timeout_ms, the
// table is left stopped (Fault, not Moving; nothing more is commanded),
// the job fails naming the timeout. The emulator ignores every byte while
// silent, so it finishes the move it had accepted.
TEST(DaemonSerialTurntable, SilenceMidMoveTimesOutAndTheTableIsLeftStopped) {
  SerialStation s;
  ASSERT_TRUE(s.Start());
  const nlohmann::json scan = s.ScanUntilMidMove("silence");
  ASSERT_FALSE(scan.is_null());
  s.emu->SetSilent(true);
  const int lines_at_fault = s.emu->lines_received();
  ExpectInterruptedThenResumed(s, scan, {"turntable", "timeout", "within 500 ms"}, [&] {
    const auto deadline = std::chrono::steady_clock::now() + 10s;
    while (s.emu->state() == "Run" && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    // Where the move in progress was going: the view after the last one
    // acknowledged.
    EXPECT_EQ(s.emu->state(), "Idle");
    EXPECT_NEAR(s.emu->machine_position_deg(), s.daemon.Acknowledged(scan["session"]).size() * 90.0,
                0.01);
    EXPECT_EQ(s.emu->lines_received(), lines_at_fault) << "the daemon went on driving the table";
    s.emu->SetSilent(false);
  });
}

// What the driver promises (grbl_reply_parser.h): bytes outside printable
// ASCII are dropped, a garbage line of its own is counted and skipped. The
// scan completes.
TEST(DaemonSerialTurntable, LineNoiseAndGarbageLinesAreTolerated) {
  SerialStation s;
  ASSERT_TRUE(s.Start());
  const nlohmann::json scan = s.ScanUntilMidMove("noise");
  ASSERT_FALSE(scan.is_null());
  s.emu->InjectGarbage(std::string("\xff\xfe\x01\x7f", 4));
  s.emu->InjectGarbage("#%garbage!\r\n");
  const nlohmann::json job = WaitForJobEnd(s.daemon.client, kObserverToken, scan["id"], 120s);
  ASSERT_EQ(job.value("state", ""), "done") << job.dump() << "\n" << s.daemon.fixture.Log();
  EXPECT_EQ(
      s.daemon.ExpectNothingLost(scan["session"], s.daemon.Acknowledged(scan["session"])).size(),
      static_cast<std::size_t>(kViews));
  EXPECT_NEAR(s.emu->machine_position_deg(), 270, 0.01);
}

// Printable garbage without a line end joins the next reply, which is then
// unrecognised: that reply is lost, the driver times out quoting what came
// instead; the job fails with it and resume finishes the session.
TEST(DaemonSerialTurntable, GarbageGluedToAReplyFailsTheMoveQuotingIt) {
  SerialStation s;
  ASSERT_TRUE(s.Start());
  const nlohmann::json scan = s.ScanUntilMidMove("garbage");
  ASSERT_FALSE(scan.is_null());
  s.emu->InjectGarbage("#%garbage!");
  ExpectInterruptedThenResumed(
      s, scan, {"turntable", "timeout", "unrecognized line(s) received, last: '#%garbage!"}, [] {});
}

// The PTY is closed under the driver (a USB adapter pulled out): the job
// fails naming the lost turntable. Resume while it is gone fails the same
// way and loses nothing; with the emulator back on the same path, the
// driver reconnects when the resumed job homes the table, and the session
// completes.
TEST(DaemonSerialTurntable, HangUpMidMoveLosesTheTableAndResumeReconnects) {
  SerialStation s;
  ASSERT_TRUE(s.Start());
  const nlohmann::json scan = s.ScanUntilMidMove("hangup");
  ASSERT_FALSE(scan.is_null());
  s.emu->HangUp();
  ExpectInterruptedThenResumed(s, scan, {"turntable", "lost"}, [&] {
    s.emu.reset();  // the symlink now dangles
    RunningDaemon& d = s.daemon;
    const std::string session = scan["session"];
    const std::vector<CaptureRecord> acknowledged = d.Acknowledged(session);
    const nlohmann::json early = d.Resume(session);
    ASSERT_FALSE(early.is_null());
    const nlohmann::json job = WaitForJobEnd(d.client, kObserverToken, early["id"], 60s);
    EXPECT_EQ(job.value("state", ""), "failed") << job.dump();
    EXPECT_NE(job.value("message", "").find("turntable"), std::string::npos) << job.dump();
    std::printf("  resume with the turntable gone: %s\n", job.value("message", "").c_str());
    EXPECT_EQ(d.SessionStateOf(session), daemon::SessionState::kInterrupted);
    EXPECT_EQ(d.ExpectNothingLost(session, acknowledged).size(), acknowledged.size());
    ASSERT_TRUE(s.StartEmulator());
  });
  // The driver reconnected (Home() after a loss), on the path it was given.
  EXPECT_NE(s.daemon.fixture.Log().find("serial_turntable/turntable: reconnected: reconnected on"),
            std::string::npos)
      << s.daemon.fixture.Log();
}

}  // namespace
}  // namespace craftscan::testing
