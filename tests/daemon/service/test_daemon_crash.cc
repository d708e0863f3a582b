// craftscand killed with SIGKILL at random moments during 20 scans: after
// each restart every acknowledged capture is on disk and readable, the
// manifest is consistent with the files, and `resume` completes the session.
// Small images (320×256) keep each scan to a few seconds.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <optional>
#include <random>
#include <set>
#include <string>
#include <thread>

#include "../sessions/status_util.h"
#include "craftscan/daemon/session_store.h"
#include "daemon_fixture.h"
#include "station_client.h"

using craftscan::testing::StatusInto;

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;

TEST(DaemonCrash, TwentyScansKilledAtRandomMomentsLoseNothing) {
  // No mesh: Poisson is the slowest stage and not what this test is about.
  DaemonFixture fixture("320x256");
  fixture.pipeline_extra = ", mesh: false";
  std::string error;
  ASSERT_TRUE(fixture.Prepare(&error)) << error;
  ASSERT_TRUE(fixture.Start(&error)) << error;
  StationClient client;
  ASSERT_TRUE(client.Start(fixture.domain(), fixture.dds_config(), fixture.station(), &error))
      << error;
  ASSERT_TRUE(client.WaitForDaemon(30s)) << fixture.Log();

  std::mt19937 random(20261129);
  constexpr int kScans = 20;
  int killed_mid_capture = 0, killed_later = 0, acknowledged_total = 0;
  for (int scan = 0; scan < kScans; ++scan) {
    ASSERT_TRUE(client.WaitFor([](StationClient& c) { return c.last_status_state == "idle"; }, 60s))
        << "scan " << scan << ": daemon not idle\n"
        << fixture.Log();
    std::size_t captures_before = 0;
    {
      auto lock = client.Lock();
      captures_before = client.captures.size();
    }
    const auto reply = client.Send(
        "scan", {{"object", "crash" + std::to_string(scan)}, {"views", 4}}, kOperatorToken);
    ASSERT_TRUE(reply) << "scan " << scan;
    ASSERT_EQ(reply->code_name, "ok") << reply->message;
    const std::string session_id = reply->result["session"];
    // Kill after a random time within the scan's usual span.
    std::this_thread::sleep_for(
        std::chrono::milliseconds(std::uniform_int_distribution<int>(0, 6000)(random)));
    ASSERT_TRUE(WIFSIGNALED(fixture.Stop(SIGKILL)));
    std::set<int> acknowledged;
    {
      auto lock = client.Lock();
      for (std::size_t i = captures_before; i < client.captures.size(); ++i) {
        if (client.captures[i].session == session_id) acknowledged.insert(client.captures[i].view);
      }
    }
    acknowledged_total += static_cast<int>(acknowledged.size());
    (acknowledged.size() < 4 ? killed_mid_capture : killed_later) += 1;

    // On disk, before the restart: every acknowledged capture is listed and readable.
    {
      auto store = daemon::SessionStore::Open(fixture.data_dir(), StatusInto(&error));
      ASSERT_TRUE(store) << error;
      const daemon::VerifyResult verify = store->Verify(session_id);
      ASSERT_TRUE(verify.IsIntact())
          << "scan " << scan << ": " << (verify.problems.empty() ? "manifest" : verify.problems[0]);
      auto session = store->OpenSession(session_id, StatusInto(&error));
      ASSERT_TRUE(session) << error;
      const std::vector<int> durable = session->DurableViews();
      for (int view : acknowledged) {
        EXPECT_TRUE(std::count(durable.begin(), durable.end(), view))
            << "scan " << scan << " view " << view;
        cv::Mat left, right;
        EXPECT_TRUE(session->LoadCapture(view, &left, &right, nullptr, &error)) << error;
        EXPECT_EQ(left.size(), cv::Size(320, 256));
      }
    }

    // Restart; the session is interrupted (or done, if the kill came after the end) and resumes.
    ASSERT_TRUE(fixture.Start(&error)) << error;
    ASSERT_TRUE(client.WaitFor([](StationClient& c) { return c.last_status_state == "idle"; }, 60s))
        << fixture.Log();
    // The status seen may still be the killed daemon's (transient-local) and
    // its endpoints linger until their lease ends: ask until the new one answers.
    std::optional<ReplyRecord> sessions;
    for (int attempt = 0; attempt < 9 && !sessions; ++attempt) {
      sessions = client.Send("get", {{"session", session_id}}, kObserverToken, 10s);
    }
    ASSERT_TRUE(sessions) << fixture.Log();
    ASSERT_EQ(sessions->code_name, "ok") << sessions->message;
    const std::string state = sessions->result["manifest"]["state"];
    if (state == "done") continue;
    ASSERT_EQ(state, "interrupted") << "scan " << scan;
    const auto resume = client.Send("resume", {{"session", session_id}}, kOperatorToken, 30s);
    ASSERT_TRUE(resume);
    ASSERT_EQ(resume->code_name, "ok") << resume->message;
    const nlohmann::json job = WaitForJobEnd(client, kObserverToken, resume->result["id"], 120s);
    ASSERT_EQ(job.value("state", ""), "done")
        << "scan " << scan << ": " << job.dump() << fixture.Log();
    {
      auto lock = client.Lock();
      for (std::size_t i = captures_before; i < client.captures.size(); ++i) {
        const CaptureRecord& c = client.captures[i];
        // Resumed captures are only of views not acknowledged before the kill.
        if (c.session == session_id && i >= captures_before + acknowledged.size()) {
          EXPECT_FALSE(acknowledged.count(c.view))
              << "scan " << scan << ": view " << c.view << " captured again";
        }
      }
    }
  }
  std::printf(
      "20 scans killed: %d during capture, %d later; %d acknowledged captures, all intact\n",
      killed_mid_capture, killed_later, acknowledged_total);
  auto store = daemon::SessionStore::Open(fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store);
  int done = 0;
  for (const daemon::SessionSummary& s : store->List()) done += s.state == "done";
  EXPECT_EQ(done, kScans);
}

}  // namespace
}  // namespace craftscan::testing
