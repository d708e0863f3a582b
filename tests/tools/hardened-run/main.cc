// hardened-run: runs a command under the sandbox a systemd unit file asks
// for, without systemd as PID 1 and without root on the host, so tests can
// run craftscand the way systemd/craftscand.service confines it.
//
//   hardened-run --unit craftscand.service --state-dir DIR [--rw PATH]...
//                [--ro PATH]... [--explain] [--] COMMAND [ARG]...
//
// The unit's [Service] settings are read from the file itself (not copied
// here), so the sandbox follows the unit; a confining setting the launcher
// does not know makes it fail rather than run a weaker sandbox.
//
// Reproduced (in the launcher's own process, which then execs COMMAND; the
// pid stays the same, so signals reach COMMAND directly):
//   - a new user namespace (the caller's uid/gid mapped to themselves) and
//     mount namespace with private propagation (PrivateMounts=);
//   - ProtectSystem=strict: / read-only recursively (mount_setattr), /dev,
//     /proc, /sys left writable as systemd does (then narrowed below);
//     StateDirectory= is --state-dir, writable; ReadWritePaths= and --rw
//     writable, ReadOnlyPaths= and --ro read-only;
//   - PrivateTmp=yes: fresh tmpfs on /tmp and /var/tmp;
//   - ProtectHome=yes: empty mode-0000 tmpfs on /home, /root, /run/user
//     (0711 when a --rw/--ro path below must stay reachable); tmpfs and
//     read-only variants too. Paths passed with --rw/--ro (and the state
//     directory) are cloned before the masks and attached again after, so a
//     build tree or test folder under /tmp or /home stays at its path;
//   - ProtectKernelTunables=: /sys, /proc/sys, /proc/sysrq-trigger read-only,
//     _sysctl() refused; ProtectControlGroups=: /sys/fs/cgroup read-only;
//     ProtectKernelModules=: /lib/modules, /usr/lib/modules inaccessible and
//     @module refused; ProtectKernelLogs=: /proc/kmsg, /dev/kmsg
//     inaccessible and syslog() refused; ProtectClock=: @clock refused;
//     ProtectHostname=: a new UTS namespace, sethostname/setdomainname
//     refused;
//   - UMask=, Environment=;
//   - CapabilityBoundingSet= (empty): bounding set, ambient, effective,
//     permitted and inheritable sets all emptied (an exec as uid 0 then
//     gains nothing);
//   - NoNewPrivileges=yes (also implied by any seccomp filter, as systemd);
//   - seccomp filters, one per setting as systemd's seccomp-util.c builds
//     them and in its order: RestrictAddressFamilies= (socket() with another
//     family → EAFNOSUPPORT), MemoryDenyWriteExecute= (mmap W+X, mprotect /
//     pkey_mprotect +X, shmat SHM_EXEC → EPERM), RestrictRealtime=
//     (sched_setscheduler other than OTHER/BATCH/IDLE → EPERM),
//     RestrictSUIDSGID= (chmod/mkdir/mknod/open/creat with S_ISUID or
//     S_ISGID → EPERM, openat2 → ENOSYS), RestrictNamespaces=yes (setns,
//     unshare/clone with any CLONE_NEW* → EPERM, clone3 → ENOSYS),
//     SystemCallArchitectures=native (other ABIs killed), LockPersonality=
//     (personality() changes → EPERM), and SystemCallFilter= last: the
//     groups taken at run time from `systemd-analyze syscall-filter`, merged
//     as systemd merges the lines (allow list with @default implied, "~"
//     lines removing), everything else → SystemCallErrorNumber=.
//     One deliberate difference: systemd ≥ 250 may answer syscalls newer
//     than its own tables with ENOSYS; here they get SystemCallErrorNumber=
//     too, which is stricter.
//
// Not reproduced (listed by --explain, with the reason):
//   - User=, Group=, SupplementaryGroups=: the command runs as the invoking
//     user (root in CI) — with no capabilities at all, so root only keeps
//     owner rights on root-owned files; read-only mounts still refuse writes;
//   - DevicePolicy=, DeviceAllow=, CPUWeight=, IOWeight=: cgroup programs and
//     controls that need systemd's cgroup delegation;
//   - ProtectProc=invisible: needs a /proc of a PID namespace of our own
//     (the pid would then change and signals would go to a stand-in);
//   - RemoveIPC=: clean-up at stop, not confinement; *DirectoryMode=:
//     the caller creates the directories.
//
// Exit status: COMMAND's (it replaces the launcher); 77 when the kernel
// offers no user namespaces or seccomp (tests skip); 125 for a bad unit,
// bad option or failed step (message on stderr); 126/127 when COMMAND
// cannot be run / found.
#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "sandbox.h"
#include "unit_sandbox.h"

extern char** environ;

namespace {

using craftscan::hardened::LaunchOptions;
using craftscan::hardened::SandboxFailure;

constexpr int kUnavailable = 77;
constexpr int kFailed = 125;

int Usage(const char* why) {
  std::fprintf(stderr,
               "hardened-run: %s\nusage: hardened-run --unit FILE [--state-dir DIR] [--rw PATH]... "
               "[--ro PATH]... [--explain] [--] COMMAND [ARG]...\n",
               why);
  return kFailed;
}

// stdout of `systemd-analyze syscall-filter`, or "" with *error.
std::string SyscallGroupsListing(std::string* error) {
  int pipe_fds[2];
  if (::pipe2(pipe_fds, O_CLOEXEC) != 0) {
    *error = std::string("pipe: ") + std::strerror(errno);
    return "";
  }
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], 1);
  // It notes on stderr what it cannot list (the kernel's own table).
  posix_spawn_file_actions_addopen(&actions, 2, "/dev/null", O_WRONLY, 0);
  char arg0[] = "systemd-analyze", arg1[] = "syscall-filter";
  char* argv[] = {arg0, arg1, nullptr};
  pid_t pid = -1;
  const int r = posix_spawnp(&pid, "systemd-analyze", &actions, nullptr, argv, environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(pipe_fds[1]);
  std::string text;
  if (r == 0) {
    char buffer[65536];
    ssize_t n;
    while ((n = ::read(pipe_fds[0], buffer, sizeof buffer)) > 0 || (n < 0 && errno == EINTR))
      if (n > 0) text.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(pipe_fds[0]);
  int status = 0;
  if (r != 0 || ::waitpid(pid, &status, 0) != pid || !WIFEXITED(status) ||
      WEXITSTATUS(status) != 0) {
    *error =
        "`systemd-analyze syscall-filter` failed (package systemd): needed for the unit's "
        "syscall groups";
    return "";
  }
  return text;
}

}  // namespace

int main(int argc, char** argv) {
  LaunchOptions options;
  std::string unit_path;
  bool explain = false;
  int i = 1;
  for (; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](std::string* target) {
      if (i + 1 >= argc) return false;
      *target = argv[++i];
      return true;
    };
    std::string v;
    if (a == "--") {
      ++i;
      break;
    } else if (a == "--unit") {
      if (!value(&unit_path)) return Usage("--unit needs a file");
    } else if (a == "--state-dir") {
      if (!value(&options.state_dir)) return Usage("--state-dir needs a directory");
    } else if (a == "--rw") {
      if (!value(&v)) return Usage("--rw needs a path");
      options.read_write.push_back(v);
    } else if (a == "--ro") {
      if (!value(&v)) return Usage("--ro needs a path");
      options.read_only.push_back(v);
    } else if (a == "--explain") {
      explain = true;
    } else if (a.rfind("--", 0) == 0) {
      return Usage(("unknown option " + a).c_str());
    } else {
      break;
    }
  }
  if (unit_path.empty()) return Usage("--unit is required");
  if (i >= argc) return Usage("no command given");

  std::ifstream in(unit_path);
  if (!in) {
    std::fprintf(stderr, "hardened-run: cannot read %s: %s\n", unit_path.c_str(),
                 std::strerror(errno));
    return kFailed;
  }
  std::stringstream text;
  text << in.rdbuf();
  std::string error;
  if (!craftscan::hardened::ParseUnit(text.str(), &options.unit, &error)) {
    std::fprintf(stderr, "hardened-run: %s: %s\n", unit_path.c_str(), error.c_str());
    return kFailed;
  }
  const auto& u = options.unit;
  if (!u.syscall_filter.empty() || u.protect_kernel_modules || u.protect_clock) {
    options.syscall_groups_text = SyscallGroupsListing(&error);
    if (options.syscall_groups_text.empty()) {
      std::fprintf(stderr, "hardened-run: %s\n", error.c_str());
      return kFailed;
    }
  }
  std::vector<std::string> trace;
  const SandboxFailure failure = craftscan::hardened::EnterSandbox(options, &trace, &error);
  if (failure != SandboxFailure::kNone) {
    std::fprintf(stderr, "hardened-run: %s\n", error.c_str());
    return failure == SandboxFailure::kUnavailable ? kUnavailable : kFailed;
  }
  if (explain) {
    for (const std::string& s : u.reproduced)
      std::fprintf(stderr, "hardened-run: reproduced %s\n", s.c_str());
    for (const std::string& s : u.not_reproduced)
      std::fprintf(stderr, "hardened-run: not reproduced %s\n", s.c_str());
    for (const std::string& s : trace) std::fprintf(stderr, "hardened-run: step %s\n", s.c_str());
  }
  ::execvp(argv[i], argv + i);
  const int e = errno;
  std::fprintf(stderr, "hardened-run: cannot run %s: %s\n", argv[i], std::strerror(e));
  return e == ENOENT ? 127 : 126;
}
