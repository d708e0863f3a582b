// craftscand's service: builds the station from a DaemonConfig (sessions,
// tokens, DDS, devices, jobs) and runs the main loop — commands in, replies
// out, StationStatus on change and every second, systemd notifications
// (READY=1 once the devices were opened, WATCHDOG=1 only while healthy,
// STATUS= lines, STOPPING=1) — until RequestStop().
//
// Stopping (SIGTERM): the running job is cancelled at its next safe point —
// every capture already acknowledged is on disk and its session is marked
// interrupted, so `resume` continues it — then the devices are closed.
//
// Degraded storage: when the data directory cannot be used (read-only,
// missing, not writable) the daemon still starts and serves status and
// devices; READY=1 comes with STATUS=degraded: <reason>, StationStatus has
// state "degraded" and the reason in last_error, and every verb that needs
// the data directory is refused with `unavailable` naming it and the error.
// The store is tried again every 10 s; once it opens, unfinished sessions
// are marked interrupted and the station serves normally.
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <string_view>

#include "craftscan/daemon/config.h"

namespace craftscan::daemon {

// The station's state, as StationStatus.state and the status verb's "state"
// carry it (ToString; clients compare these strings):
//   starting   the devices have not been tried yet
//   idle       devices open, the session store open, no job running
//   busy       a job is running
//   degraded   devices open, the data directory unusable (degraded storage)
//   error      the devices are not open (start-up failed, or a job ended
//              with them closed); they are retried every 10 s
//   stopping   SIGTERM: the running job is being checkpointed
enum class StationState { kStarting, kIdle, kBusy, kDegraded, kError, kStopping };
std::string_view ToString(StationState state);  // "starting", "idle", ...

// What the station's state follows from.
struct StationFacts {
  bool stopping = false;       // RequestStop() was seen
  bool devices_tried = false;  // the first Open of the devices has returned
  bool devices_open = false;
  bool job_running = false;
  bool store_open = false;
};
// The state for `facts`, in this order: stopping, starting, busy (a job owns
// the devices, even while it reopens them), error, degraded, idle.
StationState StationStateFrom(const StationFacts& facts);

class Daemon {
 public:
  // Checks what can be checked before serving: the config, the tokens file,
  // the DDS participant and topics. Null with *error naming the part and the
  // problem. Opens the session store (marking unfinished sessions
  // interrupted); an unusable data directory is not an error (degraded
  // storage, above). Devices are opened by Run().
  static std::unique_ptr<Daemon> Create(const DaemonConfig& config, std::string* error);
  ~Daemon();

  // Serves until RequestStop(); returns the process exit code (0 after a
  // clean stop).
  int Run();
  // Async-signal-safe: sets a flag the main loop polls (within 100 ms).
  void RequestStop() { stop_.store(true); }

 private:
  struct Impl;
  explicit Daemon(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
  std::atomic<bool> stop_{false};
};

}  // namespace craftscan::daemon
