// Fuzz target: ParseDaemonConfig (daemon/config.h). The input is the YAML
// text, optionally followed by a NUL byte and environment entries
// "NAME=value", one per line. Properties: a success is a config that passes
// IsValid and whose dump parses back to the same dump; a failure names the
// problem and leaves the output config as it was.
#include <map>
#include <string>
#include <string_view>

#include "craftscan/daemon/config.h"
#include "fuzz_target.h"

CRAFTSCAN_FUZZ_TARGET(config) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  const std::size_t nul = input.find('\0');
  const std::string yaml(input.substr(0, nul));
  std::map<std::string, std::string> env;
  if (nul != std::string_view::npos) {
    std::string_view rest = input.substr(nul + 1);
    while (!rest.empty()) {
      const std::size_t end = rest.find('\n');
      const std::string_view line = rest.substr(0, end);
      const std::size_t eq = line.find('=');
      if (eq != std::string_view::npos) {
        env[std::string(line.substr(0, eq))] = std::string(line.substr(eq + 1));
      }
      if (end == std::string_view::npos) break;
      rest.remove_prefix(end + 1);
    }
  }

  daemon::DaemonConfig config;
  config.station = "sentinel";  // must survive a failure
  config.scan.views = 77;
  std::string error;
  if (!Outcome(daemon::ParseDaemonConfig(yaml, env, &config, &error), error)) {
    CRAFTSCAN_FUZZ_CHECK(config.station == "sentinel" && config.scan.views == 77);
    return 0;
  }
  std::string why;
  CRAFTSCAN_FUZZ_CHECK(config.IsValid(&why));
  // DumpDaemonConfig's contract: the dump parses back to the same config.
  const std::string dump = daemon::DumpDaemonConfig(config);
  daemon::DaemonConfig again;
  if (!daemon::ParseDaemonConfig(dump, {}, &again, &error)) {
    CheckFailed(("the dump parses back (" + error + ")").c_str(), __FILE__, __LINE__);
  }
  CRAFTSCAN_FUZZ_CHECK(daemon::DumpDaemonConfig(again) == dump);
  return 0;
}
