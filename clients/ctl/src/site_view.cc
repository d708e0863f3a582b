#include "site_view.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <memory>
#include <string_view>
#include <vector>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/site.h"
#include "ctl.h"

namespace craftscan::ctl {
namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;

std::string Text(const char* text) { return std::string(dds::View(text)); }

json StationFields(const dds::msg::SiteStation& m) {
  return {{"station", Text(m.station)},
          {"state", Text(m.state)},
          {"job_id", Text(m.job_id)},
          {"job_verb", Text(m.job_verb)},
          {"job_state", Text(m.job_state)},
          {"progress", m.progress},
          {"reconstruction", Text(m.reconstruction)},
          {"remote_job", Text(m.remote_job)},
          {"remote_worker", Text(m.remote_worker)},
          {"load", m.load},
          {"stamp_ns", m.stamp_ns}};
}

json WorkerFields(const dds::msg::WorkerStatus& m) {
  return {{"worker", Text(m.worker)}, {"state", Text(m.state)},
          {"job_id", Text(m.job_id)}, {"station", Text(m.station)},
          {"grant", m.grant},         {"cores", m.cores},
          {"load", m.load},           {"jobs_done", m.jobs_done},
          {"stamp_ns", m.stamp_ns}};
}

// Takes what `reader` has (waiting up to `timeout` for the first) into
// `entries`: the latest data of each instance and its state now.
template <typename Msg, typename Fields>
bool TakeInto(dds::Reader<Msg>& reader, std::chrono::milliseconds timeout, char* Msg::*key,
              Fields fields, std::map<std::string, SiteInstances::Entry>* entries,
              std::string* error) {
  dds::Sample<Msg> sample;
  dds::SampleState state;
  for (auto wait = timeout;; wait = std::chrono::milliseconds(0)) {
    switch (reader.TakeWithInfo(wait, &sample, &state, error)) {
      case dds::TakeStatus::kOk: {
        SiteInstances::Entry& entry = (*entries)[Text(sample.get().*key)];
        if (state.valid_data) entry.fields = fields(sample.get());
        // The instance's state when taken (not when written): a sample
        // taken after its instance ended says so.
        entry.alive = state.instance == dds::InstanceState::kAlive && !entry.fields.is_null();
        break;
      }
      case dds::TakeStatus::kTimeout:
        return true;
      default:
        return false;
    }
  }
}

// Control characters (from a peer) would garble the table.
std::string Printable(std::string text) {
  for (char& c : text) {
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  }
  return text;
}

std::string Str(const json& object, const char* key) {
  const auto it = object.find(key);
  return it != object.end() && it->is_string() ? Printable(it->get<std::string>()) : "";
}

std::string OrDash(const std::string& text) { return text.empty() ? "-" : text; }

using Row = std::vector<std::string>;

// The rows as columns, each as wide as its widest cell, two spaces apart.
std::string Columns(const std::vector<Row>& rows) {
  std::vector<std::size_t> widths;
  for (const Row& row : rows) {
    widths.resize(std::max(widths.size(), row.size()));
    for (std::size_t i = 0; i < row.size(); ++i) widths[i] = std::max(widths[i], row[i].size());
  }
  std::string out;
  for (const Row& row : rows) {
    std::string line;
    for (std::size_t i = 0; i < row.size(); ++i) {
      line += row[i];
      if (i + 1 < row.size()) line += std::string(widths[i] - row[i].size() + 2, ' ');
    }
    out += line + "\n";
  }
  return out;
}

std::string Format(const char* format, double value) {
  char text[32];
  std::snprintf(text, sizeof text, format, value);
  return text;
}

}  // namespace

json SiteJson(const std::string& site, std::uint32_t domain, const SiteInstances& instances) {
  json stations = json::array(), workers = json::array();
  for (const auto& [id, entry] : instances.stations) {
    if (entry.alive) stations.push_back(entry.fields);
  }
  for (const auto& [id, entry] : instances.workers) {
    if (entry.alive) workers.push_back(entry.fields);
  }
  return {{"site", site}, {"domain", domain}, {"stations", stations}, {"workers", workers}};
}

std::string SiteTable(const json& site) {
  const json& stations = site["stations"];
  const json& workers = site["workers"];
  std::string out =
      "site " + Str(site, "site") + " (DDS domain " + std::to_string(site.value("domain", 0u)) +
      "): " + std::to_string(stations.size()) +
      (stations.size() == 1 ? " station, " : " stations, ") + std::to_string(workers.size()) +
      (workers.size() == 1 ? " worker" : " workers") + "\n";
  out += "\nSTATIONS\n";
  std::vector<Row> rows = {
      {"STATION", "STATE", "JOB", "RECONSTRUCTION", "REMOTE JOB -> WORKER", "LOAD"}};
  for (const json& s : stations) {
    std::string job = "-";
    if (!Str(s, "job_id").empty()) {
      job = Str(s, "job_id") + " " + Str(s, "job_verb") + " " + Str(s, "job_state") + " " +
            Format("%.0f%%", 100 * s.value("progress", 0.0));
    }
    std::string remote = "-";
    if (!Str(s, "remote_job").empty()) {
      remote = Str(s, "remote_job") + " -> " +
               (Str(s, "remote_worker").empty() ? "(offered)" : Str(s, "remote_worker"));
    }
    rows.push_back({Str(s, "station"), OrDash(Str(s, "state")), job,
                    OrDash(Str(s, "reconstruction")), remote,
                    Format("%.2f", s.value("load", 0.0))});
  }
  out += stations.empty() ? "  none\n" : Columns(rows);
  out += "\nWORKERS\n";
  rows = {{"WORKER", "STATE", "JOB", "STATION", "CORES", "LOAD", "JOBS DONE"}};
  for (const json& w : workers) {
    rows.push_back({Str(w, "worker"), OrDash(Str(w, "state")), OrDash(Str(w, "job_id")),
                    OrDash(Str(w, "station")), std::to_string(w.value("cores", 0u)),
                    Format("%.2f", w.value("load", 0.0)),
                    std::to_string(w.value("jobs_done", std::uint64_t{0}))});
  }
  out += workers.empty() ? "  none\n" : Columns(rows);
  return out;
}

int Site(const SiteOptions& options, const std::atomic<bool>* interrupted) {
  std::string why;
  if (!dds::IsValidSiteId(options.site, &why)) {
    std::fprintf(stderr, "craftscanctl: --site: %s\n", why.c_str());
    return kExitUsage;
  }
  dds::ParticipantOptions participant_options;
  participant_options.domain_id = options.domain;
  participant_options.config = ResolveDdsConfig(options.dds_config);
  if (!participant_options.IsValid(&why)) {
    std::fprintf(stderr, "craftscanctl: DDS: %s\n", why.c_str());
    return kExitUsage;
  }
  const std::shared_ptr<dds::Participant> participant =
      dds::Participant::Create(participant_options, &why);
  std::unique_ptr<dds::Reader<dds::msg::SiteStation>> stations;
  std::unique_ptr<dds::Reader<dds::msg::WorkerStatus>> workers;
  if (participant) {
    stations = dds::Reader<dds::msg::SiteStation>::Create(
        participant, dds::SiteStationTopic(options.site), &why);
  }
  if (stations) {
    workers = dds::Reader<dds::msg::WorkerStatus>::Create(
        participant, dds::WorkerStatusTopic(options.site), &why);
  }
  if (!workers) {
    std::fprintf(stderr, "craftscanctl: cannot join DDS domain %u: %s\n", options.domain,
                 why.c_str());
    return kExitLocalError;
  }
  // Both topics are transient-local: the live instances arrive as soon as
  // discovery matches their writers; the wait covers discovery.
  SiteInstances heard;
  const auto deadline =
      Clock::now() + std::chrono::milliseconds(static_cast<long long>(options.wait_s * 1000));
  constexpr std::chrono::milliseconds kSlice{50};
  while (Clock::now() < deadline) {
    if (interrupted != nullptr && interrupted->load()) return kExitInterrupted;
    if (!TakeInto(*stations, kSlice, &dds::msg::SiteStation::station, StationFields,
                  &heard.stations, &why) ||
        !TakeInto(*workers, kSlice, &dds::msg::WorkerStatus::worker, WorkerFields, &heard.workers,
                  &why)) {
      std::fprintf(stderr, "craftscanctl: site %s: %s\n", options.site.c_str(), why.c_str());
      return kExitLocalError;
    }
  }
  const json site = SiteJson(options.site, options.domain, heard);
  if (options.json) {
    std::printf("%s\n", site.dump(2, ' ', false, json::error_handler_t::replace).c_str());
  } else {
    std::fputs(SiteTable(site).c_str(), stdout);
  }
  std::fflush(stdout);
  return kExitOk;
}

}  // namespace craftscan::ctl
