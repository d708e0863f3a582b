// craftscan-worker's job loop (DESIGN.md, "a job handed to another host";
// the protocol in craftscan/dds/site.h): announce the worker on its site,
// claim offered reconstruction jobs, fetch a granted job's inputs from its
// station (the station's `get`, checksummed), reconstruct them exactly as
// the station would (ReconstructFromStoredViews), and send the outputs
// back as JobResult chunks; renew the lease by writing WorkerStatus every
// quarter of it. A job whose offer is disposed, re-granted to another worker
// or whose station vanished is dropped. The worker never writes a session:
// the station stores.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <string>

namespace craftscan::worker {

struct WorkerOptions {
  std::string worker_id;  // unique on the site, [A-Za-z][A-Za-z0-9_]{0,63}
  std::string site = "default";
  uint32_t domain = 0;
  std::string dds_config;  // Cyclone config (ParticipantOptions::config); "" = CYCLONEDDS_URI
  std::string token;       // presented with claims, results and `get`
  int threads = 2;         // reconstruction threads
  int jobs = 2;            // jobs held at once, 1..16 (a job waits for its views as they come)
  std::string work_dir;    // scratch for fetched inputs (absolute); emptied per job

  bool IsValid(std::string* why) const;
};

// What the loop tells its host process (all may be empty).
struct WorkerHooks {
  std::function<void()> ready;  // announced on the site
  std::function<void(const std::string& status)>
      status;                   // one line: "idle", "job st1/...: fetching"
  std::function<void()> alive;  // called at least once a second (watchdog)
  std::function<void(int level, const std::string& message)> log;  // 0 debug .. 3 error
};

// Runs until `stop` is set (then finishes nothing: a job in hand is
// abandoned, its station takes it back when the lease lapses; the worker's
// status instance is disposed). 0 on a clean stop; 1 when DDS cannot be
// set up (*error says why).
int RunWorker(const WorkerOptions& options, const std::atomic<bool>& stop, const WorkerHooks& hooks,
              std::string* error);

}  // namespace craftscan::worker
