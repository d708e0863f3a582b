// craftscanctl site (and status --all): every station and reconstruction
// worker of one site, as they announce themselves on the site's topics
// (craftscan/dds/site.h: SiteStation, WorkerStatus, in the site's DDS
// partition). It only listens, so it needs no token.
#pragma once

#include <atomic>
#include <cstdint>
#include <map>
#include <string>

#include <nlohmann/json.hpp>

namespace craftscan::ctl {

struct SiteOptions {
  std::string site;  // checked by Site() (dds::IsValidSiteId)
  std::uint32_t domain = 0;
  std::string dds_config;  // as GlobalOptions::dds_config (empty: the default)
  double wait_s = 2;       // how long to listen
  bool json = false;
};

// What was heard: the latest sample of each instance and whether it is
// alive (not disposed, some live writer). Keyed by station / worker id.
struct SiteInstances {
  struct Entry {
    nlohmann::json fields;  // the sample's fields, by their IDL names
    bool alive = false;
  };
  std::map<std::string, Entry> stations, workers;
};

// The live instances as JSON: {"site", "domain", "stations": [...],
// "workers": [...]}, each entry an object of its IDL fields, sorted by id.
nlohmann::json SiteJson(const std::string& site, std::uint32_t domain,
                        const SiteInstances& instances);
// The same as two tables (STATIONS, WORKERS) for people.
std::string SiteTable(const nlohmann::json& site);

// Listens for `options.wait_s` seconds (less when `interrupted` is set) and
// prints the live stations and workers. Exit codes as ctl.h's: kExitOk,
// kExitUsage (invalid site, message printed), kExitLocalError (DDS would not
// start), kExitInterrupted.
int Site(const SiteOptions& options, const std::atomic<bool>* interrupted);

}  // namespace craftscan::ctl
