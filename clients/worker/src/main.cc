// craftscan-worker: reconstruction for the stations of a site, over DDS
// (issue 21; the job loop is RunWorker, craftscan/worker/worker.h). This
// file is the process around it: arguments, the config, logging, signals
// and the service manager.
//
//   craftscan-worker [--config /etc/craftscan/craftscan-worker.yaml]
//                    [--print-config] [--check-config] [--version]
//
// Started by systemd (craftscan-worker.service, Type=notify): READY=1 once
// the worker is announced on its site, STATUS= with what it does, watchdog
// pings while the loop is alive, STOPPING=1 on SIGTERM. Exit codes: 0 after
// a clean stop, 1 when the loop fails (DDS cannot be set up), 2 for a bad
// command line or configuration (the message names the field).
#include <pthread.h>
#include <signal.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <mutex>
#include <string>
#include <thread>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>

#include "craftscan/daemon/notify.h"
#include "craftscan/pipeline/common/memory_policy.h"
#include "craftscan/worker/worker.h"
#include "worker_config.h"

namespace {

using namespace craftscan;
using Clock = std::chrono::steady_clock;

constexpr int kExitLoopFailed = 1;
constexpr int kExitBadConfig = 2;

void SetUpLogging(worker::WorkerLogLevel level) {
  spdlog::set_default_logger(spdlog::stderr_color_mt("craftscan-worker"));
  // As craftscand's.
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  switch (level) {
    case worker::WorkerLogLevel::kDebug:
      spdlog::set_level(spdlog::level::debug);
      break;
    case worker::WorkerLogLevel::kInfo:
      spdlog::set_level(spdlog::level::info);
      break;
    case worker::WorkerLogLevel::kWarning:
      spdlog::set_level(spdlog::level::warn);
      break;
    case worker::WorkerLogLevel::kError:
      spdlog::set_level(spdlog::level::err);
      break;
  }
}

void Log(int level, const std::string& message) {
  switch (level) {
    case 0:
      spdlog::debug("{}", message);
      break;
    case 1:
      spdlog::info("{}", message);
      break;
    case 2:
      spdlog::warn("{}", message);
      break;
    default:
      spdlog::error("{}", message);
      break;
  }
}

// Watchdog pings at half of systemd's WatchdogSec, from the loop's alive
// hook (called from any thread, at least once a second).
class WatchdogPinger {
 public:
  WatchdogPinger(const daemon::SystemdNotifier& notifier, bool enabled)
      : notifier_(notifier),
        interval_(enabled ? notifier.WatchdogPingInterval() : std::chrono::microseconds(0)) {}

  bool Active() const { return interval_.count() > 0; }
  std::chrono::microseconds interval() const { return interval_; }

  void Alive() {
    if (!Active()) return;
    std::lock_guard<std::mutex> lock(mutex_);
    const Clock::time_point now = Clock::now();
    if (pinged_ && now - last_ < interval_) return;
    std::string error;
    if (!notifier_.Watchdog(&error)) spdlog::warn("watchdog: {}", error);
    last_ = now;
    pinged_ = true;
  }

 private:
  const daemon::SystemdNotifier& notifier_;
  const std::chrono::microseconds interval_;
  std::mutex mutex_;
  Clock::time_point last_;
  bool pinged_ = false;
};

}  // namespace

int main(int argc, char** argv) {
  // Scans are reconstructed one after another: keep freed buffers
  // (memory_policy.h).
  craftscan::KeepFreedMemory();
  CLI::App app{"craftscan-worker: reconstructs scans for the stations of a site (over DDS)"};
  std::string config_path = "/etc/craftscan/craftscan-worker.yaml";
  bool print_config = false, check_config = false;
  app.add_option("-c,--config", config_path, "configuration file (YAML, version 1)");
  app.add_flag("--print-config", print_config,
               "print the effective configuration (file + CRAFTSCAN_WORKER_* overrides) and exit");
  app.add_flag("--check-config", check_config,
               "validate the configuration and the token file, and exit");
  app.set_version_flag("--version", std::string("craftscan-worker ") + CRAFTSCAN_VERSION);
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "craftscan-worker: %s (see --help)\n", e.what());
    return kExitBadConfig;
  }

  worker::WorkerConfig config;
  std::string error;
  if (!worker::LoadWorkerConfig(config_path, &config, &error)) {
    std::fprintf(stderr, "craftscan-worker: %s\n", error.c_str());
    return kExitBadConfig;
  }
  if (print_config) {
    std::fputs(worker::DumpWorkerConfig(config).c_str(), stdout);
    return 0;
  }
  worker::WorkerOptions options;
  if (!worker::MakeWorkerOptions(config, &options, &error)) {
    std::fprintf(stderr, "craftscan-worker: %s: %s\n", config_path.c_str(), error.c_str());
    return kExitBadConfig;
  }
  if (check_config) {
    std::printf("craftscan-worker: %s is valid\n", config_path.c_str());
    return 0;
  }
  SetUpLogging(config.log_level);

  // Signals go to one thread (sigtimedwait) before any other thread exists.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  const daemon::SystemdNotifier notifier;
  WatchdogPinger watchdog(notifier, config.watchdog.enabled);
  std::atomic<bool> stop{false}, done{false};
  std::thread signal_thread([&] {
    const timespec wait = {0, 200 * 1000 * 1000};
    while (!done.load()) {
      const int sig = sigtimedwait(&signals, nullptr, &wait);
      if (sig == SIGTERM || sig == SIGINT) {
        spdlog::info("signal {}: stopping", sig);
        notifier.Stopping("stopping");
        stop = true;
        return;
      }
    }
  });

  spdlog::info("craftscan-worker {}: worker '{}' on site '{}', DDS domain {}, {} thread(s){}",
               CRAFTSCAN_VERSION, options.worker_id, options.site, options.domain, options.threads,
               watchdog.Active() ? ", watchdog every " +
                                       std::to_string(watchdog.interval().count() / 1000) + " ms"
                                 : "");
  worker::WorkerHooks hooks;
  hooks.ready = [&] {
    notifier.Ready("worker " + options.worker_id + " on site " + options.site);
    spdlog::info("ready: announced on site '{}'", options.site);
  };
  hooks.status = [&](const std::string& status) { notifier.Status(status); };
  hooks.alive = [&] { watchdog.Alive(); };
  hooks.log = Log;
  const int code = worker::RunWorker(options, stop, hooks, &error);
  done = true;
  signal_thread.join();
  if (code != 0) {
    spdlog::critical("{}", error.empty() ? "the job loop failed" : error);
    notifier.Stopping("failed: " + error);
    return kExitLoopFailed;
  }
  spdlog::info("stopped");
  return 0;
}
