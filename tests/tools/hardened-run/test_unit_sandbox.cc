// hardened-run's unit-file model: the real craftscand.service parses into the
// sandbox it declares, unknown or unsupported confining settings are refused
// with the line named, and SystemCallFilter= lines merge as systemd merges
// them.
#include <gtest/gtest.h>

#include <sys/socket.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "file_util.h"
#include "test_paths.h"
#include "unit_sandbox.h"

namespace craftscan::hardened {
namespace {

using ::craftscan::testing::ReadFile;

bool Has(const std::vector<std::string>& list, const std::string& prefix) {
  return std::any_of(list.begin(), list.end(),
                     [&](const std::string& s) { return s.rfind(prefix, 0) == 0; });
}

TEST(HardenedUnit, CraftscandServiceKeepsItsHardening) {
  const std::string text = ReadFile(::craftscan::testing::UnitFilePath());
  ASSERT_FALSE(text.empty()) << ::craftscan::testing::UnitFilePath();
  UnitSandbox u;
  std::string error;
  ASSERT_TRUE(ParseUnit(text, &u, &error)) << error;
  EXPECT_EQ(u.protect_system, "strict");
  EXPECT_EQ(u.protect_home, "yes");
  EXPECT_TRUE(u.private_tmp);
  EXPECT_TRUE(u.private_mounts);
  EXPECT_TRUE(u.no_new_privileges);
  EXPECT_TRUE(u.drop_all_capabilities);
  EXPECT_TRUE(u.memory_deny_write_execute);
  EXPECT_TRUE(u.lock_personality);
  EXPECT_TRUE(u.restrict_realtime);
  EXPECT_TRUE(u.restrict_suid_sgid);
  EXPECT_TRUE(u.restrict_namespaces);
  EXPECT_TRUE(u.syscall_architectures_native);
  EXPECT_TRUE(u.protect_kernel_tunables);
  EXPECT_TRUE(u.protect_kernel_modules);
  EXPECT_TRUE(u.protect_kernel_logs);
  EXPECT_TRUE(u.protect_control_groups);
  EXPECT_TRUE(u.protect_clock);
  EXPECT_TRUE(u.protect_hostname);
  ASSERT_TRUE(u.syscall_error_number.has_value());
  EXPECT_EQ(*u.syscall_error_number, EPERM);
  ASSERT_EQ(u.syscall_filter.size(), 2u);
  EXPECT_FALSE(u.syscall_filter[0].invert);
  EXPECT_EQ(u.syscall_filter[0].items, std::vector<std::string>{"@system-service"});
  EXPECT_TRUE(u.syscall_filter[1].invert);
  EXPECT_EQ(u.syscall_filter[1].items, std::vector<std::string>{"@privileged"});
  EXPECT_TRUE(u.address_families_set);
  EXPECT_TRUE(u.address_families_allow);
  EXPECT_EQ(u.address_families, (std::set<int>{AF_UNIX, AF_INET, AF_INET6, AF_NETLINK}));
  ASSERT_TRUE(u.umask.has_value());
  EXPECT_EQ(*u.umask, 0027u);
  EXPECT_EQ(u.state_directory, "craftscan");
  EXPECT_TRUE(
      std::count(u.environment.begin(), u.environment.end(),
                 std::make_pair(std::string("OPENCV_OPENCL_DEVICE"), std::string("disabled"))));
  // What cannot be reproduced is said, with the reason.
  EXPECT_TRUE(Has(u.not_reproduced, "DevicePolicy=closed: "));
  EXPECT_TRUE(Has(u.not_reproduced, "ProtectProc=invisible: "));
  EXPECT_TRUE(Has(u.not_reproduced, "User=craftscan: "));
  EXPECT_TRUE(Has(u.reproduced, "MemoryDenyWriteExecute=yes"));
}

TEST(HardenedUnit, RefusesWhatItCannotReproduceNamingTheLine) {
  struct Case {
    std::string text, expected;
  };
  const std::vector<Case> cases = {
      {"[Service]\nPrivateNetwork=yes\n", "line 2: PrivateNetwork=yes: hardened-run does not know"},
      {"[Service]\nProtectSystem=full\n", "line 2: ProtectSystem=full: only ProtectSystem=strict"},
      {"[Service]\nCapabilityBoundingSet=CAP_NET_RAW\n", "only an empty bounding set"},
      {"[Service]\nRestrictAddressFamilies=AF_NOPE\n", "unknown address family AF_NOPE"},
      {"[Service]\nSystemCallFilter=@system-service:EPERM\n", "per-call error numbers"},
      {"[Service]\nSystemCallErrorNumber=EWHATEVER\n", "unknown error number"},
      {"[Service]\nUMask=0999\n", "expected an octal mode"},
      {"[Service]\nNoNewPrivileges=maybe\n", "expected a boolean"},
      {"[Service]\nRestrictNamespaces=net\n", "only RestrictNamespaces=yes/no"},
      {"[Service]\nEnvironment=NOVALUE\n", "expected NAME=value"},
      {"[Service\n", "line 1: bad section header"},
      {"[Service]\njust words\n", "line 2: expected Key=value"},
  };
  for (const Case& c : cases) {
    UnitSandbox u;
    std::string error;
    EXPECT_FALSE(ParseUnit(c.text, &u, &error)) << c.text;
    EXPECT_NE(error.find(c.expected), std::string::npos) << c.text << " -> " << error;
  }
  // Outside [Service], and service management, nothing is judged.
  UnitSandbox u;
  std::string error;
  EXPECT_TRUE(
      ParseUnit("[Unit]\nPrivateNetwork=yes\n[Service]\nType=notify\nRestart=always\n"
                "NoNewPrivileges=\\\n  yes\n",
                &u, &error))
      << error;
  EXPECT_TRUE(u.no_new_privileges);
}

TEST(HardenedUnit, SyscallFilterLinesMergeAsSystemdMergesThem) {
  const std::string listing =
      "@default\n    # always\n    exit\n    read\n\n"
      "@basic-io\n    # io\n    read\n    write\n\n"
      "@privileged\n    # priv\n    @chown\n    setuid\n\n"
      "@chown\n    # chown\n    chown\n    fchown\n\n"
      "@system-service\n    # svc\n    @basic-io\n    @chown\n    setuid\n    ioctl\n\n"
      "# Ungrouped System Calls:\n#   syslog\n";
  SyscallGroups groups;
  std::string error;
  ASSERT_TRUE(ParseSyscallGroups(listing, &groups, &error)) << error;
  EXPECT_EQ(groups.size(), 5u);
  bool allow = false;
  std::set<std::string> names;
  ASSERT_TRUE(ResolveSyscallFilter({{false, {"@system-service"}}, {true, {"@privileged"}}}, groups,
                                   &allow, &names, &error))
      << error;
  EXPECT_TRUE(allow);
  // @default is implied; @privileged (with its nested @chown) taken out.
  EXPECT_EQ(names, (std::set<std::string>{"exit", "read", "write", "ioctl"}));
  // A deny list first: plain lines then take names out of it.
  ASSERT_TRUE(ResolveSyscallFilter({{true, {"@chown", "setuid"}}, {false, {"fchown"}}}, groups,
                                   &allow, &names, &error));
  EXPECT_FALSE(allow);
  EXPECT_EQ(names, (std::set<std::string>{"chown", "setuid"}));
  // An empty line resets.
  ASSERT_TRUE(ResolveSyscallFilter({{true, {"@chown"}}, {false, {}}, {false, {"ioctl"}}}, groups,
                                   &allow, &names, &error));
  EXPECT_TRUE(allow);
  EXPECT_EQ(names, (std::set<std::string>{"exit", "read", "ioctl"}));
  EXPECT_FALSE(ResolveSyscallFilter({{false, {"@nope"}}}, groups, &allow, &names, &error));
  EXPECT_NE(error.find("unknown syscall group @nope"), std::string::npos) << error;
  EXPECT_FALSE(ParseSyscallGroups("nothing here\n", &groups, &error));
}

}  // namespace
}  // namespace craftscan::hardened
