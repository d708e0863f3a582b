#include "unit_sandbox.h"

#include <sys/socket.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <sstream>

namespace craftscan::hardened {
namespace {

std::string Trim(const std::string& s) {
  const auto begin = s.find_first_not_of(" \t\r\n");
  if (begin == std::string::npos) return "";
  const auto end = s.find_last_not_of(" \t\r\n");
  return s.substr(begin, end - begin + 1);
}

// Whitespace-separated words; a word in double quotes may hold spaces.
std::vector<std::string> Words(const std::string& value) {
  std::vector<std::string> words;
  std::string word;
  bool quoted = false, any = false;
  for (char c : value) {
    if (c == '"') {
      quoted = !quoted;
      any = true;
    } else if (!quoted && (c == ' ' || c == '\t')) {
      if (any) words.push_back(word);
      word.clear();
      any = false;
    } else {
      word += c;
      any = true;
    }
  }
  if (any) words.push_back(word);
  return words;
}

std::optional<bool> ParseBool(const std::string& v) {
  if (v == "yes" || v == "true" || v == "on" || v == "1") return true;
  if (v == "no" || v == "false" || v == "off" || v == "0") return false;
  return std::nullopt;
}

int ErrnoFromName(const std::string& name) {
  if (!name.empty() && name.find_first_not_of("0123456789") == std::string::npos) {
    const long n = std::strtol(name.c_str(), nullptr, 10);
    return n > 0 && n < 4096 ? static_cast<int>(n) : -1;
  }
  for (int e = 1; e < 4096; ++e) {
    const char* n = strerrorname_np(e);
    if (n != nullptr && name == n) return e;
  }
  return -1;
}

// [Service] settings that manage the service rather than confine it.
const std::set<std::string> kNotSandboxing = {"Type",           "NotifyAccess",  "ExecStart",
                                              "ExecStartPre",   "ExecStartPost", "ExecReload",
                                              "ExecStop",       "ExecStopPost",  "TimeoutStartSec",
                                              "TimeoutStopSec", "TimeoutSec",    "WatchdogSec",
                                              "Restart",        "RestartSec",    "KillMode",
                                              "KillSignal",     "SendSIGKILL",   "RemainAfterExit",
                                              "StandardOutput", "StandardError", "SyslogIdentifier",
                                              "PIDFile"};

// Settings that confine the service but need systemd as PID 1 (or root on
// the host) to reproduce, with the reason.
const std::map<std::string, std::string> kNotReproduced = {
    {"User", "runs as the invoking user, in a user namespace, with no capabilities"},
    {"Group", "runs with the invoking user's group"},
    {"SupplementaryGroups", "setgroups() is denied in an unprivileged user namespace"},
    {"StateDirectoryMode", "the caller creates the state directory (--state-dir)"},
    {"ConfigurationDirectory", "nothing to apply: read-only anyway under ProtectSystem=strict"},
    {"ConfigurationDirectoryMode", "the caller creates the configuration files"},
    {"ProtectProc", "hidepid needs a /proc mounted for a PID namespace of our own"},
    {"RemoveIPC", "clean-up of the user's IPC objects at stop, not a confinement"},
    {"DevicePolicy", "a cgroup BPF device program: needs systemd's cgroup delegation"},
    {"DeviceAllow", "a cgroup BPF device program: needs systemd's cgroup delegation"},
    {"CPUWeight", "a cgroup resource control"},
    {"IOWeight", "a cgroup resource control"},
};

// Settings that are a plain yes/no.
const std::map<std::string, bool UnitSandbox::*> kBooleans = {
    {"PrivateTmp", &UnitSandbox::private_tmp},
    {"PrivateMounts", &UnitSandbox::private_mounts},
    {"NoNewPrivileges", &UnitSandbox::no_new_privileges},
    {"MemoryDenyWriteExecute", &UnitSandbox::memory_deny_write_execute},
    {"LockPersonality", &UnitSandbox::lock_personality},
    {"RestrictRealtime", &UnitSandbox::restrict_realtime},
    {"RestrictSUIDSGID", &UnitSandbox::restrict_suid_sgid},
    {"ProtectKernelTunables", &UnitSandbox::protect_kernel_tunables},
    {"ProtectKernelModules", &UnitSandbox::protect_kernel_modules},
    {"ProtectKernelLogs", &UnitSandbox::protect_kernel_logs},
    {"ProtectControlGroups", &UnitSandbox::protect_control_groups},
    {"ProtectClock", &UnitSandbox::protect_clock},
    {"ProtectHostname", &UnitSandbox::protect_hostname},
};

struct AddressFamilyName {
  const char* name;
  int family;
};
const AddressFamilyName kAddressFamilies[] = {
    {"AF_UNIX", AF_UNIX},
    {"AF_LOCAL", AF_LOCAL},
    {"AF_INET", AF_INET},
    {"AF_INET6", AF_INET6},
    {"AF_NETLINK", AF_NETLINK},
    {"AF_PACKET", AF_PACKET},
    {"AF_BLUETOOTH", AF_BLUETOOTH},
    {"AF_CAN", AF_CAN},
    {"AF_VSOCK", AF_VSOCK},
    {"AF_XDP", AF_XDP},
    {"AF_ALG", AF_ALG},
    {"AF_KEY", AF_KEY},
    {"AF_TIPC", AF_TIPC},
    {"AF_RDS", AF_RDS},
    {"AF_QIPCRTR", AF_QIPCRTR},
    {"AF_APPLETALK", AF_APPLETALK},
    {"AF_AX25", AF_AX25},
    {"AF_IPX", AF_IPX},
    {"AF_X25", AF_X25},
    {"AF_NFC", AF_NFC},
    {"AF_ATMPVC", AF_ATMPVC},
    {"AF_LLC", AF_LLC},
    {"AF_IEEE802154", AF_IEEE802154},
    {"AF_MCTP", 45},
};

}  // namespace

int AddressFamilyFromName(const std::string& name) {
  for (const AddressFamilyName& a : kAddressFamilies)
    if (name == a.name) return a.family;
  return -1;
}

bool ParseUnit(const std::string& text, UnitSandbox* out, std::string* error) {
  UnitSandbox u;
  std::istringstream in(text);
  std::string section, raw, line;
  int number = 0, line_of_setting = 0;
  while (std::getline(in, raw)) {
    ++number;
    if (line.empty()) line_of_setting = number;
    // A trailing backslash continues the setting on the next line.
    if (!raw.empty() && raw.back() == '\\') {
      line += raw.substr(0, raw.size() - 1) + " ";
      continue;
    }
    line += raw;
    const std::string l = Trim(line);
    line.clear();
    if (l.empty() || l[0] == '#' || l[0] == ';') continue;
    const std::string where = "line " + std::to_string(line_of_setting) + ": ";
    if (l.front() == '[') {
      if (l.back() != ']') {
        *error = where + "bad section header '" + l + "'";
        return false;
      }
      section = l.substr(1, l.size() - 2);
      continue;
    }
    if (section != "Service") continue;
    const auto eq = l.find('=');
    if (eq == std::string::npos) {
      *error = where + "expected Key=value, got '" + l + "'";
      return false;
    }
    const std::string key = Trim(l.substr(0, eq)), value = Trim(l.substr(eq + 1));
    const std::string setting = key + "=" + value;
    auto bad = [&](const std::string& why) {
      *error = where + setting + ": " + why;
      return false;
    };
    auto boolean = [&](bool* target) {
      const auto b = ParseBool(value);
      if (!b) return bad("expected a boolean (yes/no)");
      *target = *b;
      return true;
    };
    bool reproduced = true;
    if (kNotSandboxing.count(key)) {
      continue;
    } else if (const auto it = kNotReproduced.find(key); it != kNotReproduced.end()) {
      u.not_reproduced.push_back(setting + ": " + it->second);
      reproduced = false;
    } else if (const auto b = kBooleans.find(key); b != kBooleans.end()) {
      if (!boolean(&(u.*(b->second)))) return false;
    } else if (key == "ProtectSystem") {
      if (value != "strict" && ParseBool(value) != false)
        return bad("only ProtectSystem=strict (or no) is reproduced");
      u.protect_system = value == "strict" ? "strict" : "no";
    } else if (key == "ProtectHome") {
      const auto b = ParseBool(value);
      if (b) {
        u.protect_home = *b ? "yes" : "no";
      } else if (value == "read-only" || value == "tmpfs") {
        u.protect_home = value;
      } else {
        return bad("expected yes, no, read-only or tmpfs");
      }
    } else if (key == "CapabilityBoundingSet") {
      if (!value.empty()) return bad("only an empty bounding set (no capabilities) is reproduced");
      u.drop_all_capabilities = true;
    } else if (key == "SystemCallFilter") {
      SyscallFilterLine f;
      std::string v = value;
      if (!v.empty() && v[0] == '~') {
        f.invert = true;
        v = v.substr(1);
      }
      f.items = Words(v);
      for (const std::string& item : f.items)
        if (item.find(':') != std::string::npos)
          return bad("per-call error numbers are not reproduced");
      u.syscall_filter.push_back(std::move(f));
    } else if (key == "SystemCallErrorNumber") {
      if (value == "kill") {
        u.syscall_error_number.reset();
      } else {
        const int e = ErrnoFromName(value);
        if (e < 0) return bad("unknown error number");
        u.syscall_error_number = e;
      }
    } else if (key == "SystemCallArchitectures") {
      if (value != "native") return bad("only SystemCallArchitectures=native is reproduced");
      u.syscall_architectures_native = true;
    } else if (key == "RestrictNamespaces") {
      if (!boolean(&u.restrict_namespaces))
        return bad("only RestrictNamespaces=yes/no is reproduced (not a list of kinds)");
    } else if (key == "RestrictAddressFamilies") {
      std::string v = value;
      bool allow = true;
      if (!v.empty() && v[0] == '~') {
        allow = false;
        v = v.substr(1);
      }
      if (v.empty()) {
        u.address_families_set = false;
        u.address_families.clear();
      } else {
        if (u.address_families_set && allow != u.address_families_allow)
          return bad("mixing allow and deny lists is not reproduced");
        u.address_families_set = true;
        u.address_families_allow = allow;
        for (const std::string& name : Words(v)) {
          if (name == "none" && allow) continue;
          const int af = AddressFamilyFromName(name);
          if (af < 0) return bad("unknown address family " + name);
          u.address_families.insert(af);
        }
      }
    } else if (key == "UMask") {
      char* end = nullptr;
      const long m = std::strtol(value.c_str(), &end, 8);
      if (value.empty() || *end != '\0' || m < 0 || m > 0777) return bad("expected an octal mode");
      u.umask = static_cast<mode_t>(m);
    } else if (key == "Environment") {
      for (const std::string& word : Words(value)) {
        const auto at = word.find('=');
        if (at == std::string::npos || at == 0) return bad("expected NAME=value assignments");
        u.environment.emplace_back(word.substr(0, at), word.substr(at + 1));
      }
    } else if (key == "ReadWritePaths" || key == "ReadOnlyPaths") {
      for (std::string path : Words(value)) {
        if (!path.empty() && path[0] == '-') path = path.substr(1);
        if (path.empty() || path[0] != '/') return bad("expected absolute paths");
        (key == "ReadWritePaths" ? u.read_write_paths : u.read_only_paths).push_back(path);
      }
    } else if (key == "StateDirectory") {
      const auto names = Words(value);
      if (names.size() > 1) return bad("only one state directory is reproduced");
      u.state_directory = names.empty() ? "" : names[0];
    } else {
      return bad(
          "hardened-run does not know this setting: teach it (reproduce it, or list it "
          "as not reproduced with the reason) before the unit uses it");
    }
    if (reproduced) u.reproduced.push_back(setting);
  }
  *out = std::move(u);
  return true;
}

bool ParseSyscallGroups(const std::string& text, SyscallGroups* out, std::string* error) {
  SyscallGroups groups;
  std::istringstream in(text);
  std::string line, group;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') {
      group.clear();
      continue;
    }
    if (line[0] == '@') {
      group = Trim(line);
      groups[group];
      continue;
    }
    const std::string item = Trim(line);
    if (group.empty() || item.empty() || item[0] == '#') continue;
    groups[group].push_back(item);
  }
  if (groups.empty()) {
    *error = "no syscall group found in the systemd-analyze syscall-filter output";
    return false;
  }
  *out = std::move(groups);
  return true;
}

bool ExpandSyscallGroup(const SyscallGroups& groups, const std::string& item,
                        std::set<std::string>* names, std::string* error) {
  std::function<bool(const std::string&, int)> expand = [&](const std::string& i, int depth) {
    if (i.empty() || i[0] != '@') {
      if (!i.empty()) names->insert(i);
      return true;
    }
    const auto it = groups.find(i);
    if (it == groups.end() || depth > 16) {
      *error = "unknown syscall group " + i;
      return false;
    }
    for (const std::string& member : it->second)
      if (!expand(member, depth + 1)) return false;
    return true;
  };
  return expand(item, 0);
}

bool ResolveSyscallFilter(const std::vector<SyscallFilterLine>& lines, const SyscallGroups& groups,
                          bool* allow_list, std::set<std::string>* names, std::string* error) {
  std::set<std::string> set;
  std::optional<bool> allow;
  auto apply = [&](const std::string& item, bool add) {
    std::set<std::string> expanded;
    if (!ExpandSyscallGroup(groups, item, &expanded, error)) return false;
    for (const std::string& name : expanded) {
      if (add) {
        set.insert(name);
      } else {
        set.erase(name);
      }
    }
    return true;
  };
  for (const SyscallFilterLine& line : lines) {
    if (line.items.empty()) {
      set.clear();
      allow.reset();
      continue;
    }
    if (!allow) {
      allow = !line.invert;
      // An allow list always lets through what any process needs.
      if (*allow && !apply("@default", true)) return false;
    }
    const bool add = line.invert != *allow;
    for (const std::string& item : line.items)
      if (!apply(item, add)) return false;
  }
  *allow_list = allow.value_or(false);
  *names = std::move(set);
  return true;
}

}  // namespace craftscan::hardened
