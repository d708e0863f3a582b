// The site harness (site_harness.h) with real parts: network namespaces on a
// bridge as separate hosts, each in its own CPU cgroup, the real craftscand
// (simulated station) in one host and the real craftscanctl in another, over
// Cyclone DDS across the namespaces; a host cut off with nftables and healed.
#include <gtest/gtest.h>

#include <signal.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "file_util.h"
#include "process_util.h"
#include "site_harness.h"
#include "test_paths.h"
#include "wait_util.h"

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

constexpr const char* kToken = "site-observer-token-0123456789";

double Seconds(Clock::time_point since) {
  return std::chrono::duration<double>(Clock::now() - since).count();
}

// A craftscand on the simulated station (the default with no devices
// section) in a folder of its own, on `domain`.
struct StationConfig {
  std::string station, dir, config;
};

StationConfig WriteStation(const std::string& root, const std::string& station,
                           std::uint32_t domain) {
  StationConfig s{station, root + "/" + station, ""};
  std::filesystem::create_directories(s.dir + "/data");
  {
    std::ofstream tokens(s.dir + "/tokens.yaml");
    tokens << "tokens:\n  - {name: watcher, token: \"" << kToken << "\", role: observer}\n";
  }
  std::filesystem::permissions(s.dir + "/tokens.yaml", std::filesystem::perms::owner_read |
                                                           std::filesystem::perms::owner_write);
  s.config = s.dir + "/craftscand.yaml";
  std::ofstream config(s.config);
  config << "version: 1\n"
         << "station: " << station << "\n"
         << "data_dir: " << s.dir << "/data\n"
         << "dds: {domain: " << domain << "}\n"
         << "auth: {tokens_file: " << s.dir << "/tokens.yaml}\n"
         << "plugins: {path: [" << PluginDir() << "]}\n"
         << "pipeline: {threads: 1}\n";
  return s;
}

struct CtlResult {
  int exit_code = -1;  // -1: did not end in time
  std::string out, err;
  double seconds = 0;
};

std::string Describe(const CtlResult& r) {
  return "exit " + std::to_string(r.exit_code) + " after " + std::to_string(r.seconds) +
         " s\nstdout:\n" + r.out + "\nstderr:\n" + r.err;
}

// craftscanctl in `host` (its DDS configuration from CYCLONEDDS_URI, set by
// the harness): --station, --domain, --timeout, the token, then `args`.
CtlResult Ctl(SiteNetwork& site, std::size_t host, const std::string& station,
              std::uint32_t domain, double timeout_s, const std::vector<std::string>& args) {
  static int runs = 0;
  const std::string tag = site.work_dir() + "/ctl" + std::to_string(++runs);
  HostCommand command;
  command.argv = {CraftscanctlPath(), "--station", station,
                  "--domain",         std::to_string(domain),
                  "--timeout",        std::to_string(timeout_s),
                  "--token",          kToken};
  command.argv.insert(command.argv.end(), args.begin(), args.end());
  command.stdout_path = tag + ".out";
  command.stderr_path = tag + ".err";
  CtlResult r;
  ChildProcess child;
  std::string error;
  const auto start = Clock::now();
  if (!site.Start(host, command, &child, &error)) {
    r.err = error;
    return r;
  }
  // Bound: the ctl's own timeout (discovery, then the reply) and start-up.
  r.exit_code = child.Wait(std::chrono::milliseconds(static_cast<long>(timeout_s * 2000)) + 15s);
  r.seconds = Seconds(start);
  r.out = ReadFile(command.stdout_path);
  r.err = ReadFile(command.stderr_path);
  return r;
}

std::uint32_t RandomDomain() {
  std::random_device rd;
  return 1 + rd() % 200;
}

// The line of /proc/PID/cgroup for the cpu controller (v1: "N:cpu:/path").
std::string CpuCgroupOf(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/cgroup");
  for (std::string line; std::getline(in, line);) {
    const std::size_t first = line.find(':');
    const std::size_t second = line.find(':', first + 1);
    if (first == std::string::npos || second == std::string::npos) continue;
    // (built by appending: "," + std::string gives a false -Wrestrict in GCC 12)
    std::string controllers = ",";
    controllers += line.substr(first + 1, second - first - 1);
    controllers += ",";
    if (controllers.find(",cpu,") != std::string::npos) return line.substr(second + 1);
  }
  return "";
}

std::string NetnsOf(const std::string& path) {
  std::error_code ec;
  return std::filesystem::read_symlink(path, ec).string();
}

TEST(SiteNetwork, CtlReachesAStationOnAnotherHostUntilItIsCutAndAgainWhenHealed) {
  std::string why;
  auto site = SiteNetwork::Create(
      {{"station-a", 0.3}, {"client-b", 0.3}, {"worker-c", 0.5}, {"worker-d", 0}}, &why);
  if (!site) GTEST_SKIP() << "site network unavailable: " << why;
  const auto test_start = Clock::now();

  // The hosts: own namespaces (not this process's), own addresses, no route out.
  ASSERT_EQ(site->size(), 4u);
  for (std::size_t i = 0; i < site->size(); ++i) {
    EXPECT_NE(NetnsOf(site->netns_path(i)), NetnsOf("/proc/self/ns/net")) << site->name(i);
    for (std::size_t j = 0; j < i; ++j) {
      EXPECT_NE(NetnsOf(site->netns_path(i)), NetnsOf(site->netns_path(j)));
    }
    std::string out;
    EXPECT_EQ(site->Run(i, {"ip", "-4", "-o", "addr", "show", "dev", "eth0"}, &out), 0) << out;
    EXPECT_NE(out.find("inet " + site->address(i) + "/24"), std::string::npos) << out;
    EXPECT_NE(site->Run(i, {"ip", "route", "get", "1.1.1.1"}, &out), 0)
        << site->name(i) << " has a route out: " << out;
    EXPECT_NE(out.find("unreachable"), std::string::npos) << out;
  }

  // CPU shares as asked (period 100 ms; 0 = unlimited: -1).
  const std::vector<std::string> quotas = {"30000", "30000", "50000", "-1"};
  for (std::size_t i = 0; i < site->size(); ++i) {
    EXPECT_EQ(ReadFile(site->cgroup_dir(i) + "/cpu.cfs_period_us"), "100000\n") << site->name(i);
    EXPECT_EQ(ReadFile(site->cgroup_dir(i) + "/cpu.cfs_quota_us"), quotas[i] + "\n")
        << site->name(i);
  }

  // craftscand in host A.
  const std::uint32_t domain = RandomDomain();
  const StationConfig a = WriteStation(site->work_dir(), "site_a", domain);
  ChildProcess daemon;
  HostCommand start_daemon;
  start_daemon.argv = {CraftscandPath(), "--config", a.config};
  start_daemon.stdout_path = a.dir + "/craftscand.log";
  ASSERT_TRUE(site->Start(0, start_daemon, &daemon, &why)) << why;
  const auto log = [&] { return "\ncraftscand.log:\n" + ReadFile(a.dir + "/craftscand.log"); };

  // From host B: status answers once the daemon is up (discovery across
  // the bridge; craftscanctl waits up to --timeout for the station).
  CtlResult r;
  const auto up_deadline = Clock::now() + 40s;
  do {
    r = Ctl(*site, 1, a.station, domain, 10, {"status", "--json"});
    ASSERT_TRUE(daemon.Running()) << "craftscand exited (status " << daemon.status() << ")"
                                  << log();
  } while (r.exit_code != 0 && Clock::now() < up_deadline);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << log();
  nlohmann::json status = nlohmann::json::parse(r.out, nullptr, false);
  EXPECT_EQ(status.value("station", ""), a.station) << r.out;
  EXPECT_FALSE(status.value("state", "").empty()) << r.out;
  const double first_status_s = Seconds(test_start);

  // The daemon runs in host A's namespace and cgroup.
  const pid_t daemon_pid = *daemon.pid_slot();
  EXPECT_EQ(NetnsOf("/proc/" + std::to_string(daemon_pid) + "/ns/net"),
            NetnsOf(site->netns_path(0)));
  EXPECT_EQ(CpuCgroupOf(daemon_pid), site->cgroup_path(0));
  EXPECT_NE(ReadFile(site->cgroup_dir(0) + "/cgroup.procs").find(std::to_string(daemon_pid)),
            std::string::npos);

  // Host A cut off: status from B fails as unreachable (exit 5) within its
  // timeout, naming the station and the timeout it waited.
  ASSERT_TRUE(site->Cut(0, &why)) << why;
  EXPECT_TRUE(site->is_cut(0));
  constexpr double kCutTimeoutS = 3;
  r = Ctl(*site, 1, a.station, domain, kCutTimeoutS, {"status"});
  EXPECT_EQ(r.exit_code, 5) << Describe(r);
  EXPECT_NE(r.err.find("--station " + a.station), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--timeout 3"), std::string::npos) << r.err;
  EXPECT_GE(r.seconds, kCutTimeoutS * 0.9) << Describe(r);
  EXPECT_LT(r.seconds, kCutTimeoutS * 2 + 5) << Describe(r);
  const double cut_s = r.seconds;
  // (Host A itself still works: a client inside it reaches the daemon.)
  const CtlResult inside = Ctl(*site, 0, a.station, domain, 10, {"status", "--json"});
  EXPECT_EQ(inside.exit_code, 0) << Describe(inside) << log();
  EXPECT_TRUE(daemon.Running()) << log();

  // Healed: status from B answers again.
  ASSERT_TRUE(site->Heal(0, &why)) << why;
  EXPECT_FALSE(site->is_cut(0));
  const auto heal_start = Clock::now();
  r = Ctl(*site, 1, a.station, domain, 10, {"status", "--json"});
  const double heal_s = Seconds(heal_start);
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << log();
  status = nlohmann::json::parse(r.out, nullptr, false);
  EXPECT_EQ(status.value("station", ""), a.station) << r.out;

  std::printf("site: first status after %.1f s, cut status failed after %.1f s, "
              "healed status in %.1f s\n",
              first_status_s, cut_s, heal_s);
  daemon.Signal(SIGTERM);
  EXPECT_EQ(daemon.Wait(30s), 0) << log();
}

}  // namespace
}  // namespace craftscan::testing
