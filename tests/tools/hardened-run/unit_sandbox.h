// hardened-run's model of a systemd service's sandbox: the [Service]
// settings of a unit file that confine a process, parsed into a plain struct,
// and the syscall groups of `systemd-analyze syscall-filter` resolved into
// sets of names. No side effects here: sandbox.h applies the result.
#pragma once

#include <sys/types.h>

#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace craftscan::hardened {

// One SystemCallFilter= assignment, in file order: its items, and whether
// it had the "~" (deny) prefix. An empty assignment resets the filter.
struct SyscallFilterLine {
  bool invert = false;
  std::vector<std::string> items;  // names and @groups
};

// The sandboxing settings of one unit. Values are as in the unit; every
// boolean is false / every list empty when the setting is absent.
struct UnitSandbox {
  std::string protect_system = "no";  // "no" or "strict"
  std::string protect_home = "no";    // "no", "yes", "read-only" or "tmpfs"
  bool private_tmp = false;
  bool private_mounts = false;
  bool no_new_privileges = false;
  bool drop_all_capabilities = false;  // CapabilityBoundingSet= (empty)
  std::vector<SyscallFilterLine> syscall_filter;
  std::optional<int> syscall_error_number;  // SystemCallErrorNumber=; none: kill
  bool syscall_architectures_native = false;
  bool memory_deny_write_execute = false;
  bool lock_personality = false;
  bool restrict_realtime = false;
  bool restrict_suid_sgid = false;
  bool restrict_namespaces = false;  // RestrictNamespaces=yes (all kinds)
  bool address_families_set = false;
  bool address_families_allow = true;  // false: "~" deny list
  std::set<int> address_families;      // AF_* numbers
  bool protect_kernel_tunables = false;
  bool protect_kernel_modules = false;
  bool protect_kernel_logs = false;
  bool protect_control_groups = false;
  bool protect_clock = false;
  bool protect_hostname = false;
  std::optional<mode_t> umask;
  std::vector<std::pair<std::string, std::string>> environment;  // Environment=
  std::vector<std::string> read_write_paths, read_only_paths;    // absolute
  std::string state_directory;  // StateDirectory= name (/var/lib/<name>)

  // "Key=value" of every setting this model applies (fully or as far as
  // noted), and "Key=value: why" of those it cannot reproduce without
  // systemd as PID 1; for --explain and for tests.
  std::vector<std::string> reproduced, not_reproduced;
};

// Parses the unit file text. Settings outside [Service] are ignored; so are
// [Service] settings that manage the service rather than confine it (Type=,
// ExecStart=, Restart=, timeouts, ...). A [Service] setting this model does
// not know, or a value it cannot apply (e.g. ProtectSystem=full), is an
// error naming the line: the launcher must be taught about it rather than
// silently run a weaker sandbox than the unit asks for. False with *error.
bool ParseUnit(const std::string& text, UnitSandbox* out, std::string* error);

// The syscall groups of `systemd-analyze syscall-filter` output: group name
// ("@system-service") to its entries (names and nested @groups).
using SyscallGroups = std::map<std::string, std::vector<std::string>>;

// Parses `systemd-analyze syscall-filter` output (all groups). False with
// *error when no group is found.
bool ParseSyscallGroups(const std::string& text, SyscallGroups* out, std::string* error);

// The syscall names of `item`: a name itself, or a @group expanded
// recursively. False with *error for an unknown group.
bool ExpandSyscallGroup(const SyscallGroups& groups, const std::string& item,
                        std::set<std::string>* names, std::string* error);

// Resolves the SystemCallFilter= lines as systemd does: the first non-empty
// line decides the mode (allow list, with @default implied, or "~" deny
// list); later lines of the same kind add, of the other kind remove; an
// empty line resets. Groups expand recursively. *allow_list receives the
// mode. False with *error for an unknown group.
bool ResolveSyscallFilter(const std::vector<SyscallFilterLine>& lines, const SyscallGroups& groups,
                          bool* allow_list, std::set<std::string>* names, std::string* error);

// The AF_* number for a name as the unit spells it ("AF_INET6"), or -1.
int AddressFamilyFromName(const std::string& name);

}  // namespace craftscan::hardened
