// Runs craftscand as a child process on the simulated station, in a fresh
// data directory with a tokens file and the sim rig's exact calibration, on
// a private DDS domain kept on loopback; with a fake NOTIFY_SOCKET.
#pragma once

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "craftscan/dds/participant.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "fake_notify_socket.h"
#include "file_util.h"
#include "test_paths.h"

extern char** environ;

namespace craftscan::testing {

inline constexpr const char* kObserverToken = "observer-token-0123456789";
inline constexpr const char* kOperatorToken = "operator-token-0123456789";
inline constexpr const char* kAdminToken = "admin-token-0123456789abc";

// Threads of the sim renderer and the pipeline in the daemons these tests
// start: 2, or CRAFTSCAN_TEST_THREADS. scripts/sanitize sets 1 under TSan:
// TBB's scheduler synchronises inside libtbb, which is not instrumented,
// so its worker threads make TSan report races that are not there.
inline int TestThreads() {
  const char* value = std::getenv("CRAFTSCAN_TEST_THREADS");
  const int n = value != nullptr ? std::atoi(value) : 0;
  return n >= 1 ? n : 2;
}

// The sim camera's image size for a daemon test that asks for `wanted`
// ("WxH"): `wanted`, or CRAFTSCAN_TEST_IMAGE_SIZE when that is set and has
// fewer pixels. scripts/sanitize sets it (320x256) under ASan: the daemon's
// own code -- jobs, sessions, DDS, devices -- runs the same at any size,
// while the instrumented matcher and sim renderer take minutes a view at
// 640x512 there.
inline std::string TestImageSize(const std::string& wanted) {
  const auto pixels = [](const std::string& size) {
    int w = 0, h = 0;
    return std::sscanf(size.c_str(), "%dx%d", &w, &h) == 2 ? static_cast<long>(w) * h : -1L;
  };
  const char* cap = std::getenv("CRAFTSCAN_TEST_IMAGE_SIZE");
  if (cap == nullptr || pixels(cap) <= 0) return wanted;
  return pixels(cap) < pixels(wanted) ? std::string(cap) : wanted;
}

class DaemonFixture {
 public:
  // image_size of the sim camera, e.g. "1280x1024" (TestImageSize may make
  // it smaller). extra_sim: more sim driver keys (", key: value…").
  explicit DaemonFixture(std::string image_size = "1280x1024", std::string extra_sim = "")
      : image_size_(TestImageSize(image_size)), extra_sim_(std::move(extra_sim)) {
    std::random_device rd;
    domain_ = 1 + rd() % 200;
    station_ = "t";  // (not "t" + ...: GCC 12 -Wrestrict false positive when inlined)
    station_ += std::to_string(rd() % 1000000);
    char dir[] = "/tmp/craftscand-test-XXXXXX";
    root_ = ::mkdtemp(dir);
    std::filesystem::create_directories(root_ + "/data/calibration");
  }
  ~DaemonFixture() {
    Stop(SIGKILL);
    std::error_code ignored;
    std::filesystem::remove_all(root_, ignored);
  }

  const std::string& root() const { return root_; }
  std::string data_dir() const { return root_ + "/data"; }
  const std::string& station() const { return station_; }
  std::uint32_t domain() const { return domain_; }
  std::string dds_config() const {
    return dds::ConfigFileUri(::craftscan::testing::CycloneDdsXml()) + "," +
           dds::LoopbackOnlyConfigXml();
  }
  FakeNotifySocket& notify() { return notify_; }
  // Puts the daemon on `domain` instead of its random one (before Prepare),
  // e.g. several daemons of one site, or the test's own domain.
  void set_domain(std::uint32_t domain) { domain_ = domain; }

  // Appended inside the config's pipeline mapping by Prepare, e.g.
  // ", mesh: false" for tests that need no mesh.
  std::string pipeline_extra;
  // Appended inside the config's scan mapping, e.g. ", exposure_bracket: [8]".
  std::string scan_extra;
  // False: the pipeline keeps the daemon's default working volume (what a
  // new station starts with) instead of the one fitted to the carved box.
  bool box_volume = true;
  // When not empty, the config's calibration mapping, e.g. "{guided: true}".
  std::string calibration_yaml;
  // When not empty, replaces the devices Prepare writes (the sim station):
  // the YAML lines under "devices:", e.g. "  camera: {driver: aravis, ...}\n".
  std::string devices_yaml;
  // When not empty, craftscand is started through this command prefix (a
  // launcher that execs the rest, e.g. tests/tools/hardened-run and its
  // options), so pid() stays the daemon's.
  std::vector<std::string> launcher;
  // More top-level config, appended as is (e.g. "site: s1\nreconstruction: {mode: remote}\n").
  std::string extra_yaml;

  // Writes tokens, config and the exact sim calibration. False with *error.
  bool Prepare(std::string* error, bool with_calibration = true) {
    {
      std::ofstream tokens(root_ + "/tokens.yaml");
      tokens << "tokens:\n"
             << "  - {name: watcher, token: \"" << kObserverToken << "\", role: observer}\n"
             << "  - {name: tech, token: \"" << kOperatorToken << "\", role: operator}\n"
             << "  - {name: boss, token: \"" << kAdminToken << "\", role: admin}\n";
    }
    ::chmod((root_ + "/tokens.yaml").c_str(), 0600);
    std::ofstream config(root_ + "/craftscand.yaml");
    config << "version: 1\n"
           << "station: " << station_ << "\n"
           << "data_dir: " << data_dir() << "\n"
           << "log_level: debug\n"
           << "dds: {domain: " << domain_ << "}\n"
           << "auth: {tokens_file: " << root_ << "/tokens.yaml}\n"
           << "plugins: {path: [" << ::craftscan::testing::PluginDir() << "]}\n"
           << "devices:\n";
    if (devices_yaml.empty()) {
      config << "  camera: {driver: sim, config: {image_size: " << image_size_
             << ", threads: " << TestThreads() << extra_sim_ << "}}\n"
             << "  turntable: {driver: sim, config: {image_size: " << image_size_
             << ", threads: " << TestThreads() << extra_sim_ << "}}\n";
    } else {
      config << devices_yaml;
    }
    config << "scan: {settle_ms: 0" << scan_extra
           << "}\n"
           // The carved box (80 x 60 x 50 mm) with a margin: the band the
           // matcher searches follows from this volume.
           << "pipeline: {threads: "
           << TestThreads()
           // (and the band of that volume alone: the platter beyond it
           // is not searched, as the tests were timed with).
           << (box_volume ? ", volume_radius_mm: 65, volume_max_height_mm: 70, platter_radius_mm: 0"
                          : "")
           << pipeline_extra << "}\n";
    if (!calibration_yaml.empty()) config << "calibration: " << calibration_yaml << "\n";
    config << extra_yaml;
    config.close();
    if (!with_calibration) return true;
    sim::SimDriverOptions options;
    if (!sim::SimDriverOptionsFromConfig({{"image_size", image_size_}}, &options, error))
      return false;
    auto station = sim::SimStation::Create(sim::SimRigOptions(options), error);
    if (!station) return false;
    return SaveCalibration(data_dir() + "/calibration/current.yaml", station->calibration(), error);
  }

  // Starts craftscand; with watchdog_usec > 0 it gets WATCHDOG_USEC. With
  // `notify` it gets NOTIFY_SOCKET: the test must then keep reading notify()
  // (a full datagram queue blocks the sender, as with a real manager).
  bool Start(std::string* error, long watchdog_usec = 0, bool notify = false) {
    std::vector<std::string> env;
    for (char** e = environ; *e; ++e) {
      const std::string v = *e;
      if (v.rfind("NOTIFY_SOCKET=", 0) == 0 || v.rfind("CYCLONEDDS_URI=", 0) == 0 ||
          v.rfind("WATCHDOG_", 0) == 0)
        continue;
      env.push_back(v);
    }
    if (notify) env.push_back("NOTIFY_SOCKET=" + notify_.address());
    env.push_back("CYCLONEDDS_URI=" + dds_config());
    if (watchdog_usec > 0) env.push_back("WATCHDOG_USEC=" + std::to_string(watchdog_usec));
    std::vector<char*> envp;
    for (std::string& v : env) envp.push_back(v.data());
    envp.push_back(nullptr);
    const std::string config = root_ + "/craftscand.yaml";
    const std::string log = root_ + "/craftscand.log";
    std::vector<std::string> args = launcher;
    for (const char* a : {::craftscan::testing::CraftscandPath(), "--config"}) args.push_back(a);
    args.push_back(config);
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, 2, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
    const int r = posix_spawn(&pid_, args[0].c_str(), &actions, nullptr, argv.data(), envp.data());
    posix_spawn_file_actions_destroy(&actions);
    if (r != 0) {
      *error = std::string("posix_spawn craftscand: ") + std::strerror(r);
      pid_ = -1;
      return false;
    }
    return true;
  }

  pid_t pid() const { return pid_; }

  // Sends `signal` and waits for the exit; returns the wait status (-1 if
  // not running or it did not exit within the timeout, then it is killed).
  int Stop(int signal, std::chrono::seconds timeout = std::chrono::seconds(60)) {
    if (pid_ <= 0) return -1;
    ::kill(pid_, signal);
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    int status = -1;
    while (std::chrono::steady_clock::now() < deadline) {
      const pid_t r = ::waitpid(pid_, &status, WNOHANG);
      if (r == pid_) {
        pid_ = -1;
        return status;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
    return -1;
  }

  std::string Log() const { return ReadFile(root_ + "/craftscand.log"); }

 private:
  std::string image_size_, extra_sim_;
  std::uint32_t domain_ = 0;
  std::string station_;
  std::string root_;
  FakeNotifySocket notify_;
  pid_t pid_ = -1;
};

}  // namespace craftscan::testing
