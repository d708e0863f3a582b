// craftscan_dds_security_peer: a station client in its own process, for the
// DDS Security tests (a Cyclone domain has one configuration per process, so
// a secured daemon and an unsecured intruder on the same domain need two).
//
// With the given Cyclone configuration (secured or not) it subscribes the
// station's status and capture topics and publishes a Command every 100 ms,
// until SIGTERM or --max-ms. Then it prints one report line on stdout and
// exits 0 (CLI11's non-zero code on a bad command line). Nothing that DDS
// refuses is fatal: the report says what was refused and what arrived.
//
//   craftscan_dds_security_peer --domain D --config CONFIG --station S
//                               --name NAME [--max-ms T]
//
// Report (key=value, space-separated, one line):
//   participant=ok|refused status_reader=ok|refused capture_reader=ok|refused
//   command_writer=ok|refused status=N captures=N capture_hash=H
//   commands=N status_writers=N command_readers=N
// status counts StationStatus samples of station S; capture_hash is the
// testing::CaptureHash of the last capture ("none" before one arrives).
#include <signal.h>

#include <chrono>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <thread>

#include <CLI/CLI.hpp>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"
#include "security_test_util.h"

namespace {

using namespace craftscan::dds;
using std::chrono::milliseconds;

volatile sig_atomic_t g_stop = 0;
void OnTerm(int) { g_stop = 1; }

const char* Ok(bool ok) { return ok ? "ok" : "refused"; }

}  // namespace

int main(int argc, char** argv) {
  ParticipantOptions options;
  std::string station, name;
  long max_ms = 30000;
  CLI::App app("craftscan_dds_security_peer: a station client for the DDS Security tests");
  app.add_option("--domain", options.domain_id, "DDS domain id")->required();
  app.add_option("--config", options.config, "Cyclone DDS configuration")->required();
  app.add_option("--station", station, "station id")->required();
  app.add_option("--name", name, "client name in the Commands")->required();
  app.add_option("--max-ms", max_ms, "stop after this long without SIGTERM")
      ->check(CLI::PositiveNumber);
  CLI11_PARSE(app, argc, argv);
  struct sigaction action = {};
  action.sa_handler = OnTerm;
  sigaction(SIGTERM, &action, nullptr);

  std::string error;
  auto participant = Participant::Create(options, &error);
  if (!participant) std::cerr << "craftscan_dds_security_peer: " << error << "\n";
  std::unique_ptr<Reader<msg::StationStatus>> status_reader;
  std::unique_ptr<Reader<msg::StereoCapture>> capture_reader;
  std::unique_ptr<Writer<msg::Command>> command_writer;
  if (participant) {
    status_reader = Reader<msg::StationStatus>::Create(participant, StatusTopic(station), &error);
    capture_reader = Reader<msg::StereoCapture>::Create(participant, CaptureTopic(station), &error);
    command_writer = Writer<msg::Command>::Create(participant, CommandTopic(station), &error);
  }

  long status = 0, captures = 0, commands = 0;
  std::string capture_hash = "none";
  const auto deadline = std::chrono::steady_clock::now() + milliseconds(max_ms);
  auto next_command = std::chrono::steady_clock::now();
  Sample<msg::StationStatus> status_sample;
  Sample<msg::StereoCapture> capture_sample;
  auto take_captures = [&] {
    while (capture_reader &&
           capture_reader->Take(milliseconds(0), &capture_sample, &error) == TakeStatus::kOk) {
      ++captures;
      capture_hash = craftscan::dds::testing::CaptureHash(*capture_sample);
    }
  };
  while (participant && !g_stop && std::chrono::steady_clock::now() < deadline) {
    if (status_reader &&
        status_reader->Take(milliseconds(20), &status_sample, &error) == TakeStatus::kOk) {
      if (View(status_sample->station) == station) ++status;
    } else if (!status_reader) {
      std::this_thread::sleep_for(milliseconds(20));
    }
    take_captures();
    if (command_writer && std::chrono::steady_clock::now() >= next_command) {
      Outgoing<msg::Command> command;
      command.msg().request_id = command.Keep(name + "-" + std::to_string(commands));
      command.msg().client = command.Keep(name);
      command.msg().token = command.Keep("token-of-" + name);
      command.msg().verb = command.Keep("status");
      command.msg().arguments = command.Keep("{}");
      if (command_writer->Write(command.msg(), &error)) ++commands;
      next_command += milliseconds(100);
    }
  }

  take_captures();  // one acknowledged just before SIGTERM may still be in the cache
  std::ostringstream report;
  report << "participant=" << Ok(participant != nullptr)
         << " status_reader=" << Ok(status_reader != nullptr)
         << " capture_reader=" << Ok(capture_reader != nullptr)
         << " command_writer=" << Ok(command_writer != nullptr) << " status=" << status
         << " captures=" << captures << " capture_hash=" << capture_hash << " commands=" << commands
         << " status_writers=" << (status_reader ? status_reader->MatchedWriters() : 0)
         << " command_readers=" << (command_writer ? command_writer->MatchedReaders() : 0);
  std::cout << report.str() << std::endl;
  return 0;
}
