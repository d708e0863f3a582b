// craftscanctl's subcommands, apart from argument parsing (main.cc): each
// talks to the station through a StationClient, prints for people (or JSON
// with --json) and returns the process exit code.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/client/station_client.h"

namespace craftscan::ctl {

// Exit codes (also in `craftscanctl --help`).
enum ExitCode : int {
  kExitOk = 0,
  kExitLocalError = 1,     // a local failure: cannot write --out, DDS would not start
  kExitUsage = 2,          // bad command line (CLI11 errors, values checked locally)
  kExitRefused = 3,        // the daemon answered with an error (bad_argument, forbidden, ...)
  kExitJobFailed = 4,      // the job failed or was cancelled; get: a file could not be fetched
  kExitUnreachable = 5,    // no daemon, or no reply within --timeout
  kExitStillRunning = 6,   // --max-wait passed while the job still runs (it goes on)
  kExitInterrupted = 130,  // Ctrl-C while waiting for a job (it goes on)
};

struct GlobalOptions {
  std::string station;  // station id
  std::uint32_t domain = 0;
  std::string dds_config;         // empty: client::DefaultDdsConfig()
  std::string token, token_file;  // token: --token, else --token-file, else CRAFTSCAN_TOKEN
  double timeout_s = 10;          // each exchange with the daemon
  bool json = false;
};

// The Cyclone configuration for --dds-config `given`: empty →
// client::DefaultDdsConfig(); a plain path → its file:// URI; XML, URIs and
// lists as given.
std::string ResolveDdsConfig(const std::string& given);

struct WaitOptions {
  bool wait = true;       // wait for the job's end
  double max_wait_s = 0;  // 0 = as long as the daemon keeps answering
};

class Ctl {
 public:
  // `interrupted` (set by the SIGINT handler) ends waits early.
  explicit Ctl(const std::atomic<bool>* interrupted) : interrupted_(interrupted) {}

  // Resolves the token and the DDS configuration, checks the options and
  // connects. kExitOk, kExitUsage (message printed) or kExitLocalError.
  int Init(const GlobalOptions& options);

  int Status();
  int Devices();
  int Sessions();
  // A job verb (calibrate, calibrate-turntable, capture, scan, resume).
  int Job(const std::string& verb, const nlohmann::json& args, const WaitOptions& wait);
  int Cancel();
  int Turntable(const nlohmann::json& args);
  int Camera(const nlohmann::json& args);
  int Get(const std::string& session, const std::string& out_dir,
          const std::vector<std::string>& files, std::size_t chunk_bytes);
  // get into a BagIt 1.0 bag at `bag_dir` (a new or empty folder; built in a
  // hidden staging folder beside it and renamed in once complete), with
  // External-Identifier = the session id and Bagging-Date = today (UTC).
  int GetBag(const std::string& session, const std::string& bag_dir,
             const std::string& source_organization, const std::vector<std::string>& files,
             std::size_t chunk_bytes);
  // Until Ctrl-C, `count` printed events (0 = no limit) or `duration_s`
  // seconds (0 = no limit).
  int Watch(int count, double duration_s);

 private:
  // Call with --timeout; prints and maps errors. On kExitOk *reply is set.
  int Call(const std::string& verb, const nlohmann::json& args, client::Reply* reply);
  // A verb answered at once: prints text(reply), or the reply as JSON.
  int Action(const std::string& verb, const nlohmann::json& args,
             const std::function<std::string(const client::Reply&)>& text);
  int Unreachable(const std::string& message) const;
  // The transfer of get (progress bar, error messages); kExitOk with *result.
  // files empty: every output, or with whole_session every file of the
  // session folder (FetchRequest::whole_session).
  int Fetch(const std::string& session, const std::string& out_dir,
            const std::vector<std::string>& files, bool whole_session, std::size_t chunk_bytes,
            client::FetchResult* result);
  void PrintJson(const nlohmann::json& value) const;
  bool Interrupted() const { return interrupted_ && interrupted_->load(); }

  const std::atomic<bool>* interrupted_;
  GlobalOptions options_;
  std::unique_ptr<client::StationClient> client_;
};

}  // namespace craftscan::ctl
