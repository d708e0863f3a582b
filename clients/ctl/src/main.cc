// craftscanctl: the operator's command line for a craftscan station. Talks
// to craftscand only over DDS (commands, replies, status, progress, session
// files); parses arguments here and runs the subcommand (ctl.h).
//
// Exit codes (also printed by --help):
//   0    ok (a job: it ended done)
//   1    local failure: cannot write --out, DDS would not start
//   2    usage error: CLI11 parse errors, values checked locally, no token
//   3    refused by the daemon: any error Reply (bad_argument, forbidden,
//        unauthenticated, busy, not_found, unavailable, failed, ...)
//   4    the job failed or was cancelled; get: a file could not be fetched intact
//   5    daemon unreachable: none found, or no reply within --timeout
//   6    --max-wait passed while the job still runs (it goes on)
//   130  Ctrl-C while waiting for a job or a transfer (a job goes on)
#include <signal.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>

#include "craftscan/client/file_assembler.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/site.h"
#include "ctl.h"
#include "site_view.h"

namespace {

using craftscan::ctl::kExitUsage;

std::atomic<bool> g_interrupted{false};

void OnSignal(int) { g_interrupted.store(true); }

constexpr const char* kFooter = R"(Exit codes:
  0    ok (a job: it ended done)
  1    local failure: cannot write --out, DDS would not start
  2    usage error: bad option or value, no token
  3    refused by the daemon (bad_argument, forbidden, unauthenticated, busy,
       not_found, unavailable, failed, ...)
  4    the job failed or was cancelled; get: a file could not be fetched intact
  5    daemon unreachable: no reply within --timeout. Check that craftscand
       runs, that --station and --domain match its config, and that both use
       the same Cyclone DDS set-up (CYCLONEDDS_URI / --dds-config, network)
  6    --max-wait passed while the job still runs (it goes on)
  130  Ctrl-C while waiting (a job goes on at the station)

Environment: CRAFTSCAN_TOKEN (token), CRAFTSCAN_STATION, CRAFTSCAN_DDS_DOMAIN,
CRAFTSCAN_SITE (defaults for --station, --domain and site's --site),
CRAFTSCAN_SOURCE_ORGANIZATION (default for get --source-organization),
CYCLONEDDS_URI (Cyclone DDS configuration when --dds-config is not given;
without either, /etc/craftscan/cyclonedds.xml is used if present).)";

// "exposure=5000 gain=2" → {"exposure_us": 5000, "gain_db": 2}. False with *why.
bool ParseCameraSettings(const std::vector<std::string>& items, nlohmann::json* args,
                         std::string* why) {
  static const std::map<std::string, std::string> kKeys = {{"exposure", "exposure_us"},
                                                           {"exposure_us", "exposure_us"},
                                                           {"gain", "gain_db"},
                                                           {"gain_db", "gain_db"}};
  *args = nlohmann::json::object();
  for (const std::string& item : items) {
    const std::size_t eq = item.find('=');
    const std::string key = item.substr(0, eq);
    const auto it = kKeys.find(key);
    if (eq == std::string::npos || it == kKeys.end()) {
      *why = "camera set: '" + item + "': expected exposure=MICROSECONDS or gain=DB";
      return false;
    }
    const std::string text = item.substr(eq + 1);
    char* end = nullptr;
    const double value = std::strtod(text.c_str(), &end);
    if (text.empty() || *end != '\0' || !std::isfinite(value)) {
      *why = "camera set: '" + item + "': not a number";
      return false;
    }
    if (it->second == "exposure_us" ? value <= 0 : value < 0) {
      *why = "camera set: '" + item + "': " +
             (it->second == "exposure_us" ? "exposure must be > 0 us" : "gain must be >= 0 dB");
      return false;
    }
    if (args->contains(it->second)) {
      *why = "camera set: " + key + " given twice";
      return false;
    }
    (*args)[it->second] = value;
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "craftscanctl: operate a craftscan station (status, calibration, scans, "
      "sessions, results) over DDS"};
  app.require_subcommand(1);
  app.fallthrough();  // global options may follow the subcommand
  app.footer(kFooter);
  app.set_version_flag("--version", std::string("craftscanctl ") + CRAFTSCAN_VERSION);

  craftscan::ctl::GlobalOptions g;
  g.station = std::getenv("CRAFTSCAN_STATION") ? std::getenv("CRAFTSCAN_STATION") : "station1";
  if (const char* domain = std::getenv("CRAFTSCAN_DDS_DOMAIN")) {
    g.domain = static_cast<std::uint32_t>(std::strtoul(domain, nullptr, 10));
  }
  app.add_option("--station", g.station, "station id (craftscand's `station`)")
      ->capture_default_str();
  app.add_option("--domain", g.domain, "DDS domain id (craftscand's `dds.domain`)")
      ->check(CLI::Range(0u, craftscan::dds::kMaxDomainId))
      ->capture_default_str();
  app.add_option("--token", g.token, "authorisation token (else --token-file or CRAFTSCAN_TOKEN)");
  app.add_option("--token-file", g.token_file, "file whose first line is the token");
  app.add_option("--timeout", g.timeout_s,
                 "seconds to wait for the daemon (discovery and each reply)")
      ->check(CLI::Range(0.1, 3600.0))
      ->capture_default_str();
  app.add_flag("--json", g.json, "print machine-readable JSON instead of text");
  app.add_option("--dds-config", g.dds_config,
                 "Cyclone DDS configuration: a file or XML (default: CYCLONEDDS_URI)");

  craftscan::ctl::WaitOptions wait;
  bool no_wait = false;
  auto add_wait = [&](CLI::App* sub) {
    sub->add_flag("--no-wait", no_wait, "return once the job started");
    sub->add_option("--max-wait", wait.max_wait_s,
                    "give up waiting after this many seconds (exit 6; the job goes on)")
        ->check(CLI::NonNegativeNumber);
  };

  CLI::App* status =
      app.add_subcommand("status", "the station's state, devices, job and calibration");
  // site (and status --all): the site's stations and workers; no token.
  std::string site_name(craftscan::dds::kDefaultSite);
  if (const char* env = std::getenv("CRAFTSCAN_SITE")) site_name = env;
  double site_wait_s = 2;
  auto add_site_options = [&](CLI::App* sub) {
    CLI::Option* site_option =
        sub->add_option("--site", site_name,
                        "the site (craftscand's `site`; default: CRAFTSCAN_SITE, else default)")
            ->capture_default_str();
    CLI::Option* wait_option =
        sub->add_option("--wait", site_wait_s,
                        "seconds to listen for the site's stations and workers")
            ->check(CLI::Range(0.1, 600.0))
            ->capture_default_str();
    return std::make_pair(site_option, wait_option);
  };
  bool status_all = false;
  CLI::Option* all_option = status->add_flag(
      "--all", status_all, "every station and worker of the site instead (as `site`; no token)");
  const auto [status_site, status_wait] = add_site_options(status);
  status_site->needs(all_option);
  status_wait->needs(all_option);
  CLI::App* site = app.add_subcommand(
      "site",
      "every station and reconstruction worker of the site: state, job, reconstruction mode, "
      "remote job, load (listens only: no token needed)");
  add_site_options(site);
  CLI::App* devices = app.add_subcommand("devices", "the cameras and the turntable");
  CLI::App* sessions = app.add_subcommand("sessions", "the sessions on the station");
  CLI::App* calibrate = app.add_subcommand("calibrate", "calibrate the stereo cameras (admin)");
  add_wait(calibrate);
  CLI::App* calibrate_turntable =
      app.add_subcommand("calibrate-turntable", "find the turntable axis (admin)");
  add_wait(calibrate_turntable);
  std::string object;
  CLI::App* capture = app.add_subcommand("capture", "capture one view into a new session");
  capture->add_option("--object", object, "object name (names the session)");
  add_wait(capture);
  int views = 0;
  double step_deg = 0;
  CLI::App* scan = app.add_subcommand("scan",
                                      "scan an object: views around the turntable, "
                                      "registration, fusion, mesh, measurements");
  std::string add_to;
  CLI::Option* object_option = scan->add_option(
      "--object", object, "object name (names the session; required without --add-to)");
  scan->add_option("--add-to", add_to,
                   "another turn of this finished scan's session, the object laid in another pose "
                   "(on its side): captured into the same session and joined onto its first "
                   "turn, so the model has the base (views and step default to the first turn's)")
      ->excludes(object_option);
  scan->add_option("--views", views, "number of views (default: the station's)")
      ->check(CLI::Range(2, 360));
  scan->add_option("--step", step_deg, "turntable step between views, degrees (default 360/views)")
      ->check(CLI::Range(-360.0, 360.0));
  std::vector<double> bracket;
  bool no_bracket = false;
  CLI::Option* bracket_option =
      scan->add_option("--bracket", bracket,
                       "exposure bracketing: also capture each view at these multiples of the "
                       "exposure and merge (e.g. 8 for black paint; default: the station's)")
          ->delimiter(',')
          ->check(CLI::Range(1.0, 64.0));
  scan->add_flag("--no-bracket", no_bracket,
                 "one exposure per view, whatever the station's default")
      ->excludes(bracket_option);
  add_wait(scan);
  std::string session;
  CLI::App* resume = app.add_subcommand("resume", "continue an interrupted or failed session");
  resume->add_option("SESSION", session, "session id")->required();
  add_wait(resume);
  CLI::App* cancel =
      app.add_subcommand("cancel", "cancel the running job (its session stays resumable)");
  std::string out_dir;
  std::vector<std::string> files;
  int chunk_kib = 1024;
  CLI::App* get = app.add_subcommand(
      "get", "fetch a session's results (fused cloud, mesh, report, previews) into a folder");
  get->add_option("SESSION", session, "session id")->required();
  std::string bag_dir, source_organization;
  CLI::Option* out_option =
      get->add_option("--out", out_dir, "folder to write the files to (created)");
  CLI::Option* bagit_option = get->add_option(
      "--bagit", bag_dir,
      "write a BagIt 1.0 bag (RFC 8493) to this new or empty folder instead: the whole "
      "session (manifest.json, calibration.yaml, views/, the outputs) or the --file outputs "
      "under data/, bagit.txt, bag-info.txt, manifest-sha256.txt, tagmanifest-sha256.txt");
  out_option->excludes(bagit_option);
  get->add_option("--source-organization", source_organization,
                  "bag-info.txt Source-Organization of a --bagit bag (default: "
                  "CRAFTSCAN_SOURCE_ORGANIZATION)")
      ->needs(bagit_option);
  get->add_option("--file", files, "only this output (repeatable), e.g. fused.ply, previews/a.png");
  get->add_option("--chunk-kib", chunk_kib, "transfer chunk size, KiB")
      ->check(CLI::Range(4, 4096))
      ->capture_default_str();
  int count = 0;
  double duration_s = 0;
  CLI::App* watch = app.add_subcommand("watch", "follow status and progress until Ctrl-C");
  watch->add_option("--count", count, "stop after this many events")->check(CLI::NonNegativeNumber);
  watch->add_option("--duration", duration_s, "stop after this many seconds")
      ->check(CLI::NonNegativeNumber);
  CLI::App* turntable = app.add_subcommand("turntable", "home the turntable or move it");
  turntable->require_subcommand(1);
  CLI::App* home = turntable->add_subcommand("home", "run the homing cycle");
  double angle_deg = 0;
  CLI::App* move = turntable->add_subcommand("move", "move to an absolute angle");
  move->add_option("DEG", angle_deg, "angle, degrees")
      ->required()
      ->check(CLI::Range(-3600.0, 3600.0));
  CLI::App* camera = app.add_subcommand("camera", "camera settings");
  camera->require_subcommand(1);
  std::vector<std::string> settings;
  CLI::App* camera_set = camera->add_subcommand("set", "set exposure=MICROSECONDS and/or gain=DB");
  camera_set->add_option("SETTING", settings, "exposure=… gain=…")->required()->expected(-1);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);  // prints help, version or the error
    return code == 0 ? 0 : kExitUsage;
  }
  wait.wait = !no_wait;

  // Checks that need no daemon, before connecting.
  nlohmann::json camera_args;
  std::string why;
  if (*camera_set && !ParseCameraSettings(settings, &camera_args, &why)) {
    std::fprintf(stderr, "craftscanctl: %s\n", why.c_str());
    return kExitUsage;
  }
  if (*scan && object.empty() && add_to.empty()) {
    std::fprintf(stderr,
                 "craftscanctl: scan needs --object NAME (a new session) or --add-to "
                 "SESSION (another turn of a finished scan)\n");
    return kExitUsage;
  }
  if (*get && out_dir.empty() && bag_dir.empty()) {
    std::fprintf(stderr, "craftscanctl: get needs --out DIR or --bagit DIR\n");
    return kExitUsage;
  }
  if (!bag_dir.empty() && source_organization.empty()) {
    if (const char* env = std::getenv("CRAFTSCAN_SOURCE_ORGANIZATION")) source_organization = env;
    if (source_organization.empty()) {
      std::fprintf(stderr,
                   "craftscanctl: --bagit needs the bag's Source-Organization: "
                   "--source-organization NAME or CRAFTSCAN_SOURCE_ORGANIZATION\n");
      return kExitUsage;
    }
  }
  for (const std::string& name : files) {
    if (!craftscan::client::IsSafeFileName(name, &why)) {
      std::fprintf(stderr, "craftscanctl: --file: %s\n", why.c_str());
      return kExitUsage;
    }
  }

  struct sigaction action {};
  action.sa_handler = OnSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
  signal(SIGPIPE, SIG_IGN);

  if (*site || (*status && status_all)) {
    craftscan::ctl::SiteOptions options;
    options.site = site_name;
    options.domain = g.domain;
    options.dds_config = g.dds_config;
    options.wait_s = site_wait_s;
    options.json = g.json;
    return craftscan::ctl::Site(options, &g_interrupted);
  }

  craftscan::ctl::Ctl ctl(&g_interrupted);
  if (const int rc = ctl.Init(g)) return rc;
  using nlohmann::json;
  if (*status) return ctl.Status();
  if (*devices) return ctl.Devices();
  if (*sessions) return ctl.Sessions();
  if (*calibrate) return ctl.Job("calibrate", nullptr, wait);
  if (*calibrate_turntable) return ctl.Job("calibrate-turntable", nullptr, wait);
  if (*capture) {
    return ctl.Job("capture", object.empty() ? json::object() : json{{"object", object}}, wait);
  }
  if (*scan) {
    json args = add_to.empty() ? json{{"object", object}} : json{{"add_to", add_to}};
    if (views > 0) args["views"] = views;
    if (step_deg != 0) args["step_deg"] = step_deg;
    if (!bracket.empty() || no_bracket) args["exposure_bracket"] = bracket;
    return ctl.Job("scan", args, wait);
  }
  if (*resume) return ctl.Job("resume", {{"session", session}}, wait);
  if (*cancel) return ctl.Cancel();
  if (*get && !bag_dir.empty()) {
    return ctl.GetBag(session, bag_dir, source_organization, files,
                      static_cast<std::size_t>(chunk_kib) * 1024);
  }
  if (*get) return ctl.Get(session, out_dir, files, static_cast<std::size_t>(chunk_kib) * 1024);
  if (*watch) return ctl.Watch(count, duration_s);
  if (*home) return ctl.Turntable({{"action", "home"}});
  if (*move) return ctl.Turntable({{"action", "move"}, {"angle_deg", angle_deg}});
  if (*camera_set) return ctl.Camera(camera_args);
  return kExitUsage;
}
