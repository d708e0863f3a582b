// Shared by the DDS-level tests (tests/dds, tests/clients/record): the
// loopback-only Cyclone configuration, one random domain per test process,
// and a child process that is killed and reaped if still running.
// Needs CRAFTSCAN_CYCLONEDDS_XML (the shipped systemd/cyclonedds.xml).
#pragma once

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <random>
#include <string>
#include <thread>

#include "craftscan/dds/participant.h"

namespace craftscan::testing {

// The shipped configuration plus the loopback-only fragment.
inline std::string TestDdsConfig() {
  return dds::ConfigFileUri(CRAFTSCAN_CYCLONEDDS_XML) + "," + dds::LoopbackOnlyConfigXml();
}

// One random domain per test process (1..kMaxDomainId; 0 is the usual default).
inline std::uint32_t ProcessDomainId() {
  static const std::uint32_t id = 1 + std::random_device{}() % dds::kMaxDomainId;
  return id;
}

// A spawned child's pid, killed (SIGKILL) and reaped on destruction if still
// running. Not copyable.
class ChildProcess {
 public:
  ChildProcess() = default;
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ~ChildProcess() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }

  // For posix_spawn: where it writes the pid (set -1 on failure).
  pid_t* pid_slot() { return &pid_; }
  bool started() const { return pid_ > 0; }
  void Signal(int signal) {
    if (pid_ > 0) ::kill(pid_, signal);
  }

  // The exit code (128 + signal if killed by one), or −1 if it did not exit
  // within `timeout` (it keeps running; the destructor kills it).
  int Wait(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (pid_ > 0) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      if (std::chrono::steady_clock::now() > deadline) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return -1;
  }

 private:
  pid_t pid_ = -1;
};

}  // namespace craftscan::testing
