// A station for the console's browser tests: craftscand on the simulated
// station (DaemonFixture: 640x512, the sim rig's exact calibration, tokens
// for the three roles, a private loopback DDS domain) with craftscan-web's
// server in this process in front of it on a free port.
//
//   console_station --assets DIR [--sim-extra ", key: value..."] [--calibration YAML]
//
// --sim-extra: more sim driver keys (DaemonFixture's extra_sim), e.g.
// ", technician: 1, technician_fps: 4, supersampling: 1" for the simulated
// technician of a guided calibration; --calibration: the config's
// calibration mapping, e.g. "{guided: true, views: 12}".
//
// Prints one JSON line {"url", "station", "observer", "operator", "admin",
// "data_dir"} once both answer, then reads commands, one per line, from
// stdin: "kill" (SIGKILL the daemon), "start" (start it again on the same
// data), each answered "ok" or "error: ...". EOF ends it.
#include <signal.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <string>
#include <thread>

#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <nlohmann/json.hpp>

#include "craftscan/web/console.h"
#include "craftscan/web/http_server.h"
#include "daemon_fixture.h"

int main(int argc, char** argv) {
  using namespace craftscan;
  std::string assets, sim_extra, calibration;
  for (int i = 1; i + 1 < argc; ++i) {
    const std::string name = argv[i];
    if (name == "--assets") assets = argv[i + 1];
    if (name == "--sim-extra") sim_extra = argv[i + 1];
    if (name == "--calibration") calibration = argv[i + 1];
  }
  if (assets.empty()) {
    std::fprintf(stderr,
                 "usage: console_station --assets DIR [--sim-extra TEXT] [--calibration YAML]\n");
    return 2;
  }
  // stdout carries the protocol: the console's log goes to stderr.
  spdlog::set_default_logger(spdlog::stderr_color_mt("console"));
  if (std::getenv("CRAFTSCAN_CONSOLE_DEBUG")) spdlog::set_level(spdlog::level::debug);
  // SIGTERM/SIGINT (a test runner ending it) must not leave craftscand
  // running: a thread takes them and stops the daemon before exiting.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  testing::DaemonFixture fixture("640x512", sim_extra);
  fixture.calibration_yaml = calibration;
  std::thread([&fixture, signals] {
    int sig = 0;
    sigwait(&signals, &sig);
    fixture.Stop(SIGKILL);
    std::error_code ignored;
    std::filesystem::remove_all(fixture.root(), ignored);
    std::_Exit(0);
  }).detach();
  std::string error;
  if (!fixture.Prepare(&error) || !fixture.Start(&error)) {
    std::fprintf(stderr, "craftscand: %s\n", error.c_str());
    return 1;
  }
  web::WebConfig config;
  config.listen_port = 0;
  config.stations = {fixture.station()};
  config.domain_id = fixture.domain();
  config.dds_config = fixture.dds_config();
  config.assets_dir = assets;
  config.cache_dir = fixture.root() + "/web-cache";
  auto console = web::Console::Create(config, &error);
  if (!console) {
    std::fprintf(stderr, "console: %s\n", error.c_str());
    return 1;
  }
  auto server = web::HttpServer::Start(console.get(), &error);
  if (!server) {
    std::fprintf(stderr, "server: %s\n", error.c_str());
    return 1;
  }
  const nlohmann::json hello = {{"url", "http://127.0.0.1:" + std::to_string(server->port()) + "/"},
                                {"station", fixture.station()},
                                {"observer", testing::kObserverToken},
                                {"operator", testing::kOperatorToken},
                                {"admin", testing::kAdminToken},
                                {"data_dir", fixture.data_dir()}};
  std::cout << hello.dump() << std::endl;
  std::string line;
  while (std::getline(std::cin, line)) {
    if (line == "kill") {
      fixture.Stop(SIGKILL);
      std::cout << "ok" << std::endl;
    } else if (line == "start") {
      std::cout << (fixture.Start(&error) ? std::string("ok") : "error: " + error) << std::endl;
    } else {
      std::cout << "error: unknown command '" << line << "'" << std::endl;
    }
  }
  server.reset();
  console.reset();
  return 0;
}
