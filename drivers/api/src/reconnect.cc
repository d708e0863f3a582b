// Bounded exponential back-off for reconnecting lost devices.
#include "craftscan/drivers/reconnect.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <string>
#include <utility>

namespace craftscan::drivers {

bool ReconnectPolicy::IsValid(std::string* why) const {
  auto fail = [why](const char* message) {
    if (why) *why = message;
    return false;
  };
  if (max_attempts < 1) return fail("max_attempts must be >= 1");
  if (initial_delay.count() < 0) return fail("initial_delay must be >= 0 ms");
  if (!(multiplier >= 1 && std::isfinite(multiplier))) return fail("multiplier must be >= 1");
  if (max_delay < initial_delay) return fail("max_delay must be >= initial_delay");
  return true;
}

std::chrono::milliseconds ReconnectPolicy::DelayBefore(int attempt) const {
  // In double so that large attempt numbers saturate at the cap instead of
  // overflowing.
  const double delay_ms =
      static_cast<double>(initial_delay.count()) * std::pow(multiplier, std::max(0, attempt - 1));
  const double capped = std::min(delay_ms, static_cast<double>(max_delay.count()));
  return std::chrono::milliseconds(static_cast<std::int64_t>(std::llround(capped)));
}

Reconnector::Reconnector(ReconnectPolicy policy, const HostServices& host, std::string device)
    : policy_(policy), host_(host.WithDefaults()), device_(std::move(device)) {
  assert(policy_.IsValid(nullptr));
}

void Reconnector::ReportConnected(std::string_view message) const {
  host_.log(LogLevel::kInfo, device_ + ": connected");
  host_.events({device_, DeviceEvent::kConnected, 0, std::string(message)});
}

void Reconnector::ReportLost(std::string_view message) const {
  host_.log(LogLevel::kWarning, device_ + ": lost: " + std::string(message));
  host_.events({device_, DeviceEvent::kLost, 0, std::string(message)});
}

DriverStatus Reconnector::Run(const std::function<DriverStatus()>& attempt) const {
  return Run(attempt, nullptr);
}

DriverStatus Reconnector::Run(const std::function<DriverStatus()>& attempt, ReconnectWake* wake,
                              std::chrono::milliseconds slice) const {
  const std::int64_t slice_ns = std::max<std::int64_t>(
      1, std::chrono::duration_cast<std::chrono::nanoseconds>(slice).count());
  DriverStatus last;
  for (int i = 1; i <= policy_.max_attempts; ++i) {
    const std::int64_t delay_ns =
        std::chrono::duration_cast<std::chrono::nanoseconds>(policy_.DelayBefore(i)).count();
    if (wake == nullptr) {
      host_.sleep_ns(delay_ns);
    } else {
      // Sliced so a wake ends the delay within one slice.
      std::int64_t slept_ns = 0;
      bool woken = wake->Consume();
      while (!woken && slept_ns < delay_ns) {
        const std::int64_t step = std::min(slice_ns, delay_ns - slept_ns);
        host_.sleep_ns(step);
        slept_ns += step;
        woken = wake->Consume();
      }
      if (woken && slept_ns < delay_ns) {
        host_.log(LogLevel::kInfo, device_ + ": reconnect attempt " + std::to_string(i) +
                                       " woken early after " +
                                       std::to_string(slept_ns / 1'000'000) + " of " +
                                       std::to_string(delay_ns / 1'000'000) + " ms");
      }
    }
    last = attempt();
    if (last.ok()) {
      host_.log(LogLevel::kInfo, device_ + ": reconnected (attempt " + std::to_string(i) + ")");
      host_.events({device_, DeviceEvent::kReconnected, i, {}});
      return last;
    }
    if (last.code != StatusCode::kDeviceLost && last.code != StatusCode::kIoError &&
        last.code != StatusCode::kTimeout) {
      return last;
    }
    host_.log(LogLevel::kDebug,
              device_ + ": reconnect attempt " + std::to_string(i) + " failed: " + last.ToString());
  }
  const std::string message = "gave up after " + std::to_string(policy_.max_attempts) +
                              " reconnect attempts; last: " + last.ToString();
  host_.log(LogLevel::kError, device_ + ": " + message);
  host_.events({device_, DeviceEvent::kGaveUp, policy_.max_attempts, message});
  return DriverStatus::Error(StatusCode::kDeviceLost, device_ + ": " + message);
}

}  // namespace craftscan::drivers
