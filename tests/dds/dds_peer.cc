// craftscan_dds_peer: the second process of the DDS transport tests. Takes
// `count` samples from a station's topic and writes each back unchanged on
// the same topic of station <station>_echo, then waits until the echoes are
// acknowledged. Exit 0 on success, 1 with a message on stderr otherwise, 2 on
// a bad command line.
//
//   craftscan_dds_peer --domain D --config CONFIG --station S
//                      --mode capture|cloud|status [--count N] [--timeout-ms T]
#include <chrono>
#include <cstdlib>
#include <iostream>
#include <memory>
#include <string>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

namespace {

using namespace craftscan::dds;

int Fail(const std::string& message) {
  std::cerr << "craftscan_dds_peer: " << message << "\n";
  return 1;
}

template <typename Msg>
int Echo(std::shared_ptr<Participant> participant, const TopicSpec<Msg>& in,
         const TopicSpec<Msg>& out, int count, std::chrono::milliseconds timeout) {
  std::string error;
  auto reader = Reader<Msg>::Create(participant, in, &error);
  if (!reader) return Fail(error);
  auto writer = Writer<Msg>::Create(participant, out, &error);
  if (!writer) return Fail(error);
  if (!writer->WaitForReaders(1, timeout)) return Fail("no reader on " + out.name);
  Sample<Msg> sample;
  for (int i = 0; i < count; ++i) {
    if (reader->Take(timeout, &sample, &error) != TakeStatus::kOk) {
      return Fail("sample " + std::to_string(i) + " on " + in.name + ": " +
                  (error.empty() ? "timed out" : error));
    }
    // A received message is a complete C struct: it can be written as is.
    if (!writer->Write(*sample, &error)) return Fail(error);
  }
  if (!writer->WaitForAcks(timeout, &error)) return Fail(error);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  ParticipantOptions options;
  std::string station, mode;
  int count = 1;
  long timeout_ms = 20000;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string key = argv[i], value = argv[i + 1];
    if (key == "--domain") {
      options.domain_id = static_cast<uint32_t>(std::strtoul(value.c_str(), nullptr, 10));
    } else if (key == "--config") {
      options.config = value;
    } else if (key == "--station") {
      station = value;
    } else if (key == "--mode") {
      mode = value;
    } else if (key == "--count") {
      count = std::atoi(value.c_str());
    } else if (key == "--timeout-ms") {
      timeout_ms = std::atol(value.c_str());
    } else {
      std::cerr << "craftscan_dds_peer: unknown option " << key << "\n";
      return 2;
    }
  }
  if (argc % 2 != 1 || station.empty() || count < 1 || timeout_ms <= 0) {
    std::cerr << "usage: craftscan_dds_peer --domain D --config CONFIG --station S "
                 "--mode capture|cloud|status [--count N] [--timeout-ms T]\n";
    return 2;
  }
  std::string error;
  auto participant = Participant::Create(options, &error);
  if (!participant) return Fail(error);
  const std::chrono::milliseconds timeout(timeout_ms);
  const std::string echo = station + "_echo";
  if (mode == "capture") {
    return Echo(participant, CaptureTopic(station), CaptureTopic(echo), count, timeout);
  }
  if (mode == "cloud")
    return Echo(participant, CloudTopic(station), CloudTopic(echo), count, timeout);
  if (mode == "status") {
    return Echo(participant, StatusTopic(station), StatusTopic(echo), count, timeout);
  }
  std::cerr << "craftscan_dds_peer: unknown mode '" << mode << "'\n";
  return 2;
}
