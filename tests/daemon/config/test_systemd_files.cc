// The files in systemd/: the units pass `systemd-analyze verify` with no
// parse warnings, the sysusers entry is accepted by systemd-sysusers (dry run
// on an empty root), the udev rules are well-formed, and the files agree
// with each other (user, groups, config path). Tools that are missing skip
// the test with the reason.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "../../unit/test_util.h"
#include "file_util.h"
#include "test_paths.h"

namespace craftscan {
namespace {

using ::testing::HasSubstr;
namespace fs = std::filesystem;

const fs::path kSystemdDir = ::craftscan::testing::SystemdDir();

using testing::ReadFile;

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

// The absolute path of `tool` on PATH (plus the sbin directories), or "".
std::string FindTool(const std::string& tool) {
  std::string path = std::getenv("PATH") ? std::getenv("PATH") : "";
  path += ":/usr/bin:/bin:/usr/sbin:/sbin";
  std::istringstream in(path);
  for (std::string dir; std::getline(in, dir, ':');) {
    if (dir.empty()) continue;
    const fs::path candidate = fs::path(dir) / tool;
    if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return "";
}

struct ToolRun {
  int exit_code = -1;
  std::string out, err;
};

// Runs `command` (a shell command line, arguments already quoted) with
// stdout and stderr captured into files in `dir`.
ToolRun RunTool(const std::string& command, const fs::path& dir) {
  const fs::path out = dir / "tool.out", err = dir / "tool.err";
  const std::string line = command + " </dev/null >'" + out.string() + "' 2>'" + err.string() + "'";
  const int status = std::system(line.c_str());
  ToolRun run;
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  run.out = ReadFile(out);
  run.err = ReadFile(err);
  return run;
}

// Lines of systemd-analyze's stderr that report a problem in `unit`:
// parse errors and unknown settings are warnings that name the file, e.g.
// "/tmp/x/craftscand.service:12: Unknown key 'Bogus' in section [Service], ignoring."
std::vector<std::string> UnitProblems(const std::string& stderr_text, const std::string& unit) {
  static const std::regex kProblem(
      "Unknown|unknown|Failed to parse|Invalid|invalid|ignoring|not executable|Missing|"
      "[Ee]rror|deprecated|Assignment outside of section");
  std::vector<std::string> problems;
  for (const std::string& line : Lines(stderr_text)) {
    if (line.find(unit) != std::string::npos || std::regex_search(line, kProblem)) {
      problems.push_back(line);
    }
  }
  return problems;
}

class SystemdFiles : public testing::TempDirTest {
 protected:
  // The unit with ExecStart's binary replaced by an existing one (verify
  // checks that the binary is executable; craftscand is not installed here).
  std::string TestableUnit(const std::string& binary = "craftscand") {
    std::string unit = ReadFile(kSystemdDir / (binary + ".service"));
    const std::string exec = "ExecStart=/usr/bin/" + binary + " ";
    const auto at = unit.find(exec);
    EXPECT_NE(at, std::string::npos);
    if (at != std::string::npos && ::access(("/usr/bin/" + binary).c_str(), X_OK) != 0) {
      unit.replace(at, exec.size(), "ExecStart=/bin/true ");
    }
    return unit;
  }

  ToolRun Verify(const std::string& unit_text, const std::string& name = "craftscand.service") {
    const std::string unit = WriteBytes(name, unit_text);
    return RunTool("'" + analyze_ + "' verify --man=no '" + unit + "'", dir_);
  }

  void SetUp() override {
    TempDirTest::SetUp();
    analyze_ = FindTool("systemd-analyze");
  }
  std::string analyze_;
};

TEST_F(SystemdFiles, UnitPassesSystemdAnalyzeVerify) {
  if (analyze_.empty()) GTEST_SKIP() << "systemd-analyze not installed (package systemd)";
  const ToolRun run = Verify(TestableUnit());
  EXPECT_EQ(run.exit_code, 0) << run.err;
  EXPECT_THAT(UnitProblems(run.err, Path("craftscand.service")), ::testing::IsEmpty())
      << "systemd-analyze verify:\n"
      << run.err;
  if (!run.err.empty()) std::cout << "systemd-analyze verify said:\n" << run.err;
}

// The console's unit beside it: verified the same way, a notify service
// reading /etc/craftscan/web.yaml (the shipped craftscan-web.yaml).
TEST_F(SystemdFiles, ConsoleUnitPassesSystemdAnalyzeVerify) {
  const std::string text = TestableUnit("craftscan-web");
  EXPECT_THAT(text, HasSubstr("--config /etc/craftscan/web.yaml"));
  EXPECT_THAT(text, HasSubstr("Type=notify"));
  EXPECT_THAT(text, HasSubstr("WatchdogSec="));
  if (analyze_.empty()) GTEST_SKIP() << "systemd-analyze not installed (package systemd)";
  const ToolRun run = Verify(text, "craftscan-web.service");
  EXPECT_EQ(run.exit_code, 0) << run.err;
  EXPECT_THAT(UnitProblems(run.err, Path("craftscan-web.service")), ::testing::IsEmpty())
      << "systemd-analyze verify:\n"
      << run.err;
}

// craftscan-worker's unit (issue 21): verified the same way; a notify
// service with a watchdog, reading /etc/craftscan/craftscan-worker.yaml,
// with the station's hardening and its scratch folder as StateDirectory
// (the example config's work_dir).
TEST_F(SystemdFiles, WorkerUnitPassesSystemdAnalyzeVerify) {
  const std::string unit = ReadFile(kSystemdDir / "craftscan-worker.service");
  for (const char* setting :
       {"Type=notify\n", "NotifyAccess=main\n",
        "ExecStart=/usr/bin/craftscan-worker --config /etc/craftscan/craftscan-worker.yaml\n",
        "WatchdogSec=", "Restart=on-failure\n", "User=craftscan\n",
        "StateDirectory=craftscan-worker\n",
        "Environment=CYCLONEDDS_URI=file:///etc/craftscan/cyclonedds.xml\n",
        "ProtectSystem=strict\n", "MemoryDenyWriteExecute=yes\n", "PrivateDevices=yes\n",
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK\n"}) {
    EXPECT_THAT(unit, HasSubstr(setting));
  }
  EXPECT_THAT(ReadFile(kSystemdDir / "craftscan-worker.yaml"),
              HasSubstr("\nwork_dir: /var/lib/craftscan-worker\n"));
  if (analyze_.empty()) GTEST_SKIP() << "systemd-analyze not installed (package systemd)";
  const ToolRun run = Verify(TestableUnit("craftscan-worker"), "craftscan-worker.service");
  EXPECT_EQ(run.exit_code, 0) << run.err;
  // Parse problems are only warnings: nothing at all on stderr.
  EXPECT_EQ(run.err, "");
  EXPECT_THAT(UnitProblems(run.err, Path("craftscan-worker.service")), ::testing::IsEmpty())
      << "systemd-analyze verify:\n"
      << run.err;
}

// The check above can fail: a misspelt setting is caught.
TEST_F(SystemdFiles, VerifyCatchesAnUnknownSetting) {
  if (analyze_.empty()) GTEST_SKIP() << "systemd-analyze not installed (package systemd)";
  std::string unit = TestableUnit();
  unit.replace(unit.find("ProtectHome=yes"), 15, "ProtectHomes=yes");
  const ToolRun run = Verify(unit);
  const auto problems = UnitProblems(run.err, Path("craftscand.service"));
  ASSERT_EQ(problems.size(), 1u) << run.err;
  EXPECT_THAT(problems[0], HasSubstr("ProtectHomes"));
}

TEST_F(SystemdFiles, UnitRunsTheDaemonAsDocumented) {
  const std::string unit = ReadFile(kSystemdDir / "craftscand.service");
  for (const char* setting :
       {"Type=notify\n", "NotifyAccess=main\n",
        "ExecStart=/usr/bin/craftscand --config /etc/craftscan/craftscand.yaml\n",
        "WatchdogSec=30\n", "Restart=on-failure\n", "User=craftscan\n",
        "SupplementaryGroups=plugdev dialout\n", "StateDirectory=craftscan\n",
        "ConfigurationDirectory=craftscan\n", "ProtectSystem=strict\n",
        "MemoryDenyWriteExecute=yes\n", "DevicePolicy=closed\n",
        "RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK\n"}) {
    EXPECT_THAT(unit, HasSubstr(setting));
  }
}

TEST_F(SystemdFiles, SysusersCreatesTheUserAndGroups) {
  const std::string sysusers = FindTool("systemd-sysusers");
  if (sysusers.empty()) GTEST_SKIP() << "systemd-sysusers not installed (package systemd)";
  // A dry run against an empty root: reads nothing of this machine's accounts
  // and writes nothing.
  fs::create_directories(dir_ / "root" / "etc");
  const ToolRun run = RunTool("'" + sysusers + "' --dry-run --root='" + (dir_ / "root").string() +
                                  "' '" + (kSystemdDir / "craftscan.sysusers").string() + "'",
                              dir_);
  const std::string all = run.out + run.err;
  EXPECT_EQ(run.exit_code, 0) << all;
  EXPECT_THAT(all, HasSubstr("Creating user 'craftscan'"));
  EXPECT_THAT(all, HasSubstr("Creating group 'plugdev'"));
  EXPECT_THAT(all, HasSubstr("Creating group 'dialout'"));
  EXPECT_THAT(all, ::testing::Not(::testing::ContainsRegex("Unknown|Failed|ignoring|[Ii]nvalid")))
      << all;
}

// udevadm verify needs systemd ≥ 254 (Debian 12 has 252, without udevadm
// here): check the rule syntax ourselves.
TEST_F(SystemdFiles, UdevRulesAreWellFormed) {
  const fs::path rules = kSystemdDir / "udev" / "70-craftscan-cameras.rules";
  const std::string text = ReadFile(rules);
  ASSERT_FALSE(text.empty()) << rules;
  // KEY or KEY{attr}, an operator, a double-quoted value.
  static const std::regex kPair(
      R"re(^(ACTION|SUBSYSTEM|SUBSYSTEMS|DEVTYPE|KERNEL|DRIVER|DRIVERS|ATTR|ATTRS|ENV|TAG|TAGS|)re"
      R"re(GROUP|OWNER|MODE|IMPORT|GOTO|LABEL|RUN|SYMLINK)(\{[A-Za-z0-9_]+\})?(==|!=|\+=|-=|:=|=)"[^"]*"$)re");
  std::set<std::string> labels, gotos;
  int rules_with_group = 0;
  for (const std::string& line : Lines(text)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream in(line);
    for (std::string pair; std::getline(in, pair, ',');) {
      while (!pair.empty() && pair.front() == ' ') pair.erase(0, 1);
      EXPECT_TRUE(std::regex_match(pair, kPair)) << "bad pair '" << pair << "' in: " << line;
      if (pair.rfind("LABEL=", 0) == 0) labels.insert(pair.substr(7, pair.size() - 8));
      if (pair.rfind("GOTO=", 0) == 0) gotos.insert(pair.substr(6, pair.size() - 7));
    }
    if (line.find("GROUP=\"plugdev\"") != std::string::npos) {
      ++rules_with_group;
      EXPECT_THAT(line, HasSubstr("MODE=\"0660\""));
      EXPECT_THAT(line, HasSubstr("TAG+=\"uaccess\""));
    }
  }
  EXPECT_EQ(gotos, labels);
  EXPECT_GE(rules_with_group, 2);
  // The USB3 Vision interface class match (0xEF / 0x05 / 0x00).
  EXPECT_THAT(text, HasSubstr("ENV{ID_USB_INTERFACES}==\"*:ef0500:*\""));
}

TEST_F(SystemdFiles, FilesAgreeOnUserAndGroups) {
  const std::string unit = ReadFile(kSystemdDir / "craftscand.service");
  const std::string sysusers = ReadFile(kSystemdDir / "craftscan.sysusers");
  const std::string rules = ReadFile(kSystemdDir / "udev" / "70-craftscan-cameras.rules");
  EXPECT_TRUE(std::regex_search(sysusers, std::regex(R"((^|\n)u\s+craftscan\s)")));
  EXPECT_TRUE(std::regex_search(sysusers, std::regex(R"((^|\n)m\s+craftscan\s+plugdev)")));
  EXPECT_TRUE(std::regex_search(sysusers, std::regex(R"((^|\n)m\s+craftscan\s+dialout)")));
  EXPECT_THAT(unit, HasSubstr("plugdev"));
  EXPECT_THAT(rules, HasSubstr("GROUP=\"plugdev\""));
  // The unit's StateDirectory is the sysusers home and the example data_dir.
  EXPECT_THAT(sysusers, HasSubstr("/var/lib/craftscan"));
  EXPECT_THAT(ReadFile(kSystemdDir / "craftscand.yaml"), HasSubstr("data_dir: /var/lib/craftscan"));
}

}  // namespace
}  // namespace craftscan
