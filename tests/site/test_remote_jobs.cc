// A scan's reconstruction handed to a worker (issue 21) on loopback DDS: the
// real craftscand on the sim station with reconstruction.mode remote, the
// real craftscanctl, and craftscan-worker's loop (RunWorker) on threads of
// this process. The model a worker made is checked against a reconstruction
// of the same stored views made here, the way the station makes it.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "craftscan/worker/worker.h"
#include "ctl_runner.h"
#include "daemon_fixture.h"
#include "file_util.h"
#include "remote_check.h"

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;

// A worker's loop on a thread of this test.
class TestWorker {
 public:
  // The first worker of a test process creates the domain with the station's
  // DDS config; later ones (`first` false) join it.
  TestWorker(const DaemonFixture& station, const std::string& site, const std::string& id,
             const std::string& token, bool first = true) {
    options_.worker_id = id;
    if (first) options_.dds_config = station.dds_config();
    options_.site = site;
    options_.domain = station.domain();
    options_.token = token;
    options_.threads = TestThreads();
    options_.work_dir = station.root() + "/" + id;
    thread_ = std::thread([this] {
      worker::WorkerHooks hooks;
      hooks.ready = [this] { ready_ = true; };
      hooks.log = [this](int level, const std::string& message) {
        std::lock_guard lock(mutex_);
        log_ += std::to_string(level) + " " + message + "\n";
      };
      std::string error;
      code_ = worker::RunWorker(options_, stop_, hooks, &error);
      if (code_ != 0) {
        std::lock_guard lock(mutex_);
        log_ += "RunWorker: " + error + "\n";
      }
    });
  }
  ~TestWorker() { Stop(); }
  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  bool WaitReady(std::chrono::seconds limit) {
    const auto deadline = std::chrono::steady_clock::now() + limit;
    while (!ready_ && std::chrono::steady_clock::now() < deadline)
      std::this_thread::sleep_for(20ms);
    return ready_;
  }
  std::string Log() {
    std::lock_guard lock(mutex_);
    return log_;
  }

 private:
  worker::WorkerOptions options_;
  std::atomic<bool> stop_{false}, ready_{false};
  std::mutex mutex_;
  std::string log_;
  int code_ = -1;
  std::thread thread_;
};

// A daemon whose scans are offered to the site's workers.
struct RemoteStation {
  explicit RemoteStation(const std::string& reconstruction)
      : fixture("640x512"), site("site" + std::to_string(::getpid())) {
    fixture.extra_yaml = "site: " + site + "\nreconstruction: " + reconstruction + "\n";
  }
  CtlRun Scan(int views, const std::string& step) {
    CtlProcess process(
        fixture.root(), "scan" + std::to_string(++runs),
        {"--station", fixture.station(), "--domain", std::to_string(fixture.domain()),
         "--dds-config", fixture.dds_config(), "--timeout", "60", "--token", kOperatorToken, "scan",
         "--object", "box", "--views", std::to_string(views), "--step", step, "--json"});
    return process.Wait(600s);
  }
  DaemonFixture fixture;
  std::string site;
  int runs = 0;
};

std::string Describe(const CtlRun& r) {
  return "exit " + std::to_string(r.exit_code) + "\nstdout:\n" + r.out + "\nstderr:\n" + r.err;
}

TEST(RemoteJobs, AScanReconstructedByAWorkerIsTheModelTheStationWouldHaveMade) {
  RemoteStation station("{mode: remote, offer_timeout_ms: 20000}");
  std::string error;
  ASSERT_TRUE(station.fixture.Prepare(&error)) << error;
  ASSERT_TRUE(station.fixture.Start(&error)) << error;
  TestWorker worker(station.fixture, station.site, "w1", kOperatorToken);
  ASSERT_TRUE(worker.WaitReady(30s)) << worker.Log();

  const CtlRun r = station.Scan(4, "90");
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture.Log() << worker.Log();
  const json job = json::parse(r.out, nullptr, false);
  const std::string session = job.value("session", "");
  ASSERT_FALSE(session.empty()) << r.out;
  const json remote = job.value("result", job).value("remote", json());
  ASSERT_TRUE(remote.is_object()) << r.out;
  EXPECT_EQ(remote.value("outcome", ""), "done") << r.out;
  EXPECT_EQ(remote.value("worker", ""), "w1") << r.out;
  EXPECT_EQ(remote.value("grants", 0), 1) << r.out;
  std::printf(
      "4-view 640x512 scan reconstructed by a worker: %.1f s, %.0f s remote, %.1f MB back\n",
      r.seconds, remote.value("seconds", 0.0), remote.value("bytes_back", 0.0) / 1e6);

  // The stored model is what the station makes of the same views.
  const std::string dir = station.fixture.data_dir() + "/sessions/" + session;
  const std::string stored = ReadFile(dir + "/fused.ply");
  ASSERT_FALSE(stored.empty());
  std::string local_obj;
  EXPECT_TRUE(stored == LocalFusedPly(station.fixture.root() + "/craftscand.yaml",
                                      station.fixture.data_dir(), session, TestThreads(),
                                      &local_obj))
      << "the worker's fused.ply differs from a local reconstruction of the same views";
  // mesh.obj does not travel (half the bytes back): the station writes it
  // from the worker's mesh.ply, the same bytes as its own.
  ASSERT_FALSE(local_obj.empty());
  EXPECT_TRUE(ReadFile(dir + "/mesh.obj") == local_obj)
      << "the station's mesh.obj differs from a local reconstruction's";
  for (const char* name : {"mesh.ply", "mesh.glb", "report.json", "report.html"})
    EXPECT_FALSE(ReadFile(dir + "/" + name).empty()) << name;
  const json report = json::parse(ReadFile(dir + "/report.json"), nullptr, false);
  EXPECT_TRUE(report.is_object());
}

TEST(RemoteJobs, WithNoWorkerTheStationReconstructsItselfAfterTheOfferTimeout) {
  RemoteStation station("{mode: remote, offer_timeout_ms: 500}");
  std::string error;
  ASSERT_TRUE(station.fixture.Prepare(&error)) << error;
  ASSERT_TRUE(station.fixture.Start(&error)) << error;
  const CtlRun r = station.Scan(3, "120");
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture.Log();
  const json job = json::parse(r.out, nullptr, false);
  const json remote = job.value("result", job).value("remote", json());
  EXPECT_EQ(remote.value("outcome", ""), "local") << r.out;
  EXPECT_NE(remote.value("why", "").find("no worker claimed it within 500 ms"), std::string::npos)
      << r.out;
  const std::string dir = station.fixture.data_dir() + "/sessions/" + job.value("session", "");
  EXPECT_FALSE(ReadFile(dir + "/mesh.glb").empty());
}

TEST(RemoteJobs, AWorkerWhoseTokenTheStationDoesNotListIsNeverGranted) {
  RemoteStation station("{mode: remote, offer_timeout_ms: 3000}");
  std::string error;
  ASSERT_TRUE(station.fixture.Prepare(&error)) << error;
  ASSERT_TRUE(station.fixture.Start(&error)) << error;
  TestWorker forged(station.fixture, station.site, "forged", "forged-token-0123456789");
  ASSERT_TRUE(forged.WaitReady(30s)) << forged.Log();
  const CtlRun r = station.Scan(3, "120");
  ASSERT_EQ(r.exit_code, 0) << Describe(r) << station.fixture.Log();
  const json job = json::parse(r.out, nullptr, false);
  const json remote = job.value("result", job).value("remote", json());
  EXPECT_EQ(remote.value("outcome", ""), "local") << r.out;
  EXPECT_NE(station.fixture.Log().find("refused the claim of worker 'forged'"), std::string::npos)
      << station.fixture.Log();
  EXPECT_EQ(forged.Log().find("granted"), std::string::npos) << forged.Log();
}

}  // namespace
}  // namespace craftscan::testing
