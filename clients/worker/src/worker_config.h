// craftscan-worker's configuration: the YAML file, CRAFTSCAN_WORKER_*
// environment overrides, validation naming the field (and the YAML line),
// and the WorkerOptions the job loop runs with. The same rules as
// craftscand's config (craftscan/daemon/config.h): every key is optional
// except `version`; unknown keys are refused, naming the key path; ranges
// are checked at load.
//
//   version: 1                   required; other versions are refused
//   worker: worker_<host>        the worker's id on its site: a letter, then
//                                letters, digits, '_', ≤ 64 (dds::IsValidWorkerId);
//                                default "worker_" + the host name, other
//                                characters made '_'
//   site: default                [A-Za-z0-9_-]{1,64}: the DDS partition shared with
//                                the site's stations (their `site:`)
//   log_level: info              debug | info | warning | error
//   dds:
//     domain: 0                  0..230, the stations' domain
//     config_file: ""            absolute path of a Cyclone DDS XML file, or ""
//                                (then CYCLONEDDS_URI or Cyclone's defaults)
//   auth:
//     token_file: /etc/craftscan/worker.token
//                                absolute; the token (listed in the stations'
//                                tokens.yaml) on its first line; readable by its
//                                owner only (mode 0600 or 0400)
//   threads: 2                   1..256 reconstruction threads
//   jobs: 1                      1..16 jobs held at once (their threads share
//                                the host; 2 keeps a worker busy while one job
//                                waits for its station's next view)
//   work_dir: /var/lib/craftscan-worker   absolute; scratch for a job's inputs
//   watchdog:
//     enabled: true              ping systemd's watchdog (when WatchdogSec= is set)
//
// Environment: CRAFTSCAN_WORKER_ + the key path upper-cased with '.' → '_'
// (CRAFTSCAN_WORKER_DDS_DOMAIN=3, CRAFTSCAN_WORKER_WORKER=gpu_box) overrides
// the file.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "craftscan/worker/worker.h"

namespace craftscan::worker {

inline constexpr int kWorkerConfigVersion = 1;

enum class WorkerLogLevel { kDebug, kInfo, kWarning, kError };

// "worker_" + `host_name` with every character outside [A-Za-z0-9_] made
// '_', cut to 64 characters (a valid worker id for any host name).
std::string WorkerIdForHost(const std::string& host_name);
// WorkerIdForHost(this host's name).
std::string DefaultWorkerId();

struct WorkerConfig {
  std::string worker = DefaultWorkerId();
  std::string site = "default";
  WorkerLogLevel log_level = WorkerLogLevel::kInfo;
  struct {
    uint32_t domain = 0;
    std::string config_file;
  } dds;
  struct {
    std::string token_file = "/etc/craftscan/worker.token";
  } auth;
  int threads = 2;
  int jobs = 1;
  std::string work_dir = "/var/lib/craftscan-worker";
  struct {
    bool enabled = true;
  } watchdog;

  // The ranges above; false with *why naming the field ("threads: must be
  // an integer in 1..256, got '0'").
  bool IsValid(std::string* why) const;
};

// Parses the YAML text, then applies `env` (CRAFTSCAN_WORKER_* variables;
// others are ignored) and validates. False with *error naming the field
// and, for the file, its line ("dds.domain: must be an integer in 0..230,
// got '999' (line 4)"); *config is untouched then.
bool ParseWorkerConfig(const std::string& yaml_text, const std::map<std::string, std::string>& env,
                       WorkerConfig* config, std::string* error);
// Reads the file at `path` and parses it with this process's environment.
// Errors start with the path.
bool LoadWorkerConfig(const std::string& path, WorkerConfig* config, std::string* error);

// The effective configuration as YAML (`craftscan-worker --print-config`).
std::string DumpWorkerConfig(const WorkerConfig& config);
// Every CRAFTSCAN_WORKER_* variable the config reads, in schema order.
std::vector<std::string> WorkerEnvironmentVariables();

// The token in `path`: its first line without trailing blanks. False with
// *error ("auth.token_file: /etc/craftscan/worker.token: …") when the file
// cannot be read, is not a regular file, is readable by group or others,
// or its first line is empty or longer than 128 bytes.
bool ReadWorkerToken(const std::string& path, std::string* token, std::string* error);

// The job loop's options from the config: reads the token file, and the
// Cyclone config as a file:// URI when config_file is set. False with
// *error on a token problem, an unreadable dds.config_file or options the
// loop would refuse; *options is untouched then.
bool MakeWorkerOptions(const WorkerConfig& config, WorkerOptions* options, std::string* error);

}  // namespace craftscan::worker
