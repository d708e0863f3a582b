// craftscand: parses arguments, loads the config, builds the service and
// runs it (DESIGN.md "Layout"). SIGTERM and SIGINT stop it cleanly.
#include <pthread.h>
#include <signal.h>

#include <cstdio>
#include <string>
#include <thread>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>

#include "craftscan/daemon/config.h"
#include "craftscan/daemon/daemon.h"
#include "craftscan/pipeline/common/memory_policy.h"

int main(int argc, char** argv) {
  // Views are matched over and over: keep freed buffers (memory_policy.h).
  craftscan::KeepFreedMemory();
  CLI::App app{"craftscand: the craftscan station daemon (cameras, turntable, pipeline, DDS)"};
  std::string config_path = "/etc/craftscan/craftscand.yaml";
  bool print_config = false, check_config = false;
  app.add_option("-c,--config", config_path, "configuration file (YAML, version 1)");
  app.add_flag("--print-config", print_config,
               "print the effective configuration (file + CRAFTSCAN_* overrides) and exit");
  app.add_flag("--check-config", check_config, "validate the configuration and exit");
  CLI11_PARSE(app, argc, argv);

  craftscan::daemon::DaemonConfig config;
  std::string error;
  if (!craftscan::daemon::LoadDaemonConfig(config_path, &config, &error)) {
    std::fprintf(stderr, "craftscand: %s\n", error.c_str());
    return 2;
  }
  if (print_config) {
    std::fputs(craftscan::daemon::DumpDaemonConfig(config).c_str(), stdout);
    return 0;
  }
  if (check_config) {
    std::printf("craftscand: %s is valid\n", config_path.c_str());
    return 0;
  }
  auto logger = spdlog::stderr_color_mt("craftscand");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  switch (config.log_level) {
    case craftscan::daemon::LogLevel::kDebug:
      spdlog::set_level(spdlog::level::debug);
      break;
    case craftscan::daemon::LogLevel::kInfo:
      spdlog::set_level(spdlog::level::info);
      break;
    case craftscan::daemon::LogLevel::kWarning:
      spdlog::set_level(spdlog::level::warn);
      break;
    case craftscan::daemon::LogLevel::kError:
      spdlog::set_level(spdlog::level::err);
      break;
  }

  // Signals go to one thread (sigwait) before any other thread exists.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  std::unique_ptr<craftscan::daemon::Daemon> daemon =
      craftscan::daemon::Daemon::Create(config, &error);
  if (!daemon) {
    spdlog::critical("cannot start: {}", error);
    return 1;
  }
  std::thread signal_thread([&] {
    int signal_number = 0;
    sigwait(&signals, &signal_number);
    if (signal_number != 0) {
      spdlog::info("signal {}: stopping", signal_number);
      daemon->RequestStop();
    }
  });
  const int code = daemon->Run();
  // Wake the signal thread if the loop ended for another reason.
  pthread_kill(signal_thread.native_handle(), SIGTERM);
  signal_thread.join();
  return code;
}
