// The station's side of a reconstruction handed to a worker on another host
// (craftscan/dds/site.h has the protocol and which DDS mechanism carries
// each rule). One RemoteJobs per daemon, on the daemon's participant:
//
//   offer (JobOffer "offered", transient-local)
//     → claims (JobClaim; a claim whose token the station's tokens file does
//       not list with role operator or admin, or from a worker not alive on
//       the site, is refused and logged: an unknown worker is never granted)
//     → grant (the JobOffer instance again: "granted", worker, grant n)
//     → the worker's lease: its WorkerStatus instance; NOT_ALIVE (died, cut
//       off, stopped) → offered again (grant n+1 on the next claim)
//     → result (JobResult chunks of grant n, SHA-256 checked) → done: the
//       instance disposed; a chunk of any other job or grant is dropped and
//       logged (a late duplicate).
//   No claim within offer_timeout (first offer or after a lost lease), a
//   grant older than max_remote, or a worker reporting failure → the
//   caller reconstructs locally (kLocal), the offer disposed.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/daemon/auth.h"
#include "craftscan/daemon/scan_outputs.h"
#include "craftscan/dds/participant.h"

namespace craftscan::daemon {

// A session file the worker fetches with `get`.
struct RemoteInput {
  std::string name;  // "calibration.yaml", "views/000/cloud.ply", ...
  std::uint64_t size = 0;
  std::string sha256;
  int view = -1;             // a view's cloud.ply: its index (the worker adds it to the scan)
  double angle_deg = 0;      // and its commanded angle
  std::string captured_utc;  // and when it was captured
};

// The views of a job as they become durable (the station's stage thread
// adds, RemoteJobs::Run takes). Thread-safe.
class RemoteJobFeed {
 public:
  // `inputs` of views up to `views_ready` (all views before it durable).
  void Add(std::vector<RemoteInput> inputs, int views_ready);
  // No more views will come (all in, or the scan stopped).
  void Close();
  // What came since the last Take: false when nothing did.
  bool Take(std::vector<RemoteInput>* inputs, int* views_ready, bool* closed);
  // Set by RemoteJobs::Run when it ends (any outcome): the stage stops feeding.
  void SetEnded() { ended_ = true; }
  bool ended() const { return ended_; }

 private:
  std::mutex mutex_;
  std::vector<RemoteInput> inputs_;
  int views_ready_ = 0;
  bool closed_ = false, changed_ = false;
  std::atomic<bool> ended_{false};
};

struct RemoteJobRequest {
  std::string session;
  std::vector<RemoteInput> inputs;  // known at the offer (calibration.yaml)
  nlohmann::json parameters;        // what the worker reads (ReconstructStage::RunRemote)
  int views_total = 0;
  RemoteJobFeed* feed = nullptr;  // the views as they come; null: all in `inputs` already
  std::chrono::milliseconds offer_timeout{3000};
  std::chrono::seconds max_remote{1800};
};

struct RemoteJobOutcome {
  enum class Status {
    kDone,       // `outputs` hold the checked files and the worker's result
    kLocal,      // no worker did it: reconstruct here (`message` says why)
    kCancelled,  // the stop flag was set
  };
  Status status = Status::kLocal;
  std::string message;
  ScanOutputs outputs;
  std::string job_id;
  std::string worker;            // who delivered it (kDone)
  int grants = 0;                // grants made (> 1: a lease was lost on the way)
  double seconds = 0;            // from the offer to the last file
  std::uint64_t bytes_back = 0;  // result bytes received
};

class RemoteJobs {
 public:
  // `tokens` (not owned, outlives this; null: no claim is honoured) decides
  // which workers may be granted. Null with *error when a DDS entity cannot
  // be made.
  static std::unique_ptr<RemoteJobs> Create(std::shared_ptr<dds::Participant> participant,
                                            const std::string& site, const std::string& station,
                                            const TokenAuthority* tokens, LogFn log,
                                            std::string* error);
  ~RemoteJobs();
  RemoteJobs(const RemoteJobs&) = delete;
  RemoteJobs& operator=(const RemoteJobs&) = delete;

  // Workers alive on the site now and, of them, those idle.
  int WorkersAlive();
  int WorkersIdle();

  // Offers one job and sees it through (above). `on_change(job, worker)` is
  // told the job's worker as it changes ("" = offered, none) and ("", "")
  // at the end; may be empty. Blocks; one Run at a time.
  RemoteJobOutcome Run(
      const RemoteJobRequest& request, const std::atomic<bool>& stop, const ProgressFn& progress,
      const std::function<void(const std::string&, const std::string&)>& on_change);

 private:
  struct Impl;
  explicit RemoteJobs(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace craftscan::daemon
