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
  DriverStatus last;
  for (int i = 1; i <= policy_.max_attempts; ++i) {
    const auto delay = policy_.DelayBefore(i);
    host_.sleep_ns(std::chrono::duration_cast<std::chrono::nanoseconds>(delay).count());
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
