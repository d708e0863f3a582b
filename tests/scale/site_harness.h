// Several "hosts" on this one machine, for tests of a site (stations and
// workers on different hosts talking over Cyclone DDS).
//
// SiteNetwork::Create moves the calling thread (the test's main thread) into
// a private network namespace of its own, so nothing it makes touches the
// machine's real network, and builds there:
//
//   bridge "site-br" ── veth "site-h<i>" ═══ "eth0" 10.77.0.<10+i>/24 in host i
//
// Each host is a network namespace held by a sleeping child process (its
// path: /proc/<holder>/ns/net) with `lo` and `eth0` up and no default route
// (nothing leaves the bridge), and a CPU cgroup (cgroup v1,
// /sys/fs/cgroup/cpu/craftscan-site-<test pid>/<host name>/) with
// cpu.cfs_quota_us = cores × cpu.cfs_period_us (100 ms), or unlimited.
// Processes started in a host enter its namespace and cgroup before exec and
// get CYCLONEDDS_URI = the shipped systemd/cyclonedds.xml plus a fragment
// that binds Cyclone to the host's address with unicast discovery among every
// host's address (DdsConfig). Cut() drops all of a host's traffic on eth0
// inside its namespace with nftables (its own loopback keeps working, as on a
// machine whose cable was pulled); Heal() removes the rule.
//
// The destructor kills every process left in the hosts' cgroups and the
// holders (the namespaces and veth pairs go with them), returns the thread
// to its original network namespace (the private one, with the bridge, then
// has no member and goes too) and removes the cgroups and its work folder.
//
// Needs real root (netns, veth, cgroup writes), `ip` and `nft`; Create says
// why not otherwise, for GTEST_SKIP. Not thread-safe: one test thread.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <vector>

#include "process_util.h"

namespace craftscan::testing {

// One host of a site.
struct SiteHostSpec {
  std::string name;        // its cgroup's folder: letters, digits, '-', '_'
  double cpu_cores = 0.0;  // CPU share in cores (0.3 = 30 ms per 100 ms); 0 = unlimited
};

// What to start in a host.
struct HostCommand {
  std::vector<std::string> argv;  // argv[0]: a path, or a name looked up on PATH
  std::vector<std::string> env;   // "NAME=value", added after CYCLONEDDS_URI (may override it)
  std::string stdout_path;        // "" = /dev/null; created or truncated
  std::string stderr_path;        // "" = into stdout's file
};

class SiteNetwork {
 public:
  // The site, or null with *why (why the test cannot run here: not root, no
  // cgroup v1 cpu controller, a tool missing, a command that failed and its
  // output). At most 200 hosts.
  static std::unique_ptr<SiteNetwork> Create(const std::vector<SiteHostSpec>& hosts,
                                             std::string* why);
  ~SiteNetwork();
  SiteNetwork(const SiteNetwork&) = delete;
  SiteNetwork& operator=(const SiteNetwork&) = delete;

  std::size_t size() const { return hosts_.size(); }
  const std::string& name(std::size_t host) const { return hosts_.at(host).spec.name; }
  // "10.77.0.<10+host>"
  std::string address(std::size_t host) const;
  // "/proc/<holder pid>/ns/net" (for nsenter --net=...)
  std::string netns_path(std::size_t host) const;
  // /sys/fs/cgroup/cpu/craftscan-site-<pid>/<name>
  std::string cgroup_dir(std::size_t host) const;
  // The "cpu:" line's path processes of this host show in /proc/PID/cgroup:
  // "/craftscan-site-<pid>/<name>"
  std::string cgroup_path(std::size_t host) const;
  // The CYCLONEDDS_URI for a process in `host`: ConfigFileUri(shipped
  // cyclonedds.xml) + "," + HostDdsXml(host).
  std::string DdsConfig(std::size_t host) const;
  // The fragment alone: the host's interface by address, no multicast,
  // Peers = every host's address, ParticipantIndex auto (up to 20 per host).
  std::string HostDdsXml(std::size_t host) const;
  // A folder removed at teardown, for configs and logs.
  const std::string& work_dir() const { return work_dir_; }

  // Starts `command` in `host` (its network namespace and cgroup; killed if
  // the test process dies). The environment is this process's minus
  // CYCLONEDDS_URI and NOTIFY_SOCKET, plus CYCLONEDDS_URI=DdsConfig(host),
  // plus command.env. False with *error if it could not be forked (a failing
  // exec shows as exit 127 with the reason in its stderr file).
  bool Start(std::size_t host, const HostCommand& command, ChildProcess* child, std::string* error);
  // Runs `argv` in `host` to its end: its exit code (128+signal when killed
  // by one), or -1 if it did not end within `timeout` (then it is killed).
  // *output (may be null): its stdout and stderr.
  int Run(std::size_t host, const std::vector<std::string>& argv, std::string* output,
          std::chrono::milliseconds timeout = std::chrono::seconds(10));

  // An argv prefix that runs the rest of a command line in `host` when it
  // is spawned from this thread by other helpers (DaemonFixture::launcher,
  // Spawn): nsenter into its namespace, then a shell that moves itself into
  // the host's cgroup and execs `env CYCLONEDDS_URI=DdsConfig(host) rest...`
  // (so the spawned pid stays the program's). Unlike Start, the process is
  // not killed with the test process (teardown still kills it).
  std::vector<std::string> Launcher(std::size_t host) const;

  // Drops every packet to and from the host's eth0 (an nftables table "cut"
  // in its namespace). False with *error (nft's output) if nft failed.
  bool Cut(std::size_t host, std::string* error);
  // Removes the table again.
  bool Heal(std::size_t host, std::string* error);
  bool is_cut(std::size_t host) const { return hosts_.at(host).cut; }

 private:
  struct Host {
    SiteHostSpec spec;
    pid_t holder = -1;  // the sleeping process holding the namespace
    int netns_fd = -1;  // O_CLOEXEC, for setns in children
    bool cut = false;
  };
  SiteNetwork() = default;
  bool Build(const std::vector<SiteHostSpec>& hosts, std::string* why);
  // Runs argv in the parent namespace (netns_fd -1) or in a host.
  int RunIn(int netns_fd, const std::string& cgroup_procs, const std::vector<std::string>& argv,
            std::string* output, std::chrono::milliseconds timeout);
  void Teardown();

  std::vector<Host> hosts_;
  int original_netns_fd_ = -1;  // the thread's namespace before Create
  bool in_private_netns_ = false;
  std::string site_cgroup_;  // /sys/fs/cgroup/cpu/craftscan-site-<pid>
  std::string work_dir_;
  int runs_ = 0;
};

}  // namespace craftscan::testing
