#include "craftscan/daemon/notify.h"

#include <systemd/sd-daemon.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>

namespace craftscan::daemon {
namespace {

std::string OneLine(std::string_view text) {
  std::string line(text);
  for (char& ch : line) {
    if (static_cast<unsigned char>(ch) < ' ' || ch == 0x7f) ch = ' ';
  }
  return line;
}

std::string WithStatus(std::string state, std::string_view status) {
  if (!status.empty()) state += "\nSTATUS=" + OneLine(status);
  return state;
}

}  // namespace

bool SystemdNotifier::Enabled() const {
  const char* socket = std::getenv("NOTIFY_SOCKET");
  return socket != nullptr && socket[0] != '\0';
}

bool SystemdNotifier::Send(const std::string& state, std::string* error) const {
  const int r = sd_notify(0, state.c_str());
  if (r >= 0) return true;  // 0: NOTIFY_SOCKET unset, > 0: sent
  if (error) *error = std::string("sd_notify: ") + std::strerror(-r);
  return false;
}

bool SystemdNotifier::Ready(std::string_view status, std::string* error) const {
  return Send(WithStatus("READY=1", status), error);
}

bool SystemdNotifier::Status(std::string_view text, std::string* error) const {
  return Send("STATUS=" + OneLine(text), error);
}

bool SystemdNotifier::Watchdog(std::string* error) const { return Send("WATCHDOG=1", error); }

bool SystemdNotifier::Stopping(std::string_view status, std::string* error) const {
  return Send(WithStatus("STOPPING=1", status), error);
}

bool SystemdNotifier::Reloading(std::string_view status, std::string* error) const {
  return Send(WithStatus("RELOADING=1", status), error);
}

bool SystemdNotifier::ExtendTimeout(std::chrono::microseconds extra, std::string* error) const {
  const long long usec = extra.count() > 0 ? static_cast<long long>(extra.count()) : 0;
  return Send("EXTEND_TIMEOUT_USEC=" + std::to_string(usec), error);
}

std::chrono::microseconds SystemdNotifier::WatchdogInterval() const {
  std::uint64_t usec = 0;
  if (sd_watchdog_enabled(0, &usec) <= 0) return std::chrono::microseconds(0);
  return std::chrono::microseconds(static_cast<std::int64_t>(usec));
}

}  // namespace craftscan::daemon
