// craftscan-bench subcommands. Each lives in its own file and is listed once
// in main.cc; main() only parses arguments and dispatches.
//
// Adding a subcommand (e.g. `calib`): write calib_bench.cc with a class
// derived from BenchCommand, declare its factory below, add one line to
// main.cc's list and the file to bench/CMakeLists.txt.
#pragma once

#include <memory>

namespace CLI {
class App;
}  // namespace CLI

namespace craftscan::bench {

// Process exit codes shared by every subcommand.
inline constexpr int kExitOk = 0;
inline constexpr int kExitDataError = 1;  // missing/malformed data, a failed run, I/O error
inline constexpr int kExitUsage = 2;      // bad command line

class BenchCommand {
 public:
  virtual ~BenchCommand() = default;
  // Adds the subcommand and its options to `app` (options bind to members of
  // this object) and returns it. Called once, before parsing.
  virtual CLI::App* Register(CLI::App* app) = 0;
  // Runs after a successful parse that selected this subcommand. Reports
  // errors on stderr and returns an exit code above; must not throw.
  virtual int Run() = 0;
};

// One factory per subcommand.
std::unique_ptr<BenchCommand> MakeStereoCommand();
std::unique_ptr<BenchCommand> MakeCalibCommand();
std::unique_ptr<BenchCommand> MakeSimDepthCommand();
std::unique_ptr<BenchCommand> MakeRegistrationCommand();
std::unique_ptr<BenchCommand> MakeDdsCommand();
std::unique_ptr<BenchCommand> MakeScanCommand();
std::unique_ptr<BenchCommand> MakeTurnJoinCommand();
// Built with the tests only (it runs on their site harness).
std::unique_ptr<BenchCommand> MakeSiteCommand();

}  // namespace craftscan::bench
