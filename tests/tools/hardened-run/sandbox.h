// Applies a UnitSandbox (unit_sandbox.h) to the calling process without
// systemd: an unprivileged user + mount namespace, bind mounts and tmpfs
// masks, capability and no_new_privs settings, and seccomp filters built with
// libseccomp the way systemd's seccomp-util.c builds them. See main.cc for
// what is reproduced and what is not.
#pragma once

#include <string>
#include <vector>

#include "unit_sandbox.h"

namespace craftscan::hardened {

struct LaunchOptions {
  UnitSandbox unit;
  // The directory StateDirectory= stands for (systemd: /var/lib/<name>):
  // writable inside. Required when the unit has StateDirectory=.
  std::string state_dir;
  // More writable / read-only paths (existing). Like ReadWritePaths= and
  // ReadOnlyPaths=, and besides they stay reachable at the same path when
  // they lie under a masked directory (/tmp, /var/tmp, /home, /root): the
  // build tree, a test's data directory, a notify socket's folder.
  std::vector<std::string> read_write, read_only;
  // `systemd-analyze syscall-filter` output; needed when the unit's filters
  // name syscall groups.
  std::string syscall_groups_text;
};

// Where entering failed: the kernel does not offer what is needed (user
// namespaces, seccomp), or anything else (bad option, mount error).
enum class SandboxFailure { kNone, kUnavailable, kError };

// Puts the calling process into the sandbox; the caller then execs the
// service. The process must be single-threaded (unshare(CLONE_NEWUSER)).
// After success the process has no capabilities and the seccomp filters are
// loaded: only exec and exit remain for the caller. On failure returns the
// kind with *error naming the step; the process may then be half-confined
// and must exit. *trace (may be null) receives one line per step taken
// (mounts, filters), for --explain.
SandboxFailure EnterSandbox(const LaunchOptions& options, std::vector<std::string>* trace,
                            std::string* error);

}  // namespace craftscan::hardened
