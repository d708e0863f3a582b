// craftscand under the sandbox of systemd/craftscand.service, reproduced
// without systemd by tests/tools/hardened-run (which reads the unit file
// itself; see its main.cc for what is and is not reproduced):
//   - the sandbox is in force: a probe under the same launcher is refused
//     each confined operation with the error the unit's setting gives, while
//     the same probe outside succeeds (so a no-op sandbox fails the test);
//   - the daemon works in it: READY=1 over the notify socket, status over
//     DDS, a 3-view scan of the calibrated sim station completes with an
//     intact session, SIGTERM ends it with status 0, and its log has no
//     error caused by a refused call.
// Skipped where the kernel offers no unprivileged user namespaces or
// seccomp, and in sanitizer builds (their runtimes need ptrace and
// personality(), which the unit's filter refuses). About 15 s.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "../sessions/status_util.h"
#include "craftscan/daemon/session_store.h"
#include "daemon_fixture.h"
#include "station_client.h"
#include "test_paths.h"

using craftscan::testing::StatusInto;

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define CRAFTSCAN_HARDENED_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define CRAFTSCAN_HARDENED_SANITIZED 1
#endif
#endif

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;

const char* const kUnit = ::craftscan::testing::UnitFilePath();

struct Finished {
  int status = -1;  // wait status; -1 when it had to be killed
  std::string out, err;
};

// Runs argv to completion (killed after `timeout`), stdout and stderr to
// files in `dir`.
Finished RunToEnd(const std::vector<std::string>& argv, const std::string& dir,
                  std::chrono::seconds timeout = 30s) {
  const std::string out = dir + "/run.out", err = dir + "/run.err";
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
  posix_spawn_file_actions_addopen(&actions, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
  std::vector<std::string> args = argv;
  std::vector<char*> raw;
  for (std::string& a : args) raw.push_back(a.data());
  raw.push_back(nullptr);
  pid_t pid = -1;
  Finished f;
  const int r = posix_spawn(&pid, raw[0], &actions, nullptr, raw.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (r != 0) {
    f.err = std::string("posix_spawn ") + argv[0] + ": " + std::strerror(r);
    return f;
  }
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  int status = 0;
  while (::waitpid(pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      status = -1;
      break;
    }
    std::this_thread::sleep_for(10ms);
  }
  f.status = status;
  f.out = ReadFile(out);
  f.err += ReadFile(err);
  return f;
}

// hardened-run with the unit, the fixture's data dir as StateDirectory=,
// its folder (config, tokens) and the build and source trees kept reachable
// read-only wherever they are (/tmp and /home are masked inside).
std::vector<std::string> Launcher(const DaemonFixture& f, std::vector<std::string> more_ro = {}) {
  std::vector<std::string> l = {::craftscan::testing::HardenedRunPath(), "--unit", kUnit,
                                "--state-dir", f.data_dir()};
  more_ro.insert(
      more_ro.end(),
      {f.root(),
       std::filesystem::path(::craftscan::testing::CraftscandPath()).parent_path().string(),
       ::craftscan::testing::PluginDir(), ::craftscan::testing::SystemdDir(),
       std::filesystem::path(::craftscan::testing::HardenedProbePath()).parent_path().string()});
  for (const std::string& p : more_ro) l.insert(l.end(), {"--ro", p});
  l.push_back("--");
  return l;
}

// "ACTION RESULT" lines of hardened-probe.
std::map<std::string, std::string> ProbeResults(const std::string& out) {
  std::map<std::string, std::string> results;
  std::istringstream in(out);
  for (std::string line; std::getline(in, line);) {
    const auto space = line.find(' ');
    if (space != std::string::npos) results[line.substr(0, space)] = line.substr(space + 1);
  }
  return results;
}

// Skips (returns true) where the sandbox cannot be built here.
bool SandboxUnavailable(const DaemonFixture& f, std::string* why) {
#ifdef CRAFTSCAN_HARDENED_SANITIZED
  *why =
      "sanitizer build: ASan/LSan/TSan runtimes need ptrace() and personality(), which the "
      "unit's SystemCallFilter= and LockPersonality= refuse";
  return true;
#else
  std::vector<std::string> argv = Launcher(f);
  argv.insert(argv.end(), {::craftscan::testing::HardenedProbePath(), "status"});
  const Finished run = RunToEnd(argv, f.root());
  if (WIFEXITED(run.status) && WEXITSTATUS(run.status) == 77) {
    *why = "no user namespaces or seccomp here: " + run.err;
    return true;
  }
  return false;
#endif
}

// Lines of the daemon's log that tell of a call refused by the sandbox.
std::vector<std::string> RefusalLines(const std::string& log) {
  std::vector<std::string> found;
  std::istringstream in(log);
  for (std::string line; std::getline(in, line);) {
    for (const char* sign :
         {"Operation not permitted", "Permission denied", "Read-only file system",
          "Address family not supported", "Function not implemented", "EPERM", "EACCES", "EROFS",
          "EAFNOSUPPORT", "ENOSYS", "SIGSYS"}) {
      if (line.find(sign) != std::string::npos) {
        found.push_back(line);
        break;
      }
    }
  }
  return found;
}

TEST(HardenedService, TheUnitsSandboxIsInForce) {
  DaemonFixture f("320x256");
  std::string error;
  ASSERT_TRUE(f.Prepare(&error, /*with_calibration=*/false)) << error;
  std::string why;
  if (SandboxUnavailable(f, &why)) GTEST_SKIP() << why;

  // A file in the host's /tmp the sandbox must not see, and a name the
  // probe writes in its private /tmp that the host must not get.
  std::string host_marker = "/tmp/craftscan-hardened-marker-XXXXXX";
  const int marker_fd = ::mkstemp(host_marker.data());
  ASSERT_GE(marker_fd, 0);
  ::close(marker_fd);
  const std::string private_name = "/tmp/craftscan-hardened-private-" + std::to_string(::getpid());
  const std::string data = f.data_dir(), root = f.root();

  // Action → what the unit's sandbox answers.
  const std::vector<std::pair<std::string, std::string>> expected = {
      {"write:" + data + "/probe", "OK"},                    // StateDirectory= writable
      {"write:" + root + "/probe", "EROFS"},                 // ProtectSystem=strict
      {"openw:" + root + "/craftscand.yaml", "EROFS"},       // config not writable
      {"write:/etc/craftscan-hardened-probe", "EROFS"},      // ProtectSystem=strict
      {"write:/var/lib/craftscan-hardened-probe", "EROFS"},  // only StateDirectory=
      {"openw:/proc/sys/kernel/hostname", "EROFS"},          // ProtectKernelTunables=
      {"write:" + private_name, "OK"},                       // PrivateTmp= (writable)
      {"stat:" + host_marker, "ENOENT"},                     // PrivateTmp= (private)
      {"socket:unix", "OK"},                                 // RestrictAddressFamilies=
      {"socket:inet", "OK"},
      {"socket:inet6", "OK"},
      {"socket:netlink", "OK"},
      {"socket:packet", "EAFNOSUPPORT"},
      {"mmap-wx", "EPERM"},  // MemoryDenyWriteExecute=
      {"mprotect-exec", "EPERM"},
      {"setuid-self", "EPERM"},                   // ~@privileged
      {"sethostname-same", "EPERM"},              // ~@privileged, ProtectHostname=
      {"syslog", "EPERM"},                        // not @system-service
      {"personality", "EPERM"},                   // LockPersonality=
      {"sched-fifo", "EPERM"},                    // RestrictRealtime=
      {"chmod-suid:" + data + "/suid", "EPERM"},  // RestrictSUIDSGID=
      {"unshare-user", "EPERM"},                  // RestrictNamespaces=
      {"clone3", "ENOSYS"},                       // RestrictNamespaces= (clone3)
  };
  std::vector<std::string> argv = Launcher(f);
  argv.insert(argv.end() - 1, "--explain");  // before the "--"
  argv.insert(argv.end(), ::craftscan::testing::HardenedProbePath());
  for (const auto& [action, result] : expected) argv.push_back(action);
  for (const char* more : {"list:/home", "list:/root", "status"}) argv.push_back(more);
  const Finished run = RunToEnd(argv, root);
  ASSERT_TRUE(WIFEXITED(run.status) && WEXITSTATUS(run.status) == 0)
      << "status " << run.status << "\n"
      << run.err << run.out;
  const auto results = ProbeResults(run.out);
  for (const auto& [action, result] : expected) {
    ASSERT_TRUE(results.count(action)) << action << " not run:\n" << run.out << run.err;
    EXPECT_EQ(results.at(action), result) << action << "\n" << run.err;
  }
  // ProtectHome=yes: an inaccessible empty directory (where the host has one).
  for (const std::string home : {"/home", "/root"}) {
    const std::string r = results.count("list:" + home) ? results.at("list:" + home) : "not run";
    if (std::filesystem::exists(home)) {
      EXPECT_TRUE(r == "EACCES" || r == "0 entries") << home << ": " << r;
    } else {
      EXPECT_EQ(r, "ENOENT") << home;
    }
  }
  // CapabilityBoundingSet= (empty), NoNewPrivileges=, seccomp, UMask=.
  EXPECT_EQ(results.count("status") ? results.at("status") : "",
            "CapInh:0000000000000000 CapPrm:0000000000000000 CapEff:0000000000000000 "
            "CapBnd:0000000000000000 CapAmb:0000000000000000 NoNewPrivs:1 Seccomp:2 Umask:0027");
  EXPECT_FALSE(std::filesystem::exists(private_name)) << "the probe's /tmp was the host's";
  EXPECT_FALSE(std::filesystem::exists(data + "/suid"));
  ::unlink(host_marker.c_str());
  // Said which settings are not reproduced, and why.
  EXPECT_NE(run.err.find("not reproduced DevicePolicy=closed: "), std::string::npos) << run.err;

  // The same probe outside the sandbox: the confined operations go through
  // (or fail otherwise), so the answers above came from the sandbox.
  const Finished control =
      RunToEnd({::craftscan::testing::HardenedProbePath(), "write:" + root + "/probe", "mmap-wx",
                "mprotect-exec", "setuid-self", "personality", "chmod-suid:" + data + "/suid",
                "unshare-user", "clone3", "socket:packet", "stat:" + host_marker + "-gone"},
               root);
  ASSERT_TRUE(WIFEXITED(control.status) && WEXITSTATUS(control.status) == 0) << control.err;
  const auto outside = ProbeResults(control.out);
  for (const std::string& action :
       {"write:" + root + "/probe", std::string("mmap-wx"), std::string("mprotect-exec"),
        std::string("setuid-self"), std::string("personality"), "chmod-suid:" + data + "/suid",
        std::string("unshare-user")}) {
    EXPECT_EQ(outside.count(action) ? outside.at(action) : "", "OK") << action << "\n"
                                                                     << control.out;
  }
  EXPECT_NE(outside.at("clone3"), "ENOSYS");
  EXPECT_NE(outside.at("socket:packet"), "EAFNOSUPPORT");
}

// The value of `key` ("Seccomp:") in /proc/<pid>/status.
std::string ProcStatus(pid_t pid, const std::string& key) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(in, line);) {
    if (line.rfind(key, 0) == 0) {
      std::string value = line.substr(key.size());
      value.erase(0, value.find_first_not_of(" \t"));
      return value;
    }
  }
  return "";
}

TEST(HardenedService, DaemonScansAndStopsCleanlyUnderTheUnitsSandbox) {
  DaemonFixture f("320x256");
  f.pipeline_extra = ", mesh: false";
  std::string error;
  ASSERT_TRUE(f.Prepare(&error)) << error;
  std::string why;
  if (SandboxUnavailable(f, &why)) GTEST_SKIP() << why;
  ASSERT_TRUE(f.notify().ok()) << f.notify().error();
  // The notify socket's folder is under the host's /tmp: kept reachable,
  // as /run/systemd/notify is under ProtectSystem=strict.
  f.launcher = Launcher(f, {std::filesystem::path(f.notify().address()).parent_path().string()});
  ASSERT_TRUE(f.Start(&error, 0, /*notify=*/true)) << error;

  const auto ready = f.notify().WaitFor("READY=1", 60s);
  ASSERT_TRUE(ready) << f.Log();
  EXPECT_EQ(ready->pid, f.pid());
  // The daemon itself is confined (not only the launcher before it).
  EXPECT_EQ(ProcStatus(f.pid(), "Seccomp:"), "2");
  EXPECT_EQ(ProcStatus(f.pid(), "NoNewPrivs:"), "1");
  EXPECT_EQ(ProcStatus(f.pid(), "CapEff:"), "0000000000000000");
  EXPECT_EQ(ProcStatus(f.pid(), "CapBnd:"), "0000000000000000");
  EXPECT_NE(std::filesystem::read_symlink("/proc/" + std::to_string(f.pid()) + "/ns/mnt"),
            std::filesystem::read_symlink("/proc/self/ns/mnt"));

  StationClient client;
  ASSERT_TRUE(client.Start(f.domain(), f.dds_config(), f.station(), &error)) << error;
  ASSERT_TRUE(client.WaitForDaemon(30s)) << f.Log();
  const auto status = client.Send("status", nullptr, kObserverToken);
  ASSERT_TRUE(status) << f.Log();
  ASSERT_EQ(status->code_name, "ok") << status->message;
  EXPECT_EQ(status->result["state"], "idle") << status->result.dump();

  const auto scan = client.Send(
      "scan", {{"object", "sandboxed box"}, {"views", 3}, {"step_deg", 120}}, kOperatorToken);
  ASSERT_TRUE(scan) << f.Log();
  ASSERT_EQ(scan->code_name, "ok") << scan->message;
  const std::string session_id = scan->result["session"], job_id = scan->result["id"];
  ASSERT_TRUE(client.WaitFor(
      [&](StationClient& c) {
        return c.last_job_id == job_id && c.last_job_state != "running" &&
               c.last_job_state != "queued";
      },
      300s))
      << f.Log();
  {
    auto lock = client.Lock();
    ASSERT_EQ(client.last_job_state, "done") << f.Log();
  }

  auto store = daemon::SessionStore::Open(f.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  const daemon::VerifyResult verify = store->Verify(session_id);
  EXPECT_TRUE(verify.IsIntact()) << (verify.problems.empty() ? "manifest" : verify.problems[0]);
  auto session = store->OpenSession(session_id, StatusInto(&error));
  ASSERT_TRUE(session) << error;
  EXPECT_EQ(session->state(), daemon::SessionState::kDone);
  EXPECT_EQ(session->DurableViews().size(), 3u);
  EXPECT_TRUE(session->manifest().outputs.count("fused.ply"));
  // UMask=0027: nothing of the session is open to other users.
  for (const auto& entry : std::filesystem::recursive_directory_iterator(session->dir())) {
    struct stat st {};
    ASSERT_EQ(::stat(entry.path().c_str(), &st), 0);
    EXPECT_EQ(st.st_mode & S_IRWXO, 0u) << entry.path() << " mode " << std::oct << st.st_mode;
  }

  const int stopped = f.Stop(SIGTERM);
  ASSERT_TRUE(WIFEXITED(stopped)) << "wait status " << stopped << "\n" << f.Log();
  EXPECT_EQ(WEXITSTATUS(stopped), 0) << f.Log();
  bool stopping = false;
  for (const NotifyMessage& m : f.notify().Drain()) stopping = stopping || m.Has("STOPPING=1");
  EXPECT_TRUE(stopping) << "no STOPPING=1 over the notify socket";
  const std::vector<std::string> refused = RefusalLines(f.Log());
  EXPECT_TRUE(refused.empty()) << refused.size()
                               << " log lines tell of refused calls, first: " << refused.front()
                               << "\n"
                               << f.Log();
}

}  // namespace
}  // namespace craftscan::testing
