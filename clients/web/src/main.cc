// craftscan-web: the station console in a browser (issue 17, API.md).
//
//   craftscan-web [--config /etc/craftscan/web.yaml] [--listen HOST:PORT]
//
// Started by systemd (craftscan-web.service, Type=notify): READY=1 once it
// listens, watchdog pings while it runs, STOPPING=1 on SIGTERM.
#include <signal.h>

#include <chrono>
#include <cstdio>
#include <thread>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>

#include "craftscan/daemon/notify.h"
#include "craftscan/web/console.h"
#include "craftscan/web/http_server.h"
#include "craftscan/web/web_config.h"

int main(int argc, char** argv) {
  using namespace craftscan;
  CLI::App app{"craftscan-web: the station console in a browser (HTTP + WebSocket over DDS)"};
  std::string config_path = "/etc/craftscan/web.yaml";
  std::string listen;
  app.add_option("--config", config_path, "Configuration file (YAML, version: 1)");
  app.add_option("--listen", listen, "HOST:PORT to listen on instead of the config's `listen`");
  app.set_version_flag("--version", std::string(CRAFTSCAN_VERSION));
  CLI11_PARSE(app, argc, argv);

  auto logger = spdlog::stderr_color_mt("craftscan-web");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");

  web::WebConfig config;
  std::string error;
  if (!web::LoadWebConfig(config_path, &config, &error)) {
    spdlog::critical("{}", error);
    return 2;
  }
  if (!listen.empty() &&
      !web::ParseListen(listen, &config.listen_host, &config.listen_port, &error)) {
    spdlog::critical("--listen: {}", error);
    return 2;
  }

  // Signals are taken by sigwait below, in this thread only.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  auto console = web::Console::Create(config, &error);
  if (!console) {
    spdlog::critical("{}", error);
    return 1;
  }
  auto server = web::HttpServer::Start(console.get(), &error);
  if (!server) {
    spdlog::critical("{}", error);
    return 1;
  }
  const std::string url =
      std::string(config.tls() ? "https://" : "http://") +
      (config.listen_host.find(':') != std::string::npos ? "[" + config.listen_host + "]"
                                                         : config.listen_host) +
      ":" + std::to_string(server->port()) + "/";
  spdlog::info("serving the console of {} station(s) at {}", config.stations.size(), url);
  std::printf("craftscan-web: listening on %s\n", url.c_str());
  std::fflush(stdout);

  const daemon::SystemdNotifier notifier;
  notifier.Ready("console at " + url);
  const auto ping = notifier.WatchdogPingInterval();
  const timespec wait = {0, 500 * 1000 * 1000};
  auto last_ping = std::chrono::steady_clock::now();
  while (true) {
    const int sig = sigtimedwait(&signals, nullptr, &wait);
    if (sig == SIGINT || sig == SIGTERM) {
      spdlog::info("signal {}: stopping", sig);
      break;
    }
    if (ping.count() > 0 && std::chrono::steady_clock::now() - last_ping >= ping) {
      notifier.Watchdog();
      last_ping = std::chrono::steady_clock::now();
    }
  }
  notifier.Stopping("stopping");
  server.reset();
  console.reset();
  return 0;
}
