// Waiting in tests: polls a condition until it holds or a timeout passes.
// (An object that records what it saw under a mutex waits on its condition
// variable instead: StationClient::WaitFor, StatusWatcher::WaitFor.)
#pragma once

#include <chrono>
#include <thread>

namespace craftscan::testing {

// Calls `done` until it returns true (then returns true) or `timeout` has
// passed (then false), sleeping `poll` between calls.
template <typename Done>
bool WaitFor(Done&& done, std::chrono::milliseconds timeout,
             std::chrono::milliseconds poll = std::chrono::milliseconds(20)) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(poll);
  }
  return true;
}

}  // namespace craftscan::testing
