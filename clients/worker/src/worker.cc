// PLACEHOLDER (issue 21): the lead replaces RunWorker with the job loop
// (announce, claim, fetch, reconstruct, return results). Until then it only
// plays the host-process side of the interface: ready, then alive every
// 200 ms until stopped. WorkerOptions::IsValid is meant to stay.
#include "craftscan/worker/worker.h"

#include <chrono>
#include <thread>

#include "craftscan/dds/participant.h"
#include "craftscan/dds/site.h"

namespace craftscan::worker {
namespace {

bool Fail(std::string* why, std::string message) {
  if (why) *why = std::move(message);
  return false;
}

}  // namespace

bool WorkerOptions::IsValid(std::string* why) const {
  std::string what;
  if (!dds::IsValidWorkerId(worker_id, &what)) return Fail(why, "worker: " + what);
  if (!dds::IsValidSiteId(site, &what)) return Fail(why, "site: " + what);
  if (domain > dds::kMaxDomainId) {
    return Fail(why, "domain: must be 0.." + std::to_string(dds::kMaxDomainId) + ", got " +
                         std::to_string(domain));
  }
  if (threads < 1 || threads > 256) {
    return Fail(why, "threads: must be 1..256, got " + std::to_string(threads));
  }
  if (work_dir.empty() || work_dir.front() != '/') {
    return Fail(why, "work_dir: must be an absolute path, got '" + work_dir + "'");
  }
  if (token.size() > 256) {
    return Fail(why, "token: longer than 256 bytes (" + std::to_string(token.size()) + ")");
  }
  return true;
}

int RunWorker(const WorkerOptions& options, const std::atomic<bool>& stop, const WorkerHooks& hooks,
              std::string* error) {
  if (!options.IsValid(error)) return 1;
  if (hooks.ready) hooks.ready();
  if (hooks.status) hooks.status("idle");
  while (!stop.load()) {
    if (hooks.alive) hooks.alive();
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  return 0;
}

}  // namespace craftscan::worker
