// Shared by the DDS-level tests (tests/dds, tests/dds/security,
// tests/clients/record): the loopback-only Cyclone configuration, one random
// domain per test process and a participant on it, and station names no
// other test uses. (Child processes: tests/process_util.h.)
// Uses the shipped systemd/cyclonedds.xml (test_paths.h).
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <memory>
#include <random>
#include <string>

#include "craftscan/dds/participant.h"
#include "test_paths.h"

namespace craftscan::testing {

// The shipped configuration plus the loopback-only fragment.
inline std::string TestDdsConfig() {
  return dds::ConfigFileUri(::craftscan::testing::CycloneDdsXml()) + "," +
         dds::LoopbackOnlyConfigXml();
}

// One random domain per test process (1..kMaxDomainId; 0 is the usual default).
// CRAFTSCAN_TEST_DOMAIN (a test's child process) names it instead.
inline std::uint32_t ProcessDomainId() {
  static const std::uint32_t id = [] {
    if (const char* given = std::getenv("CRAFTSCAN_TEST_DOMAIN")) {
      return static_cast<std::uint32_t>(std::strtoul(given, nullptr, 10) % (dds::kMaxDomainId + 1));
    }
    return static_cast<std::uint32_t>(1 + std::random_device{}() % dds::kMaxDomainId);
  }();
  return id;
}

// A participant on ProcessDomainId() with TestDdsConfig(); null (and a test
// failure with the reason) if it cannot be created.
inline std::shared_ptr<dds::Participant> MakeTestParticipant() {
  dds::ParticipantOptions options;
  options.domain_id = ProcessDomainId();
  options.config = TestDdsConfig();
  std::string error;
  std::shared_ptr<dds::Participant> participant = dds::Participant::Create(options, &error);
  EXPECT_NE(participant, nullptr) << error;
  return participant;
}

// A station name no other test (in this process or another) uses:
// <prefix><pid>_<counter>_<random>. The prefix tells whose it is in a capture.
inline std::string UniqueStation(const std::string& prefix) {
  static int counter = 0;
  return prefix + std::to_string(::getpid()) + "_" + std::to_string(counter++) + "_" +
         std::to_string(std::random_device{}() % 100000);
}

}  // namespace craftscan::testing
