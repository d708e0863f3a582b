// craftscan-bench: benchmarks on shared data. Thin: parse, dispatch, exit.
#include <exception>
#include <iostream>
#include <memory>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>

#include "command.h"
#include "craftscan/pipeline/common/memory_policy.h"

int main(int argc, char** argv) {
  using namespace craftscan::bench;
  // Matching reuses its freed buffers rather than fault them in afresh
  // (memory_policy.h): as craftscand and craftscan-worker do.
  craftscan::KeepFreedMemory();
  CLI::App app{"craftscan benchmarks on shared data (Middlebury stereo, calibration, bunny, ...)",
               "craftscan-bench"};
  app.require_subcommand(1);

  std::vector<std::unique_ptr<BenchCommand>> commands;
  commands.push_back(MakeStereoCommand());
  commands.push_back(MakeCalibCommand());
  commands.push_back(MakeSimDepthCommand());
  commands.push_back(MakeRegistrationCommand());
  commands.push_back(MakeDdsCommand());
  commands.push_back(MakeScanCommand());
  commands.push_back(MakeTurnJoinCommand());
#ifdef CRAFTSCAN_BENCH_SITE
  commands.push_back(MakeSiteCommand());
#endif

  std::vector<std::pair<CLI::App*, BenchCommand*>> registered;
  for (auto& command : commands) registered.emplace_back(command->Register(&app), command.get());

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // Help/version exit 0 (printed by exit()); every other parse error is usage.
    return app.exit(e) == 0 ? kExitOk : kExitUsage;
  }
  for (auto& [sub, command] : registered) {
    if (!sub->parsed()) continue;
    try {
      return command->Run();
    } catch (const std::exception& e) {  // Run() should not throw; never crash if it does
      std::cerr << "craftscan-bench: " << sub->get_name() << ": unexpected error: " << e.what()
                << "\n";
      return kExitDataError;
    }
  }
  return kExitUsage;  // unreachable: require_subcommand(1)
}
