// The site harness (site_harness.h) with real parts: network namespaces on a
// bridge as separate hosts, each in its own CPU cgroup, the real craftscand
// (simulated station) in one host and the real craftscanctl in another, over
// Cyclone DDS across the namespaces; a host cut off with nftables and healed.
#include <gtest/gtest.h>

#include <signal.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
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
CtlResult Ctl(SiteNetwork& site, std::size_t host, const std::string& station, std::uint32_t domain,
              double timeout_s, const std::vector<std::string>& args) {
  static int runs = 0;
  const std::string tag = site.work_dir() + "/ctl" + std::to_string(++runs);
  HostCommand command;
  command.argv = {CraftscanctlPath(),
                  "--station",
                  station,
                  "--domain",
                  std::to_string(domain),
                  "--timeout",
                  std::to_string(timeout_s),
                  "--token",
                  kToken};
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

// craftscand started in `host` on the config `s` (its log in s.dir).
void StartDaemon(SiteNetwork& site, std::size_t host, const StationConfig& s, ChildProcess* daemon,
                 std::string* error) {
  HostCommand command;
  command.argv = {CraftscandPath(), "--config", s.config};
  command.stdout_path = s.dir + "/craftscand.log";
  ASSERT_TRUE(site.Start(host, command, daemon, error)) << *error;
}

std::string DaemonLog(const StationConfig& s) {
  return "\n" + s.station + " craftscand.log:\n" + ReadFile(s.dir + "/craftscand.log");
}

// `status --json` from `host` until it answers (the daemon starting up) or
// 40 s have passed; fails the test if the daemon exits meanwhile.
CtlResult WaitForStatus(SiteNetwork& site, std::size_t host, const StationConfig& s,
                        std::uint32_t domain, ChildProcess& daemon) {
  CtlResult r;
  const auto deadline = Clock::now() + 40s;
  do {
    r = Ctl(site, host, s.station, domain, 10, {"status", "--json"});
    EXPECT_TRUE(daemon.Running()) << "craftscand exited (wait status " << daemon.status() << ")"
                                  << DaemonLog(s);
  } while (r.exit_code != 0 && daemon.Running() && Clock::now() < deadline);
  return r;
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
  StartDaemon(*site, 0, a, &daemon, &why);
  const auto log = [&] { return DaemonLog(a); };

  // From host B: status answers once the daemon is up (discovery across
  // the bridge; craftscanctl waits up to --timeout for the station).
  CtlResult r = WaitForStatus(*site, 1, a, domain, daemon);
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

  std::printf(
      "site: first status after %.2f s, cut status failed after %.2f s, "
      "healed status in %.2f s\n",
      first_status_s, cut_s, heal_s);
  daemon.Signal(SIGTERM);
  EXPECT_EQ(daemon.Wait(30s), 0) << log();
}

// Three stations in three hosts and the client in a fourth: each answers;
// with one cut off, the other two still do.
TEST(SiteNetwork, ThreeStationsOnThreeHostsAnswerAClientOnAFourth) {
  std::string why;
  auto site = SiteNetwork::Create(
      {{"station-1", 0.3}, {"station-2", 0.3}, {"station-3", 0.3}, {"client", 0.3}}, &why);
  if (!site) GTEST_SKIP() << "site network unavailable: " << why;
  const auto test_start = Clock::now();
  const std::uint32_t domain = RandomDomain();
  std::vector<StationConfig> stations;
  std::vector<ChildProcess> daemons(3);
  for (std::size_t i = 0; i < 3; ++i) {
    stations.push_back(WriteStation(site->work_dir(), "site_" + std::to_string(i + 1), domain));
    StartDaemon(*site, i, stations[i], &daemons[i], &why);
  }
  for (std::size_t i = 0; i < 3; ++i) {
    const CtlResult r = WaitForStatus(*site, 3, stations[i], domain, daemons[i]);
    ASSERT_EQ(r.exit_code, 0) << Describe(r) << DaemonLog(stations[i]);
    const nlohmann::json status = nlohmann::json::parse(r.out, nullptr, false);
    EXPECT_EQ(status.value("station", ""), stations[i].station) << r.out;
  }
  const double all_up_s = Seconds(test_start);

  ASSERT_TRUE(site->Cut(1, &why)) << why;
  for (std::size_t i = 0; i < 3; ++i) {
    const CtlResult r = Ctl(*site, 3, stations[i].station, domain, 3, {"status"});
    EXPECT_EQ(r.exit_code, i == 1 ? 5 : 0) << stations[i].station << " " << Describe(r);
  }
  ASSERT_TRUE(site->Heal(1, &why)) << why;
  const CtlResult r = Ctl(*site, 3, stations[1].station, domain, 10, {"status"});
  EXPECT_EQ(r.exit_code, 0) << Describe(r) << DaemonLog(stations[1]);
  std::printf("site: 3 stations answered after %.2f s\n", all_up_s);
}

// Launcher() for helpers that spawn by themselves, and a teardown that
// leaves nothing: processes, cgroups, work folder, the thread's namespace.
TEST(SiteNetwork, LauncherAndTeardownLeaveNothingBehind) {
  const std::string netns_before = NetnsOf("/proc/thread-self/ns/net");
  std::string why, site_cgroup, work_dir;
  ChildProcess sleeper;
  {
    auto site = SiteNetwork::Create({{"h0", 0.25}, {"h1", 0}}, &why);
    if (!site) GTEST_SKIP() << "site network unavailable: " << why;
    EXPECT_NE(NetnsOf("/proc/thread-self/ns/net"), netns_before) << "not in a private namespace";
    site_cgroup = std::filesystem::path(site->cgroup_dir(0)).parent_path().string();
    work_dir = site->work_dir();
    EXPECT_TRUE(std::filesystem::is_directory(site_cgroup));
    EXPECT_EQ(ReadFile(site->cgroup_dir(0) + "/cpu.cfs_quota_us"), "25000\n");

    // The quota holds: a busy loop in h0 for 1 s is throttled.
    std::string out;
    EXPECT_EQ(site->Run(0, {"timeout", "1", "sh", "-c", "while :; do :; done"}, &out), 124) << out;
    const std::string stat = ReadFile(site->cgroup_dir(0) + "/cpu.stat");
    long throttled = 0;
    const std::size_t at = stat.find("nr_throttled ");
    if (at != std::string::npos) throttled = std::atol(stat.c_str() + at + 13);
    EXPECT_GT(throttled, 3) << stat;

    HostCommand sleep;
    sleep.argv = {"sleep", "600"};
    ASSERT_TRUE(site->Start(0, sleep, &sleeper, &why)) << why;

    std::vector<std::string> argv = site->Launcher(1);
    for (const char* a : {"/bin/sh", "-c",
                          "cat /proc/self/cgroup; readlink /proc/self/ns/net; "
                          "echo \"uri=$CYCLONEDDS_URI\""}) {
      argv.push_back(a);
    }
    ChildProcess launched;
    SpawnOptions options;
    options.stdout_path = work_dir + "/launched.out";
    options.stderr_to_stdout = true;
    ASSERT_TRUE(Spawn(argv, options, &launched));
    EXPECT_EQ(launched.Wait(10s), 0) << ReadFile(options.stdout_path);
    out = ReadFile(options.stdout_path);
    EXPECT_NE(out.find(":cpu:" + site->cgroup_path(1) + "\n"), std::string::npos) << out;
    EXPECT_NE(out.find(NetnsOf(site->netns_path(1)) + "\n"), std::string::npos) << out;
    EXPECT_NE(out.find("uri=" + site->DdsConfig(1) + "\n"), std::string::npos) << out;

    // Cut and heal are visible as the nftables table in the host only.
    ASSERT_TRUE(site->Cut(0, &why)) << why;
    std::string rules;
    EXPECT_EQ(site->Run(0, {"nft", "list", "tables"}, &rules), 0) << rules;
    EXPECT_NE(rules.find("table inet cut"), std::string::npos) << rules;
    EXPECT_EQ(site->Run(1, {"nft", "list", "tables"}, &rules), 0) << rules;
    EXPECT_EQ(rules.find("table inet cut"), std::string::npos) << rules;
    ASSERT_TRUE(site->Heal(0, &why)) << why;
    EXPECT_EQ(site->Run(0, {"nft", "list", "tables"}, &rules), 0) << rules;
    EXPECT_EQ(rules.find("table inet cut"), std::string::npos) << rules;
    EXPECT_TRUE(sleeper.Running());
  }
  EXPECT_EQ(sleeper.Wait(5s), 128 + SIGKILL) << "the host's process outlived the site";
  EXPECT_EQ(NetnsOf("/proc/thread-self/ns/net"), netns_before);
  EXPECT_FALSE(std::filesystem::exists(site_cgroup)) << site_cgroup;
  EXPECT_FALSE(std::filesystem::exists(work_dir)) << work_dir;
}

}  // namespace
}  // namespace craftscan::testing
