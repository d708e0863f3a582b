#include "sandbox.h"

#include <fcntl.h>
#include <linux/capability.h>
#include <sched.h>
#include <seccomp.h>
#include <sys/mman.h>
#include <sys/mount.h>
#include <sys/personality.h>
#include <sys/prctl.h>
#include <sys/shm.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <set>

namespace craftscan::hardened {
namespace {

std::string Errno(const std::string& what) { return what + ": " + std::strerror(errno); }

bool Exists(const std::string& path) {
  struct stat st {};
  return ::lstat(path.c_str(), &st) == 0;
}

bool IsDirectory(const std::string& path) {
  struct stat st {};
  return ::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode);
}

// `path` equals `dir` or lies below it.
bool Within(const std::string& path, const std::string& dir) {
  return path == dir || (path.size() > dir.size() && path.compare(0, dir.size(), dir) == 0 &&
                         path[dir.size()] == '/');
}

bool WriteFile(const std::string& path, const std::string& text, std::string* error) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CLOEXEC);
  if (fd < 0) {
    *error = Errno("open " + path);
    return false;
  }
  const bool ok = ::write(fd, text.data(), text.size()) == static_cast<ssize_t>(text.size());
  if (!ok) *error = Errno("write " + path);
  ::close(fd);
  return ok;
}

// Sets or clears MOUNT_ATTR_RDONLY on the mount at `path` (and below it
// when `recursive`). A path that is not a mount point is first bind-mounted
// onto itself, as systemd does for ReadOnlyPaths=.
bool SetReadOnly(const std::string& path, bool read_only, bool recursive, std::string* error) {
  mount_attr attr{};
  (read_only ? attr.attr_set : attr.attr_clr) = MOUNT_ATTR_RDONLY;
  const unsigned flags = recursive ? AT_RECURSIVE : 0;
  if (::mount_setattr(AT_FDCWD, path.c_str(), flags, &attr, sizeof attr) == 0) return true;
  if (errno == EINVAL &&
      ::mount(path.c_str(), path.c_str(), nullptr, MS_BIND | MS_REC, nullptr) == 0 &&
      ::mount_setattr(AT_FDCWD, path.c_str(), flags, &attr, sizeof attr) == 0)
    return true;
  *error = Errno(std::string(read_only ? "making read-only " : "making writable ") + path);
  return false;
}

// Creates `path` (a directory, or an empty file) and its missing parents,
// inside a fresh tmpfs mask.
bool CreatePath(const std::string& path, bool directory, std::string* error) {
  for (std::size_t at = 1; at != std::string::npos; at = path.find('/', at + 1)) {
    const std::string prefix = path.substr(0, at);
    if (!prefix.empty() && !Exists(prefix) && ::mkdir(prefix.c_str(), 0755) != 0) {
      *error = Errno("mkdir " + prefix);
      return false;
    }
  }
  if (Exists(path)) return true;
  if (directory) {
    if (::mkdir(path.c_str(), 0755) == 0) return true;
  } else {
    const int fd = ::open(path.c_str(), O_CREAT | O_WRONLY | O_CLOEXEC, 0644);
    if (fd >= 0) {
      ::close(fd);
      return true;
    }
  }
  *error = Errno("creating " + path);
  return false;
}

// A path kept reachable (and writable or not) through the masks.
struct Kept {
  std::string path;
  bool writable = false;
  bool directory = true;
  int tree = -1;  // detached clone of the host's tree at path
};

// systemd's "inaccessible" nodes: an empty directory or file with mode 0000
// mounted over `path`, so a process without CAP_DAC_OVERRIDE can neither
// list nor open it.
bool MakeInaccessible(const std::string& path, std::string* error) {
  if (!Exists(path)) return true;
  if (IsDirectory(path)) {
    if (::mount("tmpfs", path.c_str(), "tmpfs", MS_RDONLY | MS_NOSUID | MS_NODEV | MS_NOEXEC,
                "mode=0000") == 0)
      return true;
    *error = Errno("masking " + path);
    return false;
  }
  // A file: bind an empty mode-0000 file from a detached tmpfs over it.
  const int fs = ::fsopen("tmpfs", FSOPEN_CLOEXEC);
  if (fs < 0) {
    *error = Errno("fsopen tmpfs");
    return false;
  }
  int mnt = -1, file = -1, tree = -1;
  bool ok = ::fsconfig(fs, FSCONFIG_CMD_CREATE, nullptr, nullptr, 0) == 0 &&
            (mnt = ::fsmount(fs, FSMOUNT_CLOEXEC, MOUNT_ATTR_NOSUID | MOUNT_ATTR_NODEV)) >= 0 &&
            (file = ::openat(mnt, "inaccessible", O_CREAT | O_WRONLY | O_CLOEXEC, 0000)) >= 0 &&
            (tree = ::open_tree(mnt, "inaccessible", OPEN_TREE_CLONE | OPEN_TREE_CLOEXEC)) >= 0 &&
            ::move_mount(tree, "", AT_FDCWD, path.c_str(), MOVE_MOUNT_F_EMPTY_PATH) == 0;
  if (!ok) *error = Errno("masking " + path);
  for (int fd : {tree, file, mnt, fs})
    if (fd >= 0) ::close(fd);
  return ok;
}

bool SetUpMounts(const LaunchOptions& o, std::vector<std::string>* trace, std::string* error) {
  const UnitSandbox& u = o.unit;
  // Private propagation: nothing mounted here reaches the host
  // (PrivateMounts=; systemd does this for any mount-namespace setting).
  if (::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0) {
    *error = Errno("making / private");
    return false;
  }
  std::vector<Kept> kept;
  auto keep = [&](const std::string& path, bool writable, bool must_exist) {
    char resolved[PATH_MAX];
    if (::realpath(path.c_str(), resolved) == nullptr) {
      if (!must_exist) return true;
      *error = Errno("resolving " + path);
      return false;
    }
    for (Kept& k : kept) {
      if (k.path == resolved) {
        k.writable = k.writable || writable;
        return true;
      }
    }
    kept.push_back({resolved, writable, IsDirectory(resolved), -1});
    return true;
  };
  if (!u.state_directory.empty() && !keep(o.state_dir, true, true)) return false;
  for (const std::string& p : u.read_write_paths)
    if (!keep(p, true, false)) return false;
  for (const std::string& p : u.read_only_paths)
    if (!keep(p, false, false)) return false;
  for (const std::string& p : o.read_write)
    if (!keep(p, true, true)) return false;
  for (const std::string& p : o.read_only)
    if (!keep(p, false, true)) return false;
  // Parents before children: a writable data directory inside a read-only
  // configuration folder is attached and flagged after it.
  std::sort(kept.begin(), kept.end(), [](const Kept& a, const Kept& b) { return a.path < b.path; });
  for (Kept& k : kept) {
    k.tree =
        ::open_tree(AT_FDCWD, k.path.c_str(), OPEN_TREE_CLONE | OPEN_TREE_CLOEXEC | AT_RECURSIVE);
    if (k.tree < 0) {
      *error = Errno("cloning the mount tree at " + k.path);
      return false;
    }
  }

  // Masks: a fresh tmpfs over each; ProtectHome=yes ones are empty and
  // mode 0000 (systemd mounts an "inaccessible" directory), or 0711 when a
  // kept path below has to be reached through it.
  struct Mask {
    std::string dir;
    mode_t mode;
    bool writable;
  };
  std::vector<Mask> masks;
  if (u.private_tmp) {
    for (const char* dir : {"/tmp", "/var/tmp"}) masks.push_back({dir, 01777, true});
  }
  if (u.protect_home == "yes" || u.protect_home == "tmpfs") {
    const mode_t mode = u.protect_home == "yes" ? 0000 : 0755;
    for (const char* dir : {"/home", "/root", "/run/user"}) masks.push_back({dir, mode, false});
  }
  for (Mask& m : masks) {
    if (!IsDirectory(m.dir)) continue;
    bool below = false;
    for (const Kept& k : kept) below = below || Within(k.path, m.dir);
    if (below && m.mode == 0000) m.mode = 0711;
    char data[32];
    std::snprintf(data, sizeof data, "mode=%04o", static_cast<unsigned>(m.mode));
    if (::mount("tmpfs", m.dir.c_str(), "tmpfs", MS_NOSUID | MS_NODEV, data) != 0) {
      *error = Errno("mounting a tmpfs on " + m.dir);
      return false;
    }
    trace->push_back("tmpfs " + m.dir + " (" + data + ")");
    for (const Kept& k : kept)
      if (Within(k.path, m.dir) && !CreatePath(k.path, k.directory, error)) return false;
  }
  for (Kept& k : kept) {
    if (::move_mount(k.tree, "", AT_FDCWD, k.path.c_str(), MOVE_MOUNT_F_EMPTY_PATH) != 0) {
      *error = Errno("attaching " + k.path);
      return false;
    }
    ::close(k.tree);
    k.tree = -1;
  }

  if (u.protect_system == "strict") {
    // Everything read-only but the API file systems.
    if (!SetReadOnly("/", true, true, error)) return false;
    for (const char* api : {"/dev", "/proc", "/sys"})
      if (IsDirectory(api) && !SetReadOnly(api, false, true, error)) return false;
    trace->push_back("read-only / (recursive), except /dev /proc /sys");
  }
  if (u.protect_home == "read-only" || u.protect_home == "tmpfs" || u.protect_home == "yes") {
    for (const char* dir : {"/home", "/root", "/run/user"})
      if (IsDirectory(dir) && !SetReadOnly(dir, true, false, error)) return false;
  }
  for (const Mask& m : masks)
    if (m.writable && IsDirectory(m.dir) && !SetReadOnly(m.dir, false, false, error)) return false;
  if (u.protect_kernel_tunables) {
    for (const char* path : {"/sys", "/proc/sys", "/proc/sysrq-trigger"})
      if (Exists(path) && !SetReadOnly(path, true, true, error)) return false;
    trace->push_back("read-only /sys /proc/sys /proc/sysrq-trigger");
  }
  if (u.protect_control_groups && IsDirectory("/sys/fs/cgroup")) {
    if (!SetReadOnly("/sys/fs/cgroup", true, true, error)) return false;
    trace->push_back("read-only /sys/fs/cgroup");
  }
  if (u.protect_kernel_modules) {
    for (const char* path : {"/lib/modules", "/usr/lib/modules"})
      if (!MakeInaccessible(path, error)) return false;
    trace->push_back("inaccessible /lib/modules /usr/lib/modules");
  }
  if (u.protect_kernel_logs) {
    for (const char* path : {"/proc/kmsg", "/dev/kmsg"})
      if (!MakeInaccessible(path, error)) return false;
    trace->push_back("inaccessible /proc/kmsg /dev/kmsg");
  }
  for (const Kept& k : kept) {
    if (!SetReadOnly(k.path, !k.writable, true, error)) return false;
    trace->push_back((k.writable ? "writable " : "read-only ") + k.path);
  }
  return true;
}

bool DropCapabilities(std::string* error) {
  int last = 63;
  std::ifstream("/proc/sys/kernel/cap_last_cap") >> last;
  for (int cap = 0; cap <= last; ++cap) {
    if (::prctl(PR_CAPBSET_DROP, cap, 0, 0, 0) != 0 && errno != EINVAL) {
      *error = Errno("dropping capability " + std::to_string(cap) + " from the bounding set");
      return false;
    }
  }
  if (::prctl(PR_CAP_AMBIENT, PR_CAP_AMBIENT_CLEAR_ALL, 0, 0, 0) != 0) {
    *error = Errno("clearing the ambient capabilities");
    return false;
  }
  __user_cap_header_struct header{_LINUX_CAPABILITY_VERSION_3, 0};
  __user_cap_data_struct data[2] = {};
  if (::syscall(SYS_capset, &header, data) != 0) {
    *error = Errno("capset (clearing effective, permitted, inheritable)");
    return false;
  }
  return true;
}

// A libseccomp filter for the native architecture only, as systemd's
// seccomp_init_for_arch: other architectures pass (SystemCallArchitectures=
// has its own filter), no_new_privs is set by us.
struct Filter {
  explicit Filter(uint32_t default_action) : ctx(::seccomp_init(default_action)) {
    if (ctx != nullptr) {
      ::seccomp_attr_set(ctx, SCMP_FLTATR_ACT_BADARCH, SCMP_ACT_ALLOW);
      ::seccomp_attr_set(ctx, SCMP_FLTATR_CTL_NNP, 0);
    }
  }
  ~Filter() {
    if (ctx != nullptr) ::seccomp_release(ctx);
  }
  Filter(const Filter&) = delete;
  Filter& operator=(const Filter&) = delete;

  // Adds a rule; a syscall this architecture does not have is skipped.
  bool Add(uint32_t action, const char* name, std::vector<scmp_arg_cmp> args, std::string* error) {
    const int nr = ::seccomp_syscall_resolve_name(name);
    if (nr == __NR_SCMP_ERROR || nr < 0) return true;
    const int r = ::seccomp_rule_add_exact_array(
        ctx, action, nr, static_cast<unsigned>(args.size()), args.empty() ? nullptr : args.data());
    // -EACCES: the rule's action is the default action anyway.
    if (r == 0 || r == -EDOM || r == -EACCES) return true;
    *error = std::string("seccomp rule for ") + name + ": " + std::strerror(-r);
    return false;
  }
  bool Load(const std::string& what, std::vector<std::string>* trace, std::string* error) {
    const int r = ::seccomp_load(ctx);
    if (r != 0) {
      *error = "loading the " + what + " filter: " + std::strerror(-r);
      return false;
    }
    trace->push_back("seccomp " + what);
    return true;
  }
  scmp_filter_ctx ctx;
};

bool LoadAddressFamilyFilter(const UnitSandbox& u, std::vector<std::string>* trace,
                             std::string* error) {
  Filter f(SCMP_ACT_ALLOW);
  const uint32_t deny = SCMP_ACT_ERRNO(EAFNOSUPPORT);
  if (u.address_families_allow) {
    // As systemd: below the first, above the last, and every gap between.
    if (u.address_families.empty()) {
      if (!f.Add(deny, "socket", {}, error)) return false;
    } else {
      const int first = *u.address_families.begin(), last = *u.address_families.rbegin();
      if (!f.Add(deny, "socket", {SCMP_A0(SCMP_CMP_LT, static_cast<scmp_datum_t>(first))}, error) ||
          !f.Add(deny, "socket", {SCMP_A0(SCMP_CMP_GT, static_cast<scmp_datum_t>(last))}, error))
        return false;
      for (int af = first + 1; af < last; ++af)
        if (!u.address_families.count(af) &&
            !f.Add(deny, "socket", {SCMP_A0(SCMP_CMP_EQ, static_cast<scmp_datum_t>(af))}, error))
          return false;
    }
  } else {
    for (int af : u.address_families)
      if (!f.Add(deny, "socket", {SCMP_A0(SCMP_CMP_EQ, static_cast<scmp_datum_t>(af))}, error))
        return false;
  }
  return f.Load("RestrictAddressFamilies=", trace, error);
}

bool LoadMemoryDenyWriteExecuteFilter(std::vector<std::string>* trace, std::string* error) {
  Filter f(SCMP_ACT_ALLOW);
  const uint32_t deny = SCMP_ACT_ERRNO(EPERM);
  const scmp_datum_t wx = PROT_WRITE | PROT_EXEC;
  return f.Add(deny, "mmap", {SCMP_A2(SCMP_CMP_MASKED_EQ, wx, wx)}, error) &&
         f.Add(deny, "mprotect", {SCMP_A2(SCMP_CMP_MASKED_EQ, PROT_EXEC, PROT_EXEC)}, error) &&
         f.Add(deny, "pkey_mprotect", {SCMP_A2(SCMP_CMP_MASKED_EQ, PROT_EXEC, PROT_EXEC)}, error) &&
         f.Add(deny, "shmat", {SCMP_A2(SCMP_CMP_MASKED_EQ, SHM_EXEC, SHM_EXEC)}, error) &&
         f.Load("MemoryDenyWriteExecute=", trace, error);
}

bool LoadRealtimeFilter(std::vector<std::string>* trace, std::string* error) {
  // SCHED_OTHER, SCHED_BATCH and SCHED_IDLE pass; every other policy
  // (FIFO, RR, DEADLINE, anything with flags above) is refused.
  Filter f(SCMP_ACT_ALLOW);
  const uint32_t deny = SCMP_ACT_ERRNO(EPERM);
  for (int policy = 0; policy < SCHED_IDLE; ++policy)
    if (policy != SCHED_OTHER && policy != SCHED_BATCH &&
        !f.Add(deny, "sched_setscheduler",
               {SCMP_A1(SCMP_CMP_EQ, static_cast<scmp_datum_t>(policy))}, error))
      return false;
  return f.Add(deny, "sched_setscheduler", {SCMP_A1(SCMP_CMP_GT, SCHED_IDLE)}, error) &&
         f.Load("RestrictRealtime=", trace, error);
}

bool LoadSuidSgidFilter(std::vector<std::string>* trace, std::string* error) {
  Filter f(SCMP_ACT_ALLOW);
  const uint32_t deny = SCMP_ACT_ERRNO(EPERM);
  for (const scmp_datum_t m : {scmp_datum_t{S_ISUID}, scmp_datum_t{S_ISGID}}) {
    const bool ok =
        f.Add(deny, "chmod", {SCMP_A1(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "fchmod", {SCMP_A1(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "fchmodat", {SCMP_A2(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "mkdir", {SCMP_A1(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "mkdirat", {SCMP_A2(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "mknod", {SCMP_A1(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "mknodat", {SCMP_A2(SCMP_CMP_MASKED_EQ, m, m)}, error) &&
        f.Add(deny, "open",
              {SCMP_A1(SCMP_CMP_MASKED_EQ, O_CREAT, O_CREAT), SCMP_A2(SCMP_CMP_MASKED_EQ, m, m)},
              error) &&
        f.Add(deny, "openat",
              {SCMP_A2(SCMP_CMP_MASKED_EQ, O_CREAT, O_CREAT), SCMP_A3(SCMP_CMP_MASKED_EQ, m, m)},
              error) &&
        f.Add(deny, "creat", {SCMP_A1(SCMP_CMP_MASKED_EQ, m, m)}, error);
    if (!ok) return false;
  }
  // openat2() keeps its mode in a struct a filter cannot read: ENOSYS, so
  // libc falls back to openat().
  return f.Add(SCMP_ACT_ERRNO(ENOSYS), "openat2", {}, error) &&
         f.Load("RestrictSUIDSGID=", trace, error);
}

bool LoadNamespaceFilter(std::vector<std::string>* trace, std::string* error) {
  Filter f(SCMP_ACT_ALLOW);
  const uint32_t deny = SCMP_ACT_ERRNO(EPERM);
  if (!f.Add(deny, "setns", {}, error)) return false;
  for (const scmp_datum_t flag :
       {scmp_datum_t{CLONE_NEWCGROUP}, scmp_datum_t{CLONE_NEWIPC}, scmp_datum_t{CLONE_NEWNET},
        scmp_datum_t{CLONE_NEWNS}, scmp_datum_t{CLONE_NEWPID}, scmp_datum_t{CLONE_NEWUSER},
        scmp_datum_t{CLONE_NEWUTS}}) {
    if (!f.Add(deny, "unshare", {SCMP_A0(SCMP_CMP_MASKED_EQ, flag, flag)}, error) ||
        !f.Add(deny, "clone", {SCMP_A0(SCMP_CMP_MASKED_EQ, flag, flag)}, error))
      return false;
  }
  // clone3() keeps its flags in a struct: ENOSYS, so libc uses clone().
  return f.Add(SCMP_ACT_ERRNO(ENOSYS), "clone3", {}, error) &&
         f.Load("RestrictNamespaces=", trace, error);
}

// Denies every syscall in `names` with EPERM (the Protect*= settings' own
// small filters).
bool LoadDenyFilter(const std::set<std::string>& names, const std::string& what,
                    std::vector<std::string>* trace, std::string* error) {
  Filter f(SCMP_ACT_ALLOW);
  for (const std::string& name : names)
    if (!f.Add(SCMP_ACT_ERRNO(EPERM), name.c_str(), {}, error)) return false;
  return f.Load(what, trace, error);
}

bool LoadPersonalityFilter(std::vector<std::string>* trace, std::string* error) {
  const int current = ::personality(0xffffffff);
  Filter f(SCMP_ACT_ALLOW);
  return f.Add(SCMP_ACT_ERRNO(EPERM), "personality",
               {SCMP_A0(SCMP_CMP_NE, static_cast<scmp_datum_t>(current))}, error) &&
         f.Load("LockPersonality=", trace, error);
}

bool LoadArchitectureFilter(std::vector<std::string>* trace, std::string* error) {
  // No rules: the filter's only effect is its architecture list (native),
  // with libseccomp's default action for any other architecture (kill).
  scmp_filter_ctx ctx = ::seccomp_init(SCMP_ACT_ALLOW);
  if (ctx == nullptr) {
    *error = "seccomp_init failed";
    return false;
  }
  ::seccomp_attr_set(ctx, SCMP_FLTATR_CTL_NNP, 0);
  const int r = ::seccomp_load(ctx);
  ::seccomp_release(ctx);
  if (r != 0) {
    *error = std::string("loading the SystemCallArchitectures= filter: ") + std::strerror(-r);
    return false;
  }
  trace->push_back("seccomp SystemCallArchitectures=native");
  return true;
}

bool LoadSyscallFilter(const UnitSandbox& u, const SyscallGroups& groups,
                       std::vector<std::string>* trace, std::string* error) {
  bool allow_list = false;
  std::set<std::string> names;
  if (!ResolveSyscallFilter(u.syscall_filter, groups, &allow_list, &names, error)) return false;
  if (!allow_list && names.empty()) return true;
  const uint32_t refuse = u.syscall_error_number
                              ? SCMP_ACT_ERRNO(static_cast<uint32_t>(*u.syscall_error_number))
                              : SCMP_ACT_KILL_PROCESS;
  Filter f(allow_list ? refuse : SCMP_ACT_ALLOW);
  for (const std::string& name : names)
    if (!f.Add(allow_list ? SCMP_ACT_ALLOW : refuse, name.c_str(), {}, error)) return false;
  return f.Load(std::string("SystemCallFilter= (") +
                    (allow_list ? "allow list of " : "deny list of ") +
                    std::to_string(names.size()) + " names)",
                trace, error);
}

// Members of a syscall group, from systemd-analyze's listing.
bool LoadGroupDenyFilter(const SyscallGroups& groups, const std::string& group,
                         const std::string& what, std::vector<std::string>* trace,
                         std::string* error) {
  std::set<std::string> names;
  return ExpandSyscallGroup(groups, group, &names, error) &&
         LoadDenyFilter(names, what, trace, error);
}

}  // namespace

SandboxFailure EnterSandbox(const LaunchOptions& o, std::vector<std::string>* trace_out,
                            std::string* error) {
  std::vector<std::string> ignored_trace;
  std::vector<std::string>* trace = trace_out != nullptr ? trace_out : &ignored_trace;
  const UnitSandbox& u = o.unit;
  if (!u.state_directory.empty() && o.state_dir.empty()) {
    *error = "the unit has StateDirectory=" + u.state_directory + ": pass --state-dir";
    return SandboxFailure::kError;
  }
  SyscallGroups groups;
  const bool needs_groups =
      !u.syscall_filter.empty() || u.protect_kernel_modules || u.protect_clock;
  if (needs_groups && !ParseSyscallGroups(o.syscall_groups_text, &groups, error))
    return SandboxFailure::kError;
  if (::prctl(PR_GET_SECCOMP, 0, 0, 0, 0) < 0) {
    *error = Errno("seccomp is not available (prctl PR_GET_SECCOMP)");
    return SandboxFailure::kUnavailable;
  }

  const uid_t uid = ::geteuid();
  const gid_t gid = ::getegid();
  int flags = CLONE_NEWUSER | CLONE_NEWNS;
  if (u.protect_hostname) flags |= CLONE_NEWUTS;
  if (::unshare(flags) != 0) {
    *error = Errno("user namespaces are not available (unshare CLONE_NEWUSER|CLONE_NEWNS)");
    return SandboxFailure::kUnavailable;
  }
  // The invoking user keeps its ids (root stays root, without capabilities
  // once they are dropped below).
  if (!WriteFile("/proc/self/setgroups", "deny", error) ||
      !WriteFile("/proc/self/uid_map", std::to_string(uid) + " " + std::to_string(uid) + " 1",
                 error) ||
      !WriteFile("/proc/self/gid_map", std::to_string(gid) + " " + std::to_string(gid) + " 1",
                 error))
    return SandboxFailure::kError;
  trace->push_back("user namespace (uid " + std::to_string(uid) + " mapped to itself), mount " +
                   "namespace" + (u.protect_hostname ? ", UTS namespace" : ""));
  if (!SetUpMounts(o, trace, error)) return SandboxFailure::kError;

  if (u.umask) ::umask(*u.umask);
  for (const auto& [name, value] : u.environment) ::setenv(name.c_str(), value.c_str(), 1);
  if (u.drop_all_capabilities) {
    if (!DropCapabilities(error)) return SandboxFailure::kError;
    trace->push_back("no capabilities (bounding, ambient, effective, permitted, inheritable)");
  }
  // Seccomp filters need no_new_privs once capabilities are gone; systemd
  // implies it the same way.
  const bool any_filter = u.address_families_set || u.memory_deny_write_execute ||
                          u.restrict_realtime || u.restrict_suid_sgid || u.restrict_namespaces ||
                          u.lock_personality || !u.syscall_filter.empty() ||
                          u.syscall_architectures_native || u.protect_kernel_logs ||
                          u.protect_kernel_modules || u.protect_clock || u.protect_hostname ||
                          u.protect_kernel_tunables;
  if (u.no_new_privileges || any_filter) {
    if (::prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0) {
      *error = Errno("PR_SET_NO_NEW_PRIVS");
      return SandboxFailure::kError;
    }
    trace->push_back("no_new_privs");
  }
  // In systemd's order; the syscall filter last (it may refuse seccomp()).
  if (u.address_families_set && !LoadAddressFamilyFilter(u, trace, error))
    return SandboxFailure::kError;
  if (u.memory_deny_write_execute && !LoadMemoryDenyWriteExecuteFilter(trace, error))
    return SandboxFailure::kError;
  if (u.restrict_realtime && !LoadRealtimeFilter(trace, error)) return SandboxFailure::kError;
  if (u.restrict_suid_sgid && !LoadSuidSgidFilter(trace, error)) return SandboxFailure::kError;
  if (u.restrict_namespaces && !LoadNamespaceFilter(trace, error)) return SandboxFailure::kError;
  if (u.protect_kernel_tunables &&
      !LoadDenyFilter({"_sysctl"}, "ProtectKernelTunables=", trace, error))
    return SandboxFailure::kError;
  if (u.protect_kernel_modules &&
      !LoadGroupDenyFilter(groups, "@module", "ProtectKernelModules=", trace, error))
    return SandboxFailure::kError;
  if (u.protect_kernel_logs && !LoadDenyFilter({"syslog"}, "ProtectKernelLogs=", trace, error))
    return SandboxFailure::kError;
  if (u.protect_clock && !LoadGroupDenyFilter(groups, "@clock", "ProtectClock=", trace, error))
    return SandboxFailure::kError;
  if (u.protect_hostname &&
      !LoadDenyFilter({"sethostname", "setdomainname"}, "ProtectHostname=", trace, error))
    return SandboxFailure::kError;
  if (u.syscall_architectures_native && !LoadArchitectureFilter(trace, error))
    return SandboxFailure::kError;
  if (u.lock_personality && !LoadPersonalityFilter(trace, error)) return SandboxFailure::kError;
  if (!u.syscall_filter.empty() && !LoadSyscallFilter(u, groups, trace, error))
    return SandboxFailure::kError;
  return SandboxFailure::kNone;
}

}  // namespace craftscan::hardened
