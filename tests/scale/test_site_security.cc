// DDS Security on a site (issue 21): a secured station and reconstruction
// workers as separate hosts (site_harness.h: a network namespace on a bridge
// and a CPU cgroup per host), the real programs over Cyclone DDS with its
// security plugins.
//
// The PKI is made by scripts/dds-security-setup as a site would: one site CA
// (--ca) that signs the station's identities (daemon, client "console") and
// the worker "wsite" (--worker, role worker: the site topics in the site's
// partition, craftscan/*/command, reply and file for `get`). Each process
// gets its identity's generated cyclonedds.xml with the host's interface
// and peers added: craftscand through dds.config_file
// (CRAFTSCAN_DDS_CONFIG_FILE), craftscan-worker through its config's
// dds.config_file, craftscanctl through --dds-config.
//
// First, with two workers that hold the operator token the station lists but
// no identity of the site CA -- "wforeign" (an identity of the same name
// scheme, issued by another CA) and "wplain" (no DDS Security at all) -- a
// scan is reconstructed locally: no claim of theirs ever reaches the station
// (its log has no claim of them, refused or granted), none is granted, and
// the station falls back once the offer times out. Then "wsite" joins: the
// next scan is granted to it, and its model is stored once, intact, and
// equal byte for byte to the station's own reconstruction of the same views
// (LocalFusedPly); the foreign workers still have no grant. `craftscanctl
// site` with the console identity lists the station and wsite only.
//
// Skips (with the reason) without root, network namespaces, cgroup v1,
// openssl, or Cyclone's security plugins (libdds_security_{auth,ac,crypto}
// from Debian's libddsc0debian).
#include <gtest/gtest.h>

#include <dlfcn.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <dds/dds.h>
#include <nlohmann/json.hpp>

#include "../site/remote_check.h"
#include "daemon_fixture.h"
#include "file_util.h"
#include "process_util.h"
#include "site_harness.h"
#include "test_paths.h"

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

// Hosts: the station, then the workers.
constexpr std::size_t kStation = 0, kSiteWorker = 1, kForeignWorker = 2, kPlainWorker = 3;
constexpr int kViews = 4;
constexpr const char* kStep = "90";
constexpr const char* kImageSize = "320x256";
// Long enough for an idle worker's claim (every second), short enough for
// the fallback case.
constexpr const char* kReconstruction = "{mode: remote, offer_timeout_ms: 5000, max_remote_s: 300}";

// Why Cyclone's security plugins cannot be loaded, or "" if they can: they
// are looked up as Cyclone does, by name and then in libddsc0debian/ beside
// libddsc.
std::string SecurityPluginsMissing() {
  Dl_info info{};
  std::string dir;
  if (::dladdr(reinterpret_cast<void*>(&dds_create_participant), &info) != 0 &&
      info.dli_fname != nullptr)
    dir = std::filesystem::path(info.dli_fname).parent_path().string();
  for (const char* plugin : {"auth", "ac", "crypto"}) {
    const std::string name = std::string("libdds_security_") + plugin + ".so";
    void* handle = ::dlopen(name.c_str(), RTLD_LAZY | RTLD_LOCAL);
    if (handle == nullptr && !dir.empty())
      handle = ::dlopen((dir + "/libddsc0debian/" + name).c_str(), RTLD_LAZY | RTLD_LOCAL);
    if (handle == nullptr)
      return name + " not found (Cyclone DDS's security plugins: Debian's libddsc0debian)";
    ::dlclose(handle);
  }
  return "";
}

bool Eventually(const std::function<bool()>& done, std::chrono::milliseconds limit) {
  const auto deadline = Clock::now() + limit;
  while (!done()) {
    if (Clock::now() > deadline) return false;
    std::this_thread::sleep_for(50ms);
  }
  return true;
}

std::size_t Count(const std::string& text, const std::string& what) {
  std::size_t n = 0;
  for (std::size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

class SecuredSite {
 public:
  // Null with *why when the site cannot be made here (skip).
  static std::unique_ptr<SecuredSite> Create(std::string* why) {
    auto site = std::unique_ptr<SecuredSite>(new SecuredSite);
    site->net_ = SiteNetwork::Create(
        {{"station", 0.5}, {"wsite", 0.5}, {"wforeign", 0.3}, {"wplain", 0.3}}, why);
    if (!site->net_) return nullptr;
    std::random_device rd;
    site->domain_ = 1 + rd() % 200;
    site->site_ = "secured" + std::to_string(::getpid());
    site->station_ = std::make_unique<DaemonFixture>(kImageSize);
    site->station_->set_domain(site->domain_);
    return site;
  }

  SiteNetwork& net() { return *net_; }
  DaemonFixture& station() { return *station_; }
  const std::string& site() const { return site_; }
  std::string dir() const { return net_->work_dir(); }

  // dds-security-setup for the station (out `out`) with `extra` options;
  // false with a test failure naming its output.
  bool Setup(const std::string& out, const std::vector<std::string>& extra) {
    std::vector<std::string> argv = {DdsSecuritySetupPath(),
                                     "--out",
                                     out,
                                     "--station",
                                     station_->station(),
                                     "--site",
                                     site_,
                                     "--domain",
                                     std::to_string(domain_),
                                     "--base-config",
                                     CycloneDdsXml()};
    argv.insert(argv.end(), extra.begin(), extra.end());
    std::string output;
    const int code = net_->Run(kStation, argv, &output, 120s);
    EXPECT_EQ(code, 0) << "dds-security-setup: " << output;
    return code == 0;
  }

  // The identity's generated cyclonedds.xml with the host's interface and
  // peers (HostDdsXml) added as one more <Domain>, the same way the script
  // adds its <Security> block: one file, for dds.config_file.
  std::string HostConfig(std::size_t host, const std::string& identity) {
    const std::string bundle = ReadFile(identity + "/cyclonedds.xml");
    std::string fragment = net_->HostDdsXml(host);
    fragment = fragment.substr(std::string("<CycloneDDS>").size());
    fragment.resize(fragment.size() - std::string("</CycloneDDS>").size());
    const std::size_t close = bundle.rfind("</CycloneDDS>");
    EXPECT_NE(close, std::string::npos) << identity;
    const std::string path = dir() + "/" + net_->name(host) + "-" +
                             std::filesystem::path(identity).filename().string() + ".xml";
    std::ofstream(path) << bundle.substr(0, close) << fragment << bundle.substr(close);
    return path;
  }

  bool StartStation(const std::string& dds_config_file, std::string* error) {
    station_->launcher = net_->Launcher(kStation);
    station_->launcher.push_back("CRAFTSCAN_DDS_CONFIG_FILE=" + dds_config_file);
    station_->extra_yaml = "site: " + site_ + "\nreconstruction: " + kReconstruction + "\n";
    return station_->Prepare(error) && station_->Start(error);
  }

  // craftscan-worker `name` in `host` with the operator token (one the
  // station lists) and dds.config_file `dds_config_file` ("" = none: the
  // host's plain CYCLONEDDS_URI).
  bool StartWorker(std::size_t host, const std::string& name, const std::string& dds_config_file,
                   std::string* error) {
    const std::string wdir = dir() + "/" + name;
    std::filesystem::create_directories(wdir);
    std::ofstream(wdir + "/worker.token") << kOperatorToken << "\n";
    std::filesystem::permissions(wdir + "/worker.token", std::filesystem::perms::owner_read |
                                                             std::filesystem::perms::owner_write);
    std::ofstream(wdir + "/craftscan-worker.yaml")
        << "version: 1\nworker: " << name << "\nsite: " << site_ << "\nlog_level: info\n"
        << "dds: {domain: " << domain_ << ", config_file: \"" << dds_config_file << "\"}\n"
        << "auth: {token_file: " << wdir << "/worker.token}\nthreads: " << TestThreads()
        << "\nwork_dir: " << wdir << "/work\nwatchdog: {enabled: false}\n";
    logs_[host] = wdir + "/worker.log";
    HostCommand command;
    command.argv = {WorkerPath(), "--config", wdir + "/craftscan-worker.yaml"};
    command.stdout_path = logs_[host];
    ChildProcess& child = workers_[host];
    if (!net_->Start(host, command, &child, error)) return false;
    const bool ready = Eventually(
        [&] { return WorkerLog(host).find("ready: announced") != std::string::npos; }, 30s);
    if (!ready || !child.Running()) {
      *error = "worker " + name + " did not come up:\n" + WorkerLog(host);
      return false;
    }
    return true;
  }
  std::string WorkerLog(std::size_t host) const {
    const auto it = logs_.find(host);
    return it == logs_.end() ? "" : ReadFile(it->second);
  }
  bool WorkerRunning(std::size_t host) { return workers_[host].Running(); }

  // craftscanctl in the station's host with the console identity: its exit
  // code (-1 if it did not end within `limit`), *out its stdout, *err its
  // stderr.
  int Ctl(const std::string& console_config, const std::vector<std::string>& args,
          std::chrono::seconds limit, std::string* out, std::string* err = nullptr) {
    HostCommand command;
    command.argv = {CraftscanctlPath(),
                    "--station",
                    station_->station(),
                    "--domain",
                    std::to_string(domain_),
                    "--dds-config",
                    console_config,
                    "--timeout",
                    "30",
                    "--token",
                    kOperatorToken};
    command.argv.insert(command.argv.end(), args.begin(), args.end());
    const std::string tag = dir() + "/ctl" + std::to_string(++ctl_runs_);
    command.stdout_path = tag + ".out";
    command.stderr_path = tag + ".err";
    ChildProcess child;
    std::string error;
    if (!net_->Start(kStation, command, &child, &error)) {
      ADD_FAILURE() << error;
      return -1;
    }
    const int code = child.Wait(limit);
    *out = ReadFile(command.stdout_path);
    if (err != nullptr) *err = ReadFile(command.stderr_path);
    return code;
  }

  std::string Logs() const {
    std::string all = "\n--- craftscand.log:\n" + station_->Log();
    for (const auto& [host, path] : logs_)
      all += "\n--- " + net_->name(host) + " log:\n" + ReadFile(path);
    return all;
  }

 private:
  SecuredSite() = default;
  // Declared first: destroyed last, after the processes below.
  std::unique_ptr<SiteNetwork> net_;
  std::uint32_t domain_ = 0;
  std::string site_;
  std::unique_ptr<DaemonFixture> station_;
  std::map<std::size_t, ChildProcess> workers_;
  std::map<std::size_t, std::string> logs_;
  int ctl_runs_ = 0;
};

// A scan's JSON: the session and result.remote (null when absent).
struct Scan {
  int code = -2;
  std::string session, output;
  json remote = json::object();
};

Scan RunScan(SecuredSite& site, const std::string& console_config) {
  Scan scan;
  std::string err;
  scan.code = site.Ctl(
      console_config,
      {"scan", "--object", "box", "--views", std::to_string(kViews), "--step", kStep, "--json"},
      240s, &scan.output, &err);
  const json job = json::parse(scan.output, nullptr, false);
  if (job.is_object()) {
    const json result = job.value("result", job);
    scan.session = job.value("session", result.value("session", ""));
    scan.remote = result.value("remote", json::object());
  }
  scan.output += "\nstderr:\n" + err;
  return scan;
}

// The model of `session` is stored once, intact, and is the station's own
// reconstruction of the stored views.
void ExpectModelStoredOnce(DaemonFixture& station, const std::string& session) {
  ASSERT_FALSE(session.empty());
  std::string error;
  auto store = daemon::SessionStore::Open(station.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  const daemon::VerifyResult verified = store->Verify(session);
  EXPECT_TRUE(verified.IsIntact())
      << (verified.problems.empty() ? "manifest unreadable" : verified.problems.front());
  daemon::Manifest m;
  {
    // (Closed again before LocalFusedPly opens it.)
    auto s = store->OpenSession(session, StatusInto(&error));
    ASSERT_TRUE(s) << error;
    m = s->manifest();
  }
  EXPECT_EQ(m.state, daemon::SessionState::kDone) << m.error;
  int fused_stored = 0;
  for (const daemon::JournalEntry& e : m.journal)
    fused_stored += e.event == "output" && e.detail == "fused.ply" ? 1 : 0;
  EXPECT_EQ(fused_stored, 1) << "fused.ply stored " << fused_stored << " times";
  const std::string model = ReadFile(station.data_dir() + "/sessions/" + session + "/fused.ply");
  EXPECT_FALSE(model.empty());
  EXPECT_TRUE(model == LocalFusedPly(station.root() + "/craftscand.yaml", station.data_dir(),
                                     session, TestThreads()))
      << "fused.ply (" << model.size() << " bytes) differs from a local reconstruction";
}

TEST(SiteSecurity, OnlyAWorkerOfTheSiteCaIsGrantedAndItsModelIsTheStationsOwn) {
  const auto start = Clock::now();
  if (const std::string why = SecurityPluginsMissing(); !why.empty()) GTEST_SKIP() << why;
  if (::access("/usr/bin/openssl", X_OK) != 0) GTEST_SKIP() << "openssl not installed";
  std::string why;
  auto site = SecuredSite::Create(&why);
  if (!site) GTEST_SKIP() << "site network unavailable: " << why;

  // The site CA signs the station's identities and the site's worker;
  // another CA (the station's own, as made without --ca) signs "wforeign".
  const std::string pki = site->dir() + "/pki", foreign = site->dir() + "/foreign";
  ASSERT_TRUE(site->Setup(
      pki, {"--ca", site->dir() + "/site-ca", "--client", "console", "--worker", "wsite"}));
  ASSERT_TRUE(site->Setup(foreign, {"--worker", "wforeign"}));
  EXPECT_NE(ReadFile(pki + "/identities/wsite/cert.pem"), "");
  const std::string console = site->HostConfig(kStation, pki + "/identities/console");

  std::string error;
  ASSERT_TRUE(site->StartStation(site->HostConfig(kStation, pki + "/identities/daemon"), &error))
      << error;
  ASSERT_TRUE(site->StartWorker(kForeignWorker, "wforeign",
                                site->HostConfig(kForeignWorker, foreign + "/identities/wforeign"),
                                &error))
      << error;
  ASSERT_TRUE(site->StartWorker(kPlainWorker, "wplain", "", &error)) << error;
  ASSERT_TRUE(Eventually(
      [&] {
        std::string out;
        return site->Ctl(console, {"status", "--json"}, 60s, &out) == 0;
      },
      60s))
      << "the secured station did not answer its secured console" << site->Logs();

  // 1. No worker of the site: the foreign ones are never heard, the
  //    station reconstructs itself.
  const Scan local = RunScan(*site, console);
  ASSERT_EQ(local.code, 0) << local.output << site->Logs();
  EXPECT_EQ(local.remote.value("outcome", ""), "local") << local.remote.dump();
  EXPECT_NE(local.remote.value("why", "").find("no worker claimed it within 5000 ms"),
            std::string::npos)
      << local.remote.dump();
  ExpectModelStoredOnce(site->station(), local.session);

  // 2. The site's worker joins and is granted the next scan.
  ASSERT_TRUE(site->StartWorker(kSiteWorker, "wsite",
                                site->HostConfig(kSiteWorker, pki + "/identities/wsite"), &error))
      << error;
  const Scan remote = RunScan(*site, console);
  ASSERT_EQ(remote.code, 0) << remote.output << site->Logs();
  EXPECT_EQ(remote.remote.value("outcome", ""), "done") << remote.remote.dump() << site->Logs();
  EXPECT_EQ(remote.remote.value("worker", ""), "wsite") << remote.remote.dump();
  ExpectModelStoredOnce(site->station(), remote.session);
  const std::string log = site->station().Log();
  EXPECT_EQ(Count(log, ": result of worker wsite"), 1u) << site->Logs();
  EXPECT_EQ(Count(log, "granted to worker wsite"), 1u) << site->Logs();

  // The foreign workers ran throughout, held a listed token, and never got
  // a claim through: DDS Security, not the token check, kept them out.
  for (const std::size_t host : {kForeignWorker, kPlainWorker}) {
    const std::string name = site->net().name(host);
    EXPECT_TRUE(site->WorkerRunning(host)) << name << site->Logs();
    EXPECT_EQ(site->WorkerLog(host).find(": granted (grant"), std::string::npos) << site->Logs();
    EXPECT_EQ(log.find("worker '" + name + "'"), std::string::npos) << site->Logs();
    EXPECT_EQ(log.find("worker " + name), std::string::npos) << site->Logs();
  }

  // The console identity reads the site's topics: the station and wsite.
  std::string view;
  EXPECT_EQ(
      site->Ctl(console, {"site", "--site", site->site(), "--wait", "3", "--json"}, 60s, &view), 0)
      << view;
  EXPECT_NE(view.find("\"" + site->station().station() + "\""), std::string::npos) << view;
  EXPECT_NE(view.find("\"wsite\""), std::string::npos) << view;
  EXPECT_EQ(view.find("wforeign"), std::string::npos) << view;
  EXPECT_EQ(view.find("wplain"), std::string::npos) << view;
  std::printf("site-security: local fallback, then wsite granted; %.1f s in all\n",
              std::chrono::duration<double>(Clock::now() - start).count());
}

}  // namespace
}  // namespace craftscan::testing
