// craftscan-worker as systemd runs it, under a fake service manager
// (fake_notify_socket.h): READY=1 from the worker's own pid, watchdog pings
// when WATCHDOG_USEC is set (and none when it is not, or watchdog.enabled is
// false), SIGTERM or SIGINT → STOPPING=1 and exit 0; a bad config or token
// → exit 2 naming the field, never READY=1; the command line's other modes.
// DDS stays on loopback (CYCLONEDDS_URI) on a domain of this test's own.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <regex>
#include <string>
#include <vector>

#include "dds/dds_test_util.h"
#include "fake_notify_socket.h"
#include "file_util.h"
#include "process_util.h"

namespace craftscan {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;
using namespace std::chrono_literals;
using testing::ChildProcess;
using testing::FakeNotifySocket;
using testing::ScopedEnv;
namespace fs = std::filesystem;

constexpr auto kStartDeadline = 15s;  // READY=1 (DDS discovery set-up included)
constexpr auto kExitDeadline = 15s;

class WorkerProcess : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(manager_.ok()) << manager_.error();
    dir_ = fs::temp_directory_path() /
           ("craftscan_test_worker_process_" + std::to_string(std::random_device{}()));
    fs::create_directories(dir_ / "work");
    token_ = (dir_ / "worker.token").string();
    std::ofstream(token_) << "worker-token-1\n";
    ::chmod(token_.c_str(), 0600);
  }
  void TearDown() override {
    child_.Kill();
    fs::remove_all(dir_);
  }

  // A valid config with `extra` lines appended (later keys must not repeat
  // earlier ones).
  std::string WriteConfig(const std::string& extra = "", bool with_token = true) {
    std::string text =
        "version: 1\nworker: test_worker\nsite: test_site\nwork_dir: " + (dir_ / "work").string() +
        "\ndds:\n  domain: " + std::to_string(testing::ProcessDomainId()) + "\n";
    if (with_token) text += "auth:\n  token_file: " + token_ + "\n";
    text += extra;
    const std::string path = (dir_ / "craftscan-worker.yaml").string();
    std::ofstream(path) << text;
    return path;
  }

  bool Start(const std::vector<std::string>& args) {
    std::vector<std::string> argv = {CRAFTSCAN_WORKER_BINARY};
    argv.insert(argv.end(), args.begin(), args.end());
    testing::SpawnOptions options;
    options.stdout_path = (dir_ / "stdout").string();
    options.stderr_path = (dir_ / "stderr").string();
    return testing::Spawn(argv, options, &child_);
  }

  // Runs to the end (a mode that exits by itself); its exit code.
  int Run(const std::vector<std::string>& args) {
    if (!Start(args)) return -2;
    return child_.Wait(kExitDeadline);
  }

  std::string Out() const { return testing::ReadFile(dir_ / "stdout"); }
  std::string Err() const { return testing::ReadFile(dir_ / "stderr"); }

  // WATCHDOG=1 datagrams within `window`, failing on anything but those
  // and STATUS= lines.
  int CountPings(std::chrono::milliseconds window) {
    int pings = 0;
    const auto end = std::chrono::steady_clock::now() + window;
    while (std::chrono::steady_clock::now() < end) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          end - std::chrono::steady_clock::now());
      const auto m = manager_.Receive(std::max(left, 1ms));
      if (!m) continue;
      if (m->Has("WATCHDOG=1")) {
        ++pings;
      } else {
        EXPECT_TRUE(m->Value("STATUS").has_value()) << "unexpected: " << m->text;
      }
    }
    return pings;
  }

  FakeNotifySocket manager_;
  ScopedEnv notify_{"NOTIFY_SOCKET", manager_.address()};
  ScopedEnv watchdog_pid_{"WATCHDOG_PID", std::nullopt};
  ScopedEnv cyclone_{"CYCLONEDDS_URI", testing::TestDdsConfig()};
  fs::path dir_;
  std::string token_;
  ChildProcess child_;
};

TEST_F(WorkerProcess, ReadyPingsAndStopsCleanlyOnSigterm) {
  ScopedEnv watchdog("WATCHDOG_USEC", "1000000");  // pings every 0.5 s
  ASSERT_TRUE(Start({"--config", WriteConfig()}));
  const auto ready = manager_.WaitFor("READY=1", kStartDeadline);
  ASSERT_TRUE(ready) << "no READY=1; stderr:\n" << Err();
  EXPECT_EQ(ready->pid, *child_.pid_slot()) << "READY=1 must come from the main process";
  EXPECT_THAT(ready->Value("STATUS").value_or(""), HasSubstr("test_worker"));
  // 0.5 s apart: at least 3 in 2.5 s (4–5 expected), not a flood.
  const int pings = CountPings(2500ms);
  EXPECT_GE(pings, 3);
  EXPECT_LE(pings, 7);
  child_.Signal(SIGTERM);
  EXPECT_TRUE(manager_.WaitFor("STOPPING=1", 5s)) << Err();
  EXPECT_EQ(child_.Wait(kExitDeadline), 0) << Err();
  // Logged as craftscand logs: ISO time, level, message.
  EXPECT_TRUE(std::regex_search(
      Err(),
      std::regex(R"((^|\n)\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3} .*info.* ready: announced)")))
      << Err();
  EXPECT_THAT(Err(), HasSubstr("signal 15: stopping"));
}

TEST_F(WorkerProcess, SigintStopsToo) {
  ASSERT_TRUE(Start({"--config", WriteConfig()}));
  ASSERT_TRUE(manager_.WaitFor("READY=1", kStartDeadline)) << Err();
  child_.Signal(SIGINT);
  EXPECT_TRUE(manager_.WaitFor("STOPPING=1", 5s)) << Err();
  EXPECT_EQ(child_.Wait(kExitDeadline), 0) << Err();
}

TEST_F(WorkerProcess, NoPingsWithoutWatchdogUsec) {
  ScopedEnv watchdog("WATCHDOG_USEC", std::nullopt);
  ASSERT_TRUE(Start({"--config", WriteConfig()}));
  ASSERT_TRUE(manager_.WaitFor("READY=1", kStartDeadline)) << Err();
  EXPECT_EQ(CountPings(1500ms), 0);
  child_.Signal(SIGTERM);
  EXPECT_EQ(child_.Wait(kExitDeadline), 0) << Err();
}

TEST_F(WorkerProcess, NoPingsWhenTheConfigTurnsTheWatchdogOff) {
  ScopedEnv watchdog("WATCHDOG_USEC", "1000000");
  ASSERT_TRUE(Start({"--config", WriteConfig("watchdog:\n  enabled: false\n")}));
  ASSERT_TRUE(manager_.WaitFor("READY=1", kStartDeadline)) << Err();
  EXPECT_EQ(CountPings(1500ms), 0);
  child_.Signal(SIGTERM);
  EXPECT_EQ(child_.Wait(kExitDeadline), 0) << Err();
}

TEST_F(WorkerProcess, BadConfigExits2NamingTheFieldWithoutReady) {
  EXPECT_EQ(Run({"--config", WriteConfig("threads: 0\n")}), 2);
  EXPECT_THAT(Err(), HasSubstr("threads: must be an integer in 1..256, got '0' (line 9)"));
  EXPECT_THAT(Err(), HasSubstr((dir_ / "craftscan-worker.yaml").string()));
  const auto sent = manager_.Drain();
  for (const auto& m : sent) EXPECT_FALSE(m.Has("READY=1")) << m.text;
}

TEST_F(WorkerProcess, UnknownKeyAndMissingFileExit2) {
  EXPECT_EQ(Run({"--config", WriteConfig("treads: 4\n")}), 2);
  EXPECT_THAT(Err(), HasSubstr("treads: unknown key"));
  EXPECT_EQ(Run({"--config", (dir_ / "absent.yaml").string()}), 2);
  EXPECT_THAT(Err(), HasSubstr("absent.yaml: cannot open: No such file or directory"));
  EXPECT_TRUE(manager_.Drain().empty());
}

TEST_F(WorkerProcess, MissingOrOpenTokenExits2) {
  const std::string missing = (dir_ / "nope.token").string();
  EXPECT_EQ(Run({"--config", WriteConfig("auth:\n  token_file: " + missing + "\n", false)}), 2);
  EXPECT_THAT(Err(), HasSubstr("auth.token_file: " + missing + ": cannot open"));
  ::chmod(token_.c_str(), 0644);
  EXPECT_EQ(Run({"--config", WriteConfig()}), 2);
  EXPECT_THAT(Err(), HasSubstr("mode 0644"));
  EXPECT_TRUE(manager_.Drain().empty());
}

TEST_F(WorkerProcess, MissingCycloneFileExits2) {
  const std::string missing = (dir_ / "cyclonedds.xml").string();
  ScopedEnv file("CRAFTSCAN_WORKER_DDS_CONFIG_FILE", missing);
  EXPECT_EQ(Run({"--config", WriteConfig()}), 2);
  EXPECT_THAT(Err(), HasSubstr("dds.config_file: " + missing + ": cannot read"));
  EXPECT_TRUE(manager_.Drain().empty());
}

TEST_F(WorkerProcess, EnvironmentOverrideReachesTheProcess) {
  ScopedEnv threads("CRAFTSCAN_WORKER_THREADS", "999");
  EXPECT_EQ(Run({"--config", WriteConfig()}), 2);
  EXPECT_THAT(Err(), HasSubstr("CRAFTSCAN_WORKER_THREADS: threads: must be an integer in 1..256"));
}

TEST_F(WorkerProcess, CheckPrintVersionAndUsage) {
  const std::string config = WriteConfig("threads: 5\n");
  EXPECT_EQ(Run({"--config", config, "--check-config"}), 0) << Err();
  EXPECT_THAT(Out(), HasSubstr(config + " is valid"));
  EXPECT_EQ(Run({"--config", config, "--print-config"}), 0) << Err();
  EXPECT_THAT(Out(), HasSubstr("threads: 5\n"));
  EXPECT_THAT(Out(), HasSubstr("worker: \"test_worker\"\n"));
  EXPECT_EQ(Run({"--version"}), 0);
  EXPECT_THAT(Out(), ::testing::ContainsRegex("craftscan-worker [0-9]+\\.[0-9]+"));
  EXPECT_EQ(Run({"--help"}), 0);
  EXPECT_THAT(Out(), HasSubstr("--check-config"));
  EXPECT_EQ(Run({"--bogus"}), 2);
  EXPECT_THAT(Err(), HasSubstr("--bogus"));
  // None of these modes talks to the service manager.
  EXPECT_TRUE(manager_.Drain().empty());
}

}  // namespace
}  // namespace craftscan
