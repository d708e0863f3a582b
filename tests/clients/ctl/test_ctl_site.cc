// craftscanctl site end to end: real craftscand daemons (sim station,
// 320x256) on one private loopback domain, two on one site and one on
// another, and a reconstruction worker played by this test (it writes and
// renews a WorkerStatus instance on the site's topic). The site view lists
// exactly the site's live stations and workers, and drops a worker that
// disposed its instance, a station whose daemon was killed (its liveliness
// lease lapses) and one that stopped cleanly (it disposes its instance).
#include <gtest/gtest.h>

#include <signal.h>
#include <sys/wait.h>

#include <atomic>
#include <chrono>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/site.h"
#include "ctl_runner.h"
#include "daemon_fixture.h"
#include "dds_test_util.h"
#include "file_util.h"
#include "wait_util.h"

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

std::string Describe(const CtlRun& r) {
  return "exit " + std::to_string(r.exit_code) + "\nstdout:\n" + r.out + "\nstderr:\n" + r.err;
}

// A craftscand of the sim station on the test's domain and `site`.
std::unique_ptr<DaemonFixture> StartDaemon(const std::string& site, const std::string& extra,
                                           std::string* error) {
  auto daemon = std::make_unique<DaemonFixture>("320x256");
  daemon->set_domain(ProcessDomainId());
  daemon->extra_yaml = "site: " + site + "\n" + extra;
  daemon->pipeline_extra = ", mesh: false";
  if (!daemon->Prepare(error) || !daemon->Start(error)) return nullptr;
  return daemon;
}

// Plays a reconstruction worker of `site`: writes its WorkerStatus every
// kWorkerLeaseMs/5 (renewing its lease) until Dispose.
class FakeWorker {
 public:
  FakeWorker(std::shared_ptr<dds::Participant> participant, const std::string& site,
             const std::string& id, const std::string& station) {
    std::string error;
    writer_ = dds::Writer<dds::msg::WorkerStatus>::Create(std::move(participant),
                                                          dds::WorkerStatusTopic(site), &error);
    EXPECT_NE(writer_, nullptr) << error;
    status_.msg().worker = status_.Keep(id);
    status_.msg().state = status_.Keep("reconstructing");
    status_.msg().job_id = status_.Keep(station + "/20260101-000000-box/1");
    status_.msg().station = status_.Keep(station);
    status_.msg().grant = 2;
    status_.msg().cores = 3;
    status_.msg().load = 0.25;
    status_.msg().jobs_done = 7;
    if (!writer_) return;
    thread_ = std::thread([this] {
      while (!stop_.load()) {
        status_.msg().stamp_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                                     std::chrono::system_clock::now().time_since_epoch())
                                     .count();
        std::string why;
        EXPECT_TRUE(writer_->Write(status_.msg(), &why)) << why;
        std::this_thread::sleep_for(std::chrono::milliseconds(dds::kWorkerLeaseMs / 5));
      }
    });
  }
  ~FakeWorker() { StopRenewing(); }

  // Stops renewing and disposes the instance (a worker that stops).
  void Dispose() {
    StopRenewing();
    std::string error;
    ASSERT_TRUE(writer_ && writer_->Dispose(status_.msg(), &error)) << error;
  }

 private:
  void StopRenewing() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }

  std::unique_ptr<dds::Writer<dds::msg::WorkerStatus>> writer_;
  dds::Outgoing<dds::msg::WorkerStatus> status_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

class SiteView {
 public:
  explicit SiteView(std::string site) : site_(std::move(site)) {}

  // craftscanctl [global options] site --site <site> --wait <wait_s> `extra`.
  std::vector<std::string> Args(double wait_s, const std::vector<std::string>& extra,
                                const std::string& site = "") const {
    std::vector<std::string> args = {"--domain",
                                     std::to_string(ProcessDomainId()),
                                     "--dds-config",
                                     TestDdsConfig(),
                                     "site",
                                     "--site",
                                     site.empty() ? site_ : site,
                                     "--wait",
                                     std::to_string(wait_s)};
    args.insert(args.end(), extra.begin(), extra.end());
    return args;
  }
  // Starts `site --json` listening for `wait_s` seconds.
  std::unique_ptr<CtlProcess> StartJson(double wait_s, const std::string& site = "") {
    return std::make_unique<CtlProcess>(dir_.path(), "site" + std::to_string(++runs_),
                                        Args(wait_s, {"--json"}, site));
  }
  CtlRun Run(double wait_s, const std::vector<std::string>& extra) {
    CtlProcess process(dir_.path(), "site" + std::to_string(++runs_), Args(wait_s, extra));
    return process.Wait(60s);
  }
  // The listing of one `site --json` run; null if it failed (reported).
  json Listing(double wait_s = 1, const std::string& site = "") {
    const CtlRun r = StartJson(wait_s, site)->Wait(60s);
    EXPECT_EQ(r.exit_code, 0) << Describe(r);
    return Parse(r);
  }
  static json Parse(const CtlRun& r) {
    const json value = json::parse(r.out, nullptr, false);
    return value.is_discarded() ? json() : value;
  }
  const std::string& dir() const { return dir_.path(); }

 private:
  std::string site_;
  TempDir dir_{"craftscanctl-site"};
  int runs_ = 0;
};

// station id → its entry in a listing.
std::map<std::string, json> Stations(const json& listing) {
  std::map<std::string, json> out;
  if (!listing.is_object()) return out;
  for (const json& s : listing.value("stations", json::array())) out[s.value("station", "")] = s;
  return out;
}
std::map<std::string, json> Workers(const json& listing) {
  std::map<std::string, json> out;
  if (!listing.is_object()) return out;
  for (const json& w : listing.value("workers", json::array())) out[w.value("worker", "")] = w;
  return out;
}

// Lists `site` until every station of `ids` is idle on it (daemons start in
// a few seconds). The last listing.
json WaitUntilIdle(SiteView& view, const std::set<std::string>& ids, const std::string& site = "") {
  json listing;
  WaitFor(
      [&] {
        listing = view.Listing(1, site);
        const auto stations = Stations(listing);
        for (const std::string& id : ids) {
          const auto it = stations.find(id);
          if (it == stations.end() || it->second.value("state", "") != "idle") return false;
        }
        return true;
      },
      45s, 100ms);
  return listing;
}

std::set<std::string> Ids(const std::map<std::string, json>& entries) {
  std::set<std::string> ids;
  for (const auto& [id, entry] : entries) ids.insert(id);
  return ids;
}

TEST(CraftscanctlSite, ListsTheSitesLiveStationsAndWorkersAndDropsThoseThatEnd) {
  const std::string site = UniqueStation("s");
  const std::string other_site = UniqueStation("o");
  std::string error;
  auto a = StartDaemon(site, "reconstruction: {mode: auto}\n", &error);
  ASSERT_NE(a, nullptr) << error;
  auto b = StartDaemon(site, "", &error);
  ASSERT_NE(b, nullptr) << error;
  auto elsewhere = StartDaemon(other_site, "reconstruction: {mode: remote}\n", &error);
  ASSERT_NE(elsewhere, nullptr) << error;
  auto participant = MakeTestParticipant();
  ASSERT_NE(participant, nullptr);
  const std::string worker_id = UniqueStation("w");
  auto worker = std::make_unique<FakeWorker>(participant, site, worker_id, a->station());

  SiteView view(site);
  // The other site's daemon is up (on its own site), so its absence below
  // means the partitions keep it out.
  json listing = WaitUntilIdle(view, {elsewhere->station()}, other_site);
  EXPECT_EQ(Ids(Stations(listing)), std::set<std::string>{elsewhere->station()}) << listing;
  EXPECT_EQ(Stations(listing)[elsewhere->station()].value("reconstruction", ""), "remote");
  EXPECT_TRUE(Workers(listing).empty()) << listing;

  listing = WaitUntilIdle(view, {a->station(), b->station()});
  auto stations = Stations(listing);
  ASSERT_EQ(Ids(stations), (std::set<std::string>{a->station(), b->station()}))
      << listing << a->Log() << b->Log();
  EXPECT_EQ(listing.value("site", ""), site);
  for (const auto& [id, s] : stations) {
    EXPECT_EQ(s.value("state", ""), "idle") << s;
    EXPECT_EQ(s.value("remote_job", "x"), "") << s;
    EXPECT_EQ(s.value("remote_worker", "x"), "") << s;
    EXPECT_GE(s.value("load", -1.0), 0.0) << s;
    EXPECT_GT(s.value("stamp_ns", 0LL), 0LL) << s;
  }
  EXPECT_EQ(stations[a->station()].value("reconstruction", ""), "auto");
  EXPECT_EQ(stations[b->station()].value("reconstruction", ""), "local");
  auto workers = Workers(listing);
  ASSERT_EQ(Ids(workers), std::set<std::string>{worker_id}) << listing;
  const json& w = workers[worker_id];
  EXPECT_EQ(w.value("state", ""), "reconstructing");
  EXPECT_EQ(w.value("job_id", ""), a->station() + "/20260101-000000-box/1");
  EXPECT_EQ(w.value("station", ""), a->station());
  EXPECT_EQ(w.value("grant", 0u), 2u);
  EXPECT_EQ(w.value("cores", 0u), 3u);
  EXPECT_DOUBLE_EQ(w.value("load", 0.0), 0.25);
  EXPECT_EQ(w.value("jobs_done", 0u), 7u);

  // The worker stops: its disposed instance is gone at once.
  worker->Dispose();
  listing = view.Listing();
  EXPECT_TRUE(Workers(listing).empty()) << listing;
  EXPECT_EQ(Ids(Stations(listing)), (std::set<std::string>{a->station(), b->station()}));

  // A daemon killed (no disposal): a listener that saw it alive drops it
  // when its liveliness lease lapses (NOT_ALIVE_NO_WRITERS), well before
  // DDS would notice the dead participant (its 10 s lease).
  {
    // It listens 9 s; `a` dies within 3 s of its start: its lease (4 s)
    // lapses before the listener ends, the participant's (10 s) would not.
    const auto started = Clock::now();
    auto long_view = view.StartJson(9);
    // A view started with it hears `a` alive (discovery takes a moment).
    const CtlRun before = view.StartJson(1.5)->Wait(60s);
    ASSERT_EQ(before.exit_code, 0) << Describe(before);
    ASSERT_EQ(Stations(SiteView::Parse(before)).count(a->station()), 1u) << before.out;
    const double killed_at = std::chrono::duration<double>(Clock::now() - started).count();
    ASSERT_LT(killed_at, 3.0) << "the short view took too long for the timing to prove anything";
    a->Stop(SIGKILL);
    const CtlRun after = long_view->Wait(60s);
    ASSERT_EQ(after.exit_code, 0) << Describe(after);
    EXPECT_EQ(Ids(Stations(SiteView::Parse(after))), std::set<std::string>{b->station()})
        << "killed " << killed_at << " s after the listener started:\n"
        << after.out;
  }
  listing = view.Listing();
  EXPECT_EQ(Ids(Stations(listing)), std::set<std::string>{b->station()}) << listing;

  // A daemon stopped cleanly disposes its instance.
  {
    auto long_view = view.StartJson(6);
    const CtlRun before = view.StartJson(1.5)->Wait(60s);
    ASSERT_EQ(Stations(SiteView::Parse(before)).count(b->station()), 1u) << Describe(before);
    const int status = b->Stop(SIGTERM, 30s);
    ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << status << "\n" << b->Log();
    const CtlRun after = long_view->Wait(60s);
    ASSERT_EQ(after.exit_code, 0) << Describe(after);
    EXPECT_TRUE(Stations(SiteView::Parse(after)).empty()) << after.out;
  }
  listing = view.Listing();
  EXPECT_TRUE(Stations(listing).empty()) << listing;
  EXPECT_TRUE(Workers(listing).empty()) << listing;
  // The other site's station was never affected.
  EXPECT_EQ(Ids(Stations(view.Listing(1, other_site))),
            std::set<std::string>{elsewhere->station()});
}

TEST(CraftscanctlSite, TableNamesEachStationAndWorkerAndUsageErrorsExit2) {
  const std::string site = UniqueStation("s");
  std::string error;
  auto a = StartDaemon(site, "", &error);
  ASSERT_NE(a, nullptr) << error;
  auto b = StartDaemon(site, "reconstruction: {mode: remote}\n", &error);
  ASSERT_NE(b, nullptr) << error;
  auto participant = MakeTestParticipant();
  ASSERT_NE(participant, nullptr);
  const std::string worker_id = UniqueStation("w");
  FakeWorker worker(participant, site, worker_id, b->station());

  SiteView view(site);
  WaitUntilIdle(view, {a->station(), b->station()});
  CtlRun r = view.Run(1, {});
  ASSERT_EQ(r.exit_code, 0) << Describe(r);
  EXPECT_NE(r.out.find("site " + site + " (DDS domain " + std::to_string(ProcessDomainId()) +
                       "): 2 stations, 1 worker"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("STATIONS"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("WORKERS"), std::string::npos) << r.out;
  // One row per station, naming its state and mode; the worker's row.
  const std::vector<std::pair<std::string, std::string>> modes = {{a->station(), "local"},
                                                                  {b->station(), "remote"}};
  for (const auto& [id, mode] : modes) {
    const auto row = r.out.find("\n" + id + " ");
    ASSERT_NE(row, std::string::npos) << id << "\n" << r.out;
    const std::string line = r.out.substr(row + 1, r.out.find('\n', row + 1) - row - 1);
    EXPECT_NE(line.find(" idle "), std::string::npos) << line;
    EXPECT_NE(line.find(" " + mode + " "), std::string::npos) << line;
  }
  const auto row = r.out.find("\n" + worker_id + " ");
  ASSERT_NE(row, std::string::npos) << r.out;
  const std::string line = r.out.substr(row + 1, r.out.find('\n', row + 1) - row - 1);
  EXPECT_NE(line.find("reconstructing"), std::string::npos) << line;
  EXPECT_NE(line.find(b->station()), std::string::npos) << line;

  // status --all is the same view; CRAFTSCAN_SITE names the site.
  {
    CtlProcess all(view.dir(), "all",
                   {"--domain", std::to_string(ProcessDomainId()), "--dds-config", TestDdsConfig(),
                    "--json", "status", "--all", "--wait", "1"},
                   {"CRAFTSCAN_SITE=" + site});
    r = all.Wait(60s);
    ASSERT_EQ(r.exit_code, 0) << Describe(r);
    const json listing = SiteView::Parse(r);
    EXPECT_EQ(Ids(Stations(listing)), (std::set<std::string>{a->station(), b->station()})) << r.out;
    EXPECT_EQ(Ids(Workers(listing)), std::set<std::string>{worker_id}) << r.out;
  }
  // Usage errors: exit 2 with a message naming the problem; no token needed.
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"site", "--site", "no spaces"},
           {"site", "--site", ""},
           {"site", "--wait", "0"},
           {"status", "--site", site},  // --site needs --all
       }) {
    CtlProcess bad(view.dir(), "bad", args);
    r = bad.Wait(60s);
    EXPECT_EQ(r.exit_code, 2) << args[2] << "\n" << Describe(r);
    EXPECT_FALSE(r.err.empty()) << Describe(r);
  }
  CtlProcess bad(view.dir(), "bad-site", {"site", "--site", "a/b"});
  r = bad.Wait(60s);
  EXPECT_EQ(r.exit_code, 2) << Describe(r);
  EXPECT_NE(r.err.find("site 'a/b'"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace craftscan::testing
