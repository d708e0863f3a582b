// Device-loss handling shared by all drivers: a bounded exponential back-off
// policy and the loop that runs reconnect attempts and reports DeviceEvents
// to the host. A driver detects the loss (transport error, N consecutive
// timeouts, ...), calls ReportLost(), and in its Reconnect() runs
// Reconnector::Run with an attempt that reopens the device and re-applies the
// last settings. A ReconnectWake lets another thread (e.g. a USB hot-plug
// arrival of the lost device) end a back-off delay early.
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <string>
#include <string_view>

#include "craftscan/drivers/host.h"
#include "craftscan/drivers/status.h"

namespace craftscan::drivers {

struct ReconnectPolicy {
  int max_attempts = 5;                          // attempts per Run, ≥ 1
  std::chrono::milliseconds initial_delay{200};  // before attempt 1, ≥ 0
  double multiplier = 2.0;                       // delay growth per attempt, ≥ 1
  std::chrono::milliseconds max_delay{5000};     // cap on any delay, ≥ initial_delay

  bool IsValid(std::string* why) const;  // names the offending field
  // Delay before attempt `attempt` (1-based): initial_delay · multiplier^(attempt−1),
  // capped at max_delay.
  std::chrono::milliseconds DelayBefore(int attempt) const;
};

// Ends a Reconnector::Run back-off early. Thread-safe; Notify() from any
// thread, Run() consumes it.
class ReconnectWake {
 public:
  // The current back-off delay of a Run using this wake (or, if none is
  // running, the first delay of the next one) ends at once.
  void Notify() { pending_.store(true); }
  // Drops a pending Notify() (e.g. one left over from before a new loss).
  void Clear() { pending_.store(false); }
  // True once per Notify().
  bool Consume() { return pending_.exchange(false); }

 private:
  std::atomic<bool> pending_{false};
};

class Reconnector {
 public:
  // `device` names the device in events and log lines (e.g. "sim/camera").
  // host: its sleep_ns waits between attempts, events/log receive the
  // reports (missing members get defaults).
  Reconnector(ReconnectPolicy policy, const HostServices& host, std::string device);

  const ReconnectPolicy& policy() const { return policy_; }

  // Reports DeviceEvent::kConnected / kLost (and logs).
  void ReportConnected(std::string_view message = {}) const;
  void ReportLost(std::string_view message) const;

  // Up to policy().max_attempts times: sleep DelayBefore(i), call attempt().
  // The first kOk reports kReconnected (with the attempt number) and returns
  // kOk. An attempt returning anything but kDeviceLost, kIoError or kTimeout
  // stops the loop and is returned (the device is there but refuses). After
  // the last failure reports kGaveUp and returns kDeviceLost with the last
  // attempt's message. attempt is called on the caller's thread.
  DriverStatus Run(const std::function<DriverStatus()>& attempt) const;
  // As Run(attempt), but each back-off delay is slept in host sleeps of at
  // most `slice` and ends as soon as wake->Consume() returns true: the next
  // attempt is made at once (logged as "woken early"). A null wake: Run(attempt).
  DriverStatus Run(const std::function<DriverStatus()>& attempt, ReconnectWake* wake,
                   std::chrono::milliseconds slice = std::chrono::milliseconds(10)) const;

 private:
  ReconnectPolicy policy_;
  HostServices host_;
  std::string device_;
};

}  // namespace craftscan::drivers
