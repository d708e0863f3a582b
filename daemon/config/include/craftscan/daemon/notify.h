// Service manager notifications for craftscand (sd_notify(3) protocol):
// readiness, status text, watchdog pings, stopping/reloading, start/stop
// timeout extension. Every call is a no-op returning true when NOTIFY_SOCKET
// is unset (craftscand started from a shell or a test).
//
//   SystemdNotifier notifier;
//   notifier.Ready("station1: 2 devices, idle");
//   auto ping = notifier.WatchdogPingInterval();   // 0: no watchdog
//   ... every `ping`: notifier.Watchdog();
//   notifier.Stopping("checkpointing scan 20240501-101500-egg");
//
// Thread safety: all methods are const and may be called from any thread
// (each call opens its own socket), provided no thread modifies
// NOTIFY_SOCKET / WATCHDOG_* in the environment meanwhile.
#pragma once

#include <chrono>
#include <string>
#include <string_view>

namespace craftscan::daemon {

class SystemdNotifier {
 public:
  // Whether NOTIFY_SOCKET is set (the service manager listens).
  bool Enabled() const;

  // The senders below return true when the message was sent or
  // NOTIFY_SOCKET is unset; false with *error (may be null) saying why
  // sending failed. Status texts are reduced to one line (control
  // characters become spaces) so they cannot inject other assignments.

  // READY=1 (with STATUS=<status> when not empty), in one datagram.
  bool Ready(std::string_view status = {}, std::string* error = nullptr) const;
  // STATUS=<text>: one line shown by `systemctl status`.
  bool Status(std::string_view text, std::string* error = nullptr) const;
  // WATCHDOG=1: the daemon is alive.
  bool Watchdog(std::string* error = nullptr) const;
  // STOPPING=1 (with STATUS= when not empty).
  bool Stopping(std::string_view status = {}, std::string* error = nullptr) const;
  // RELOADING=1 (with STATUS= when not empty); send Ready() when done.
  bool Reloading(std::string_view status = {}, std::string* error = nullptr) const;
  // EXTEND_TIMEOUT_USEC=<extra>: the start or stop in progress needs up to
  // `extra` more from now (e.g. while checkpointing a job on stop).
  bool ExtendTimeout(std::chrono::microseconds extra, std::string* error = nullptr) const;

  // The watchdog timeout systemd set for this process (WATCHDOG_USEC, when
  // WATCHDOG_PID is unset or this pid), else 0: no watchdog, or an invalid
  // setting. Ping at WatchdogPingInterval(), half of it.
  std::chrono::microseconds WatchdogInterval() const;
  std::chrono::microseconds WatchdogPingInterval() const { return WatchdogInterval() / 2; }

 private:
  bool Send(const std::string& state, std::string* error) const;
};

}  // namespace craftscan::daemon
