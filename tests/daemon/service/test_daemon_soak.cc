// Load and long runs (issue 8): the real craftscand on the sim station scans
// back to back while DDS clients come and go around it (some reading
// everything, some slowly, some never), and neither its memory nor its open
// files may grow. Prints FIGURE lines (per scan and a summary) for reports.
// CRAFTSCAN_SOAK_SCANS overrides the number of scans (default 50) for a
// quick look; the trend checks need at least 20.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <numeric>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "../sessions/status_util.h"
#include "craftscan/daemon/session_store.h"
#include "daemon_fixture.h"
#include "daemon_probe.h"
#include "station_client.h"

using craftscan::testing::StatusInto;

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

int ScanCount() {
  const char* text = std::getenv("CRAFTSCAN_SOAK_SCANS");
  const int n = text ? std::atoi(text) : 0;
  return n > 0 ? n : 50;
}

// Subscribers that come and go on a thread of their own until stopped: each
// round makes a participant with readers of the station's clouds, captures
// and status, keeps it 0.3–1.5 s, reading everything (round % 3 == 0),
// one sample every 0.5 s (== 1) or nothing at all (== 2), then deletes it.
class ClientChurn {
 public:
  ClientChurn(std::uint32_t domain, std::string station)
      : domain_(domain), station_(std::move(station)), thread_([this] { Loop(); }) {}
  ~ClientChurn() { Stop(); }

  void Stop() {
    running_ = false;
    if (thread_.joinable()) thread_.join();
  }
  int rounds() const { return rounds_; }
  long samples() const { return samples_; }
  const std::string& error() const { return error_; }  // after Stop()

 private:
  void Loop() {
    std::mt19937 random(7);
    std::uniform_int_distribution<int> hold_ms(300, 1500);
    for (int round = 0; running_; ++round) {
      std::string error;
      auto participant = JoinDomain(domain_, &error);
      auto clouds = participant ? dds::Reader<dds::msg::PointCloud>::Create(
                                      participant, dds::CloudTopic(station_), &error)
                                : nullptr;  // the three share the participant
      auto captures = clouds ? dds::Reader<dds::msg::StereoCapture>::Create(
                                   participant, dds::CaptureTopic(station_), &error)
                             : nullptr;
      auto status = captures ? dds::Reader<dds::msg::StationStatus>::Create(
                                   participant, dds::StatusTopic(station_), &error)
                             : nullptr;
      if (!status) {
        error_ = "round " + std::to_string(round) + ": " + error;
        return;
      }
      const auto until = Clock::now() + std::chrono::milliseconds(hold_ms(random));
      const int mode = round % 3;
      dds::Sample<dds::msg::PointCloud> cloud;
      dds::Sample<dds::msg::StereoCapture> capture;
      dds::Sample<dds::msg::StationStatus> state;
      while (running_ && Clock::now() < until) {
        if (mode == 2) {
          std::this_thread::sleep_for(50ms);
          continue;
        }
        const auto wait = mode == 0 ? 20ms : 0ms;
        int got = 0;
        got += clouds->Take(wait, &cloud, &error) == dds::TakeStatus::kOk;
        got += captures->Take(wait, &capture, &error) == dds::TakeStatus::kOk;
        got += status->Take(wait, &state, &error) == dds::TakeStatus::kOk;
        samples_ += got;
        if (mode == 1) std::this_thread::sleep_for(500ms);
      }
      ++rounds_;
    }
  }

  std::uint32_t domain_;
  std::string station_;
  std::atomic<bool> running_{true};
  std::atomic<int> rounds_{0};
  std::atomic<long> samples_{0};
  std::string error_;
  std::thread thread_;  // last: starts after the members it uses
};

double MeanRssMb(const std::vector<ProcFigures>& figures, std::size_t first, std::size_t last) {
  double sum = 0;
  for (std::size_t i = first; i <= last; ++i) sum += figures[i].rss_kb / 1024.0;
  return sum / static_cast<double>(last - first + 1);
}

TEST(DaemonSoak, FiftyScansBackToBackWithClientsComingAndGoingLeakNothing) {
  const int scans = ScanCount();
  DaemonFixture fixture("320x256");
  fixture.pipeline_extra = ", mesh: false, measure_box: false";
  StationClient client;
  std::string error;
  ASSERT_TRUE(fixture.Prepare(&error)) << error;
  ASSERT_TRUE(fixture.Start(&error)) << error;
  ASSERT_TRUE(client.Start(fixture.domain(), fixture.dds_config(), fixture.station(), &error))
      << error;
  ASSERT_TRUE(client.WaitForDaemon(30s)) << fixture.Log();
  auto churn = std::make_unique<ClientChurn>(fixture.domain(), fixture.station());

  const auto start = Clock::now();
  const ProcFigures initial = ReadProcFigures(fixture.pid());
  std::vector<ProcFigures> after;  // after each scan
  std::vector<std::string> sessions;
  std::vector<double> seconds;
  for (int i = 0; i < scans; ++i) {
    const auto scan_start = Clock::now();
    const auto reply = client.Send(
        "scan", {{"object", "soak " + std::to_string(i)}, {"views", 4}, {"step_deg", 90}},
        kOperatorToken);
    ASSERT_TRUE(reply) << "scan " << i << ": no reply\n" << fixture.Log();
    ASSERT_EQ(reply->code_name, "ok") << "scan " << i << ": " << reply->message;
    const std::string job = reply->result["id"];
    sessions.push_back(reply->result["session"]);
    ASSERT_TRUE(client.WaitFor(
        [&](StationClient& c) {
          return c.last_job_id == job && c.last_job_state != "running" &&
                 c.last_job_state != "queued";
        },
        120s))
        << "scan " << i << " did not end\n"
        << fixture.Log();
    {
      auto lock = client.Lock();
      ASSERT_EQ(client.last_job_state, "done") << "scan " << i << "\n" << fixture.Log();
    }
    seconds.push_back(std::chrono::duration<double>(Clock::now() - scan_start).count());
    // The daemon hands a job's freed memory back 250 ms after it ends.
    std::this_thread::sleep_for(500ms);
    if (i == 0 || i + 1 == scans) {  // where the time of a scan goes
      const auto status = client.Send("status", nullptr, kObserverToken);
      ASSERT_TRUE(status);
      const nlohmann::json& result = status->result["job"]["result"];
      std::printf(
          "FIGURE soak scan %d stages: capture %.0f ms, match %.0f ms, reconstruct %.0f ms: %s\n",
          i + 1, result.value("capture_ms", 0.0), result.value("match_ms", 0.0),
          result.value("reconstruct_ms", 0.0), result["stage_ms"].dump().c_str());
    }
    after.push_back(ReadProcFigures(fixture.pid()));
    const double cpu_s =
        after.back().cpu_s - (i == 0 ? initial.cpu_s : after[after.size() - 2].cpu_s);
    std::printf(
        "FIGURE soak scan %d: %.2f s (daemon CPU %.2f s), rss %.1f MB, peak %.1f MB, "
        "threads %d, fds %d\n",
        i + 1, seconds.back(), cpu_s, after.back().rss_kb / 1024.0, after.back().hwm_kb / 1024.0,
        after.back().threads, after.back().fds);
    std::fflush(stdout);
  }
  const double total_s = std::chrono::duration<double>(Clock::now() - start).count();
  churn->Stop();
  EXPECT_EQ(churn->error(), "");
  std::printf(
      "FIGURE soak %d scans in %.0f s (%.2f s mean, %.2f s max; daemon CPU %.2f s a scan); "
      "%d client rounds read %ld samples\n",
      scans, total_s, total_s / scans, *std::max_element(seconds.begin(), seconds.end()),
      (after.back().cpu_s - initial.cpu_s) / scans, churn->rounds(), churn->samples());
  EXPECT_GT(churn->rounds(), scans);  // clients came and went all along

  // Every session is on disk, done and intact.
  auto store = daemon::SessionStore::Open(fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  const auto listed = client.Send("sessions", nullptr, kObserverToken);
  ASSERT_TRUE(listed);
  EXPECT_EQ(listed->result["sessions"].size(), static_cast<std::size_t>(scans));
  for (const std::string& id : sessions) {
    const daemon::VerifyResult verify = store->Verify(id);
    EXPECT_TRUE(verify.IsIntact())
        << id << ": " << (verify.problems.empty() ? "" : verify.problems[0]);
    auto session = store->OpenSession(id, StatusInto(&error));
    ASSERT_TRUE(session) << error;
    EXPECT_EQ(session->state(), daemon::SessionState::kDone) << id;
    EXPECT_EQ(session->DurableViews().size(), 4u) << id;
  }

  // Bounds. RSS: the daemon (code, DDS, the sim station: ~100 MB idle) with
  // a 4-view 320x256 scan's buffers freed needs ~160 MB; 300 MB would mean
  // it holds on to scans. Open files: DDS sockets, the plugins, the log; a
  // session's files are closed when it ends; 64 is several times that.
  long max_rss_kb = 0;
  int max_fds = 0;
  for (const ProcFigures& f : after) {
    max_rss_kb = std::max(max_rss_kb, f.rss_kb);
    max_fds = std::max(max_fds, f.fds);
  }
  std::printf(
      "FIGURE soak daemon rss at start %.1f MB, max after a scan %.1f MB, peak %.1f MB; "
      "threads at start %d, after the last scan %d; fds at start %d, max %d\n",
      initial.rss_kb / 1024.0, max_rss_kb / 1024.0, after.back().hwm_kb / 1024.0, initial.threads,
      after.back().threads, initial.fds, max_fds);
  EXPECT_LT(max_rss_kb / 1024.0, 300.0);
  EXPECT_LT(max_fds, 64);
  if (scans < 20) GTEST_SKIP() << "trend checks need 20 scans or more";
  // No growth. RSS: the mean of the last 10 scans is within 30 MB of that
  // of scans 6-15. What may still come after scan 15 is bounded warm-up:
  // glibc keeps up to 40 MB of exited threads' stacks for new ones, and a
  // job's threads sometimes land on a malloc arena not used before (steps
  // of 10-15 MB, none after scan ~25; measured +10 to +16 MB). A leak of
  // 1 MB a scan (a few clouds) would add 40 MB. Threads: the same after the
  // last scan as after scan 5 (every job's threads joined); open files too,
  // give or take one being closed.
  const std::size_t n = after.size();
  const double early = MeanRssMb(after, 5, 14), late = MeanRssMb(after, n - 10, n - 1);
  std::printf(
      "FIGURE soak rss mean scans 6-15 %.1f MB, last 10 %.1f MB (%+.1f MB); fds after scan 5 "
      "%d, after scan %zu %d\n",
      early, late, late - early, after[4].fds, n, after[n - 1].fds);
  EXPECT_LT(late - early, 30.0);
  EXPECT_EQ(after[n - 1].threads, after[4].threads);
  EXPECT_NEAR(after[n - 1].fds, after[4].fds, 2);
}

}  // namespace
}  // namespace craftscan::testing
