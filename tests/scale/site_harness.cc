#include "site_harness.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "craftscan/dds/participant.h"
#include "file_util.h"
#include "test_paths.h"

extern char** environ;

namespace craftscan::testing {
namespace {

constexpr const char* kCgroupCpuRoot = "/sys/fs/cgroup/cpu";
constexpr const char* kBridge = "site-br";
constexpr long kCfsPeriodUs = 100000;

std::string Errno(const std::string& what) { return what + ": " + std::strerror(errno); }

// argv[0] as a path: itself if it has a '/', else the first executable of
// that name on PATH (then /usr/sbin, /sbin: ip and nft live there). "" if none.
std::string ResolveProgram(const std::string& name) {
  if (name.find('/') != std::string::npos) return name;
  const char* path = std::getenv("PATH");
  std::string dirs = path != nullptr ? path : "";
  dirs += ":/usr/local/sbin:/usr/sbin:/sbin:/usr/bin:/bin";
  std::stringstream stream(dirs);
  std::string dir;
  while (std::getline(stream, dir, ':')) {
    if (dir.empty()) continue;
    const std::string candidate = dir + "/" + name;
    if (::access(candidate.c_str(), X_OK) == 0) return candidate;
  }
  return "";
}

// Writes `value` to a cgroup file. False with *why.
bool WriteFile(const std::string& path, const std::string& value, std::string* why) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
  if (fd < 0) {
    *why = Errno("open " + path);
    return false;
  }
  const ssize_t n = ::write(fd, value.data(), value.size());
  const int saved = errno;
  ::close(fd);
  if (n != static_cast<ssize_t>(value.size())) {
    errno = saved;
    *why = Errno("write '" + value + "' to " + path);
    return false;
  }
  return true;
}

// Async-signal-safe helpers for the forked child (no allocation).
void ChildSay(const char* a, const char* b) {
  const auto put = [](const char* s) {
    if (s != nullptr && ::write(STDERR_FILENO, s, std::strlen(s)) < 0) return;
  };
  put("site harness: ");
  put(a);
  put(b);
  put(": ");
  put(std::strerror(errno));
  put("\n");
}

void ChildRedirect(const char* path, int target, int flags) {
  const int fd = ::open(path, flags, 0644);
  if (fd < 0) {
    ChildSay("cannot open ", path);
    ::_exit(126);
  }
  if (fd != target) {
    ::dup2(fd, target);
    ::close(fd);
  }
}

// Forks a child that enters `netns_fd` (-1: stays) and the cgroup whose
// cgroup.procs is `cgroup_procs` ("": stays), then execs. Everything the
// child touches is prepared here, before fork (the test process may have
// threads). *pid = the child, or -1 with *error.
bool ForkExec(int netns_fd, const std::string& cgroup_procs, const std::string& program,
              const std::vector<std::string>& argv, const std::vector<std::string>& env,
              const std::string& stdout_path, const std::string& stderr_path, pid_t* pid,
              std::string* error) {
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  std::vector<char*> envp;
  for (const std::string& e : env) envp.push_back(const_cast<char*>(e.c_str()));
  envp.push_back(nullptr);
  const char* out = stdout_path.empty() ? "/dev/null" : stdout_path.c_str();
  const char* err = stderr_path.empty() ? nullptr : stderr_path.c_str();
  const char* procs = cgroup_procs.empty() ? nullptr : cgroup_procs.c_str();
  const pid_t parent = ::getpid();

  const pid_t child = ::fork();
  if (child < 0) {
    *error = Errno("fork");
    *pid = -1;
    return false;
  }
  if (child == 0) {
    // Dies with the test process (a crashed test leaves no daemon behind).
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    if (::getppid() != parent) ::_exit(126);
    ChildRedirect("/dev/null", STDIN_FILENO, O_RDONLY);
    ChildRedirect(out, STDOUT_FILENO, O_WRONLY | O_CREAT | O_TRUNC);
    if (err != nullptr) {
      ChildRedirect(err, STDERR_FILENO, O_WRONLY | O_CREAT | O_TRUNC);
    } else {
      ::dup2(STDOUT_FILENO, STDERR_FILENO);
    }
    if (procs != nullptr) {
      char digits[24];
      int n = 0;
      char reversed[24];
      for (long v = ::getpid(); v > 0; v /= 10) reversed[n++] = static_cast<char>('0' + v % 10);
      for (int i = 0; i < n; ++i) digits[i] = reversed[n - 1 - i];
      const int fd = ::open(procs, O_WRONLY);
      if (fd < 0 || ::write(fd, digits, static_cast<size_t>(n)) != n) {
        ChildSay("cannot join the cgroup ", procs);
        ::_exit(126);
      }
      ::close(fd);
    }
    if (netns_fd >= 0 && ::setns(netns_fd, CLONE_NEWNET) != 0) {
      ChildSay("setns", "");
      ::_exit(126);
    }
    ::execve(program.c_str(), args.data(), envp.data());
    ChildSay("cannot execute ", program.c_str());
    ::_exit(127);
  }
  *pid = child;
  return true;
}

// A child that makes a network namespace of its own and sleeps. *pid, or
// false with *why.
bool StartHolder(pid_t* pid, std::string* why) {
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) {
    *why = Errno("pipe");
    return false;
  }
  const pid_t parent = ::getpid();
  const pid_t child = ::fork();
  if (child < 0) {
    *why = Errno("fork");
    ::close(fds[0]);
    ::close(fds[1]);
    return false;
  }
  if (child == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGKILL);
    ::close(fds[0]);
    char answer = 'K';
    if (::getppid() != parent || ::unshare(CLONE_NEWNET) != 0) answer = 'E';
    if (::write(fds[1], &answer, 1) != 1 || answer != 'K') ::_exit(1);
    ::close(fds[1]);
    for (;;) ::pause();
  }
  ::close(fds[1]);
  pollfd p{fds[0], POLLIN, 0};
  char answer = 0;
  const bool ready = ::poll(&p, 1, 5000) == 1 && ::read(fds[0], &answer, 1) == 1 && answer == 'K';
  ::close(fds[0]);
  if (!ready) {
    ::kill(child, SIGKILL);
    ::waitpid(child, nullptr, 0);
    *why = "the namespace holder could not unshare(CLONE_NEWNET)";
    return false;
  }
  *pid = child;
  return true;
}

// Removes the cgroups of sites whose test process is gone (killed before its
// destructor ran: its hosts' processes died with it, PR_SET_PDEATHSIG, but
// the folders stay): kills what is left in them, then rmdir.
void RemoveStaleSiteCgroups() {
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator(kCgroupCpuRoot, ec)) {
    const std::string name = entry.path().filename().string();
    const std::string prefix = "craftscan-site-";
    if (name.rfind(prefix, 0) != 0 || !entry.is_directory(ec)) continue;
    const std::string pid = name.substr(prefix.size());
    if (pid.empty() || pid.find_first_not_of("0123456789") != std::string::npos) continue;
    if (std::filesystem::exists("/proc/" + pid, ec)) continue;  // (a live site, or pid reuse)
    for (const auto& host : std::filesystem::directory_iterator(entry.path(), ec)) {
      if (!host.is_directory(ec)) continue;
      std::ifstream procs(host.path() / "cgroup.procs");
      for (pid_t p; procs >> p;) ::kill(p, SIGKILL);
      ::rmdir(host.path().c_str());
    }
    ::rmdir(entry.path().c_str());
  }
}

}  // namespace

std::unique_ptr<SiteNetwork> SiteNetwork::Create(const std::vector<SiteHostSpec>& hosts,
                                                 std::string* why) {
  std::unique_ptr<SiteNetwork> site(new SiteNetwork());
  if (!site->Build(hosts, why)) return nullptr;  // the destructor removes what was made
  return site;
}

SiteNetwork::~SiteNetwork() { Teardown(); }

std::string SiteNetwork::address(std::size_t host) const {
  return "10.77.0." + std::to_string(10 + host);
}

std::string SiteNetwork::netns_path(std::size_t host) const {
  return "/proc/" + std::to_string(hosts_.at(host).holder) + "/ns/net";
}

std::string SiteNetwork::cgroup_dir(std::size_t host) const {
  return site_cgroup_ + "/" + hosts_.at(host).spec.name;
}

std::string SiteNetwork::cgroup_path(std::size_t host) const {
  return cgroup_dir(host).substr(std::strlen(kCgroupCpuRoot));
}

std::string SiteNetwork::HostDdsXml(std::size_t host) const {
  std::string xml = "<CycloneDDS><Domain><General><Interfaces><NetworkInterface address=\"";
  xml += address(host);
  xml +=
      "\"/></Interfaces><AllowMulticast>false</AllowMulticast></General>"
      "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
      "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex><Peers>";
  for (std::size_t i = 0; i < hosts_.size(); ++i) {
    xml += "<Peer address=\"";
    xml += address(i);
    xml += "\"/>";
  }
  xml += "</Peers></Discovery></Domain></CycloneDDS>";
  return xml;
}

std::string SiteNetwork::DdsConfig(std::size_t host) const {
  return dds::ConfigFileUri(CycloneDdsXml()) + "," + HostDdsXml(host);
}

bool SiteNetwork::Build(const std::vector<SiteHostSpec>& hosts, std::string* why) {
  if (::geteuid() != 0) {
    *why = "needs real root (network namespaces, veth pairs, cgroup writes)";
    return false;
  }
  if (hosts.empty() || hosts.size() > 200) {
    *why = "1 to 200 hosts";
    return false;
  }
  for (const SiteHostSpec& spec : hosts) {
    if (spec.name.empty() || spec.name.find_first_not_of(
                                 "abcdefghijklmnopqrstuvwxyz"
                                 "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789-_") != std::string::npos) {
      *why = "host name '" + spec.name + "': letters, digits, '-' and '_' only";
      return false;
    }
    if (!(spec.cpu_cores >= 0.0) || spec.cpu_cores > 1024.0) {
      *why = "host " + spec.name + ": cpu_cores must be >= 0";
      return false;
    }
  }
  if (::access((std::string(kCgroupCpuRoot) + "/cpu.cfs_quota_us").c_str(), W_OK) != 0) {
    *why = std::string("no writable cgroup v1 cpu controller at ") + kCgroupCpuRoot;
    return false;
  }
  for (const char* tool : {"ip", "nft", "nsenter"}) {
    if (ResolveProgram(tool).empty()) {
      *why = std::string("'") + tool + "' is not installed (scripts/setup installs it)";
      return false;
    }
  }

  // The private parent namespace: only this thread moves (and the children
  // it forks from now on).
  original_netns_fd_ = ::open("/proc/thread-self/ns/net", O_RDONLY | O_CLOEXEC);
  if (original_netns_fd_ < 0) {
    *why = Errno("open /proc/thread-self/ns/net");
    return false;
  }
  if (::unshare(CLONE_NEWNET) != 0) {
    *why = Errno("unshare(CLONE_NEWNET)");
    return false;
  }
  in_private_netns_ = true;

  std::string pattern = (std::filesystem::temp_directory_path() / "craftscan-site-XXXXXX").string();
  if (::mkdtemp(pattern.data()) == nullptr) {
    *why = Errno("mkdtemp " + pattern);
    return false;
  }
  work_dir_ = pattern;

  // Cgroups: the site's folder, then one per host.
  RemoveStaleSiteCgroups();
  const std::string site_cgroup =
      std::string(kCgroupCpuRoot) + "/craftscan-site-" + std::to_string(::getpid());
  if (::mkdir(site_cgroup.c_str(), 0755) != 0) {
    *why = Errno("mkdir " + site_cgroup);
    return false;
  }
  site_cgroup_ = site_cgroup;

  for (const SiteHostSpec& spec : hosts) {
    hosts_.push_back(Host{spec});
    const std::string dir = cgroup_dir(hosts_.size() - 1);
    if (::mkdir(dir.c_str(), 0755) != 0) {
      *why = Errno("mkdir " + dir);
      hosts_.back().spec.name.clear();  // not made: nothing to remove
      return false;
    }
    const long quota =
        spec.cpu_cores > 0 ? std::max(1000L, std::lround(spec.cpu_cores * kCfsPeriodUs)) : -1;
    if (!WriteFile(dir + "/cpu.cfs_period_us", std::to_string(kCfsPeriodUs), why) ||
        !WriteFile(dir + "/cpu.cfs_quota_us", std::to_string(quota), why)) {
      return false;
    }
  }

  // The bridge in the private parent namespace, then each host on it.
  std::string output;
  const auto parent = [&](const std::vector<std::string>& argv) {
    if (RunIn(-1, "", argv, &output, std::chrono::seconds(10)) == 0) return true;
    std::string joined;
    for (const std::string& a : argv) joined += " " + a;
    *why = "failed:" + joined + ": " + output;
    return false;
  };
  if (!parent({"ip", "link", "set", "lo", "up"}) ||
      !parent({"ip", "link", "add", kBridge, "type", "bridge"}) ||
      !parent({"ip", "link", "set", kBridge, "up"})) {
    return false;
  }
  for (std::size_t i = 0; i < hosts_.size(); ++i) {
    Host& host = hosts_[i];
    if (!StartHolder(&host.holder, why)) return false;
    host.netns_fd = ::open(netns_path(i).c_str(), O_RDONLY | O_CLOEXEC);
    if (host.netns_fd < 0) {
      *why = Errno("open " + netns_path(i));
      return false;
    }
    const std::string veth = "site-h" + std::to_string(i);
    const auto inside = [&](const std::vector<std::string>& argv) {
      if (RunIn(host.netns_fd, "", argv, &output, std::chrono::seconds(10)) == 0) return true;
      std::string joined;
      for (const std::string& a : argv) joined += " " + a;
      *why = "failed in host " + host.spec.name + ":" + joined + ": " + output;
      return false;
    };
    if (!parent({"ip", "link", "add", veth, "type", "veth", "peer", "name", "eth0", "netns",
                 netns_path(i)}) ||
        !parent({"ip", "link", "set", veth, "master", kBridge, "up"}) ||
        !inside({"ip", "link", "set", "lo", "up"}) ||
        !inside({"ip", "addr", "add", address(i) + "/24", "dev", "eth0"}) ||
        !inside({"ip", "link", "set", "eth0", "up"})) {
      return false;
    }
  }
  return true;
}

int SiteNetwork::RunIn(int netns_fd, const std::string& cgroup_procs,
                       const std::vector<std::string>& argv, std::string* output,
                       std::chrono::milliseconds timeout) {
  if (output != nullptr) output->clear();
  const std::string program = ResolveProgram(argv.at(0));
  if (program.empty()) {
    if (output != nullptr) *output = argv[0] + ": not found";
    return 127;
  }
  const std::string out =
      work_dir_.empty() ? std::string() : work_dir_ + "/run" + std::to_string(++runs_) + ".out";
  std::vector<std::string> env;
  for (char** e = environ; *e != nullptr; ++e) env.emplace_back(*e);
  ChildProcess child;
  std::string error;
  if (!ForkExec(netns_fd, cgroup_procs, program, argv, env, out, "", child.pid_slot(), &error)) {
    if (output != nullptr) *output = error;
    return 127;
  }
  const int code = child.Wait(timeout);
  if (output != nullptr && !out.empty()) *output = ReadFile(out);
  if (!out.empty()) ::unlink(out.c_str());
  return code;
}

bool SiteNetwork::Start(std::size_t host, const HostCommand& command, ChildProcess* child,
                        std::string* error) {
  if (host >= hosts_.size() || command.argv.empty()) {
    *error = "no such host, or no command";
    return false;
  }
  const std::string program = ResolveProgram(command.argv[0]);
  if (program.empty()) {
    *error = command.argv[0] + ": not found on PATH";
    return false;
  }
  std::vector<std::string> env;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string v = *e;
    if (v.rfind("CYCLONEDDS_URI=", 0) == 0 || v.rfind("NOTIFY_SOCKET=", 0) == 0) continue;
    env.push_back(v);
  }
  env.push_back("CYCLONEDDS_URI=" + DdsConfig(host));
  env.insert(env.end(), command.env.begin(), command.env.end());
  child->Kill();
  return ForkExec(hosts_[host].netns_fd, cgroup_dir(host) + "/cgroup.procs", program, command.argv,
                  env, command.stdout_path, command.stderr_path, child->pid_slot(), error);
}

int SiteNetwork::Run(std::size_t host, const std::vector<std::string>& argv, std::string* output,
                     std::chrono::milliseconds timeout) {
  return RunIn(hosts_.at(host).netns_fd, cgroup_dir(host) + "/cgroup.procs", argv, output, timeout);
}

std::vector<std::string> SiteNetwork::Launcher(std::size_t host) const {
  // sh -c SCRIPT CONFIG PROCS rest...: $0 is the Cyclone config, $1 the
  // cgroup.procs file, the rest the command.
  return {ResolveProgram("nsenter"),
          "--net=" + netns_path(host),
          "--",
          "/bin/sh",
          "-c",
          "echo $$ > \"$1\" && shift && exec /usr/bin/env \"CYCLONEDDS_URI=$0\" \"$@\"",
          DdsConfig(host),
          cgroup_dir(host) + "/cgroup.procs"};
}

bool SiteNetwork::Cut(std::size_t host, std::string* error) {
  // Everything on eth0, both ways; the host's loopback (its processes among
  // themselves) stays. Dropped in the host's input and output hooks: a
  // sender elsewhere sees silence; a sender in the host gets EPERM from
  // sendto (as with a local firewall rule) rather than silence.
  const std::string rules = work_dir_ + "/cut.nft";
  {
    std::ofstream file(rules);
    file << "table inet cut {\n"
         << "  chain in { type filter hook input priority -300; policy accept; "
         << "iifname \"eth0\" drop; }\n"
         << "  chain out { type filter hook output priority -300; policy accept; "
         << "oifname \"eth0\" drop; }\n"
         << "}\n";
  }
  std::string output;
  const int code = Run(host, {"nft", "-f", rules}, &output);
  if (code != 0) {
    *error = "nft -f (cut " + name(host) + ") exited " + std::to_string(code) + ": " + output;
    return false;
  }
  hosts_[host].cut = true;
  return true;
}

bool SiteNetwork::Heal(std::size_t host, std::string* error) {
  std::string output;
  const int code = Run(host, {"nft", "delete", "table", "inet", "cut"}, &output);
  if (code != 0) {
    *error = "nft delete table inet cut (heal " + name(host) + ") exited " + std::to_string(code) +
             ": " + output;
    return false;
  }
  hosts_[host].cut = false;
  return true;
}

void SiteNetwork::Teardown() {
  // Every process left in a host's cgroup (what the test started and what
  // those started), until none is left or 5 s have passed.
  if (!site_cgroup_.empty()) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    for (;;) {
      bool any = false;
      for (std::size_t i = 0; i < hosts_.size(); ++i) {
        if (hosts_[i].spec.name.empty()) continue;
        std::ifstream procs(cgroup_dir(i) + "/cgroup.procs");
        for (pid_t pid; procs >> pid;) {
          any = true;
          ::kill(pid, SIGKILL);
        }
      }
      if (!any || std::chrono::steady_clock::now() > deadline) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  for (Host& host : hosts_) {
    if (host.netns_fd >= 0) ::close(host.netns_fd);
    host.netns_fd = -1;
    if (host.holder > 0) {
      ::kill(host.holder, SIGKILL);
      ::waitpid(host.holder, nullptr, 0);
      host.holder = -1;
    }
  }
  if (in_private_netns_) {
    // Back to where the thread was: the private namespace (bridge and all)
    // has no member left and goes.
    if (::setns(original_netns_fd_, CLONE_NEWNET) != 0) {
      std::fprintf(stderr, "site harness: cannot return to the original network namespace: %s\n",
                   std::strerror(errno));
    }
    in_private_netns_ = false;
  }
  if (original_netns_fd_ >= 0) ::close(original_netns_fd_);
  original_netns_fd_ = -1;
  if (!site_cgroup_.empty()) {
    // A killed process leaves its cgroup at exit (a zombie no longer counts);
    // rmdir retries briefly while the last ones exit.
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    for (std::size_t i = 0; i < hosts_.size(); ++i) {
      if (hosts_[i].spec.name.empty()) continue;
      const std::string dir = cgroup_dir(i);
      while (::rmdir(dir.c_str()) != 0 && errno == EBUSY &&
             std::chrono::steady_clock::now() < deadline) {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
      }
    }
    if (::rmdir(site_cgroup_.c_str()) != 0) {
      std::fprintf(stderr, "site harness: cannot remove %s: %s\n", site_cgroup_.c_str(),
                   std::strerror(errno));
    }
    site_cgroup_.clear();
  }
  if (!work_dir_.empty()) {
    std::error_code ignored;
    std::filesystem::remove_all(work_dir_, ignored);
    work_dir_.clear();
  }
}

}  // namespace craftscan::testing
