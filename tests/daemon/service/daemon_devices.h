// For the daemon tests with real device components instead of the sim
// (test_daemon_devices.cc: the serial turntable through the PTY GRBL
// emulator; test_daemon_aravis.cc: Aravis fake GigE cameras): a running
// craftscand with its clients (a StationClient and a StatusWatcher, both
// from station_client.h), and the checks every fault case makes (the job's
// end, nothing acknowledged lost, the daemon still serving).
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "../sessions/status_util.h"
#include "craftscan/client/station_client.h"
#include "craftscan/daemon/session_store.h"
#include "daemon_fixture.h"
#include "station_client.h"

using craftscan::testing::StatusInto;

namespace craftscan::testing {

using namespace std::chrono_literals;

struct RunningDaemon {
  DaemonFixture fixture{"320x256"};
  StationClient client;
  StatusWatcher watcher;

  // Writes the config (`devices_yaml` replaces the sim devices; no mesh: not
  // what these tests are about), starts craftscand and both clients. Fails
  // the test (false) if anything does not come up.
  bool Start(const std::string& devices_yaml) {
    fixture.devices_yaml = devices_yaml;
    fixture.pipeline_extra = ", mesh: false";
    std::string error;
    if (!fixture.Prepare(&error) || !fixture.Start(&error) ||
        !client.Start(fixture.domain(), fixture.dds_config(), fixture.station(), &error) ||
        !watcher.Start(fixture.domain(), fixture.station(), &error)) {
      ADD_FAILURE() << error;
      return false;
    }
    if (!client.WaitForDaemon(30s) ||
        !client.WaitFor([](StationClient& c) { return c.last_status_state == "idle"; }, 60s)) {
      ADD_FAILURE() << "craftscand did not come up idle; log:\n" << fixture.Log();
      return false;
    }
    return true;
  }

  // Starts a scan of `views` views; the reply's result ({id, session}), or
  // null (the test failed) when it was refused.
  nlohmann::json Scan(const std::string& object, int views) {
    const auto reply = client.Send("scan", {{"object", object}, {"views", views}}, kOperatorToken);
    if (!reply || reply->code_name != "ok") {
      ADD_FAILURE() << "scan refused: " << (reply ? reply->message : "no reply") << "\n"
                    << fixture.Log();
      return nullptr;
    }
    return reply->result;
  }

  nlohmann::json Resume(const std::string& session) {
    const auto reply = client.Send("resume", {{"session", session}}, kOperatorToken);
    if (!reply || reply->code_name != "ok") {
      ADD_FAILURE() << "resume refused: " << (reply ? reply->message : "no reply");
      return nullptr;
    }
    return reply->result;
  }

  // Starts a scan of `views` views and waits until its first capture is
  // acknowledged; the reply's result ({id, session}), or null (the test
  // failed).
  nlohmann::json ScanUntilFirstCapture(const std::string& object, int views) {
    nlohmann::json scan = Scan(object, views);
    if (scan.is_null()) return scan;
    if (!WaitForCaptures(scan["session"], 1, 60s)) {
      ADD_FAILURE() << "no capture acknowledged\n" << fixture.Log();
      return nullptr;
    }
    return scan;
  }

  // Waits until at least `count` captures of `session` were acknowledged.
  bool WaitForCaptures(const std::string& session, std::size_t count,
                       std::chrono::seconds timeout) {
    return client.WaitFor([&](StationClient& c) { return Captures(c, session).size() >= count; },
                          timeout);
  }

  // The acknowledged (published) captures of `session`, by view.
  std::vector<CaptureRecord> Acknowledged(const std::string& session) {
    auto lock = client.Lock();
    return Captures(client, session);
  }

  // The job's progress messages (from JobProgress); the last is its end.
  std::vector<std::string> ProgressOf(const std::string& job) {
    auto lock = client.Lock();
    std::vector<std::string> messages;
    for (std::size_t i = 0; i < client.progress.size(); ++i)
      if (client.progress[i].first == job) messages.push_back(client.progress_messages[i]);
    return messages;
  }

  // The session on disk is intact (Verify: every listed file present with
  // its checksum) and holds every acknowledged capture, bit-exact with what
  // was published. The durable views.
  std::vector<int> ExpectNothingLost(const std::string& session,
                                     const std::vector<CaptureRecord>& acknowledged) {
    std::string error;
    auto store = daemon::SessionStore::Open(fixture.data_dir(), StatusInto(&error));
    if (!store) {
      ADD_FAILURE() << error;
      return {};
    }
    const daemon::VerifyResult verify = store->Verify(session);
    EXPECT_TRUE(verify.IsIntact())
        << session << ": " << (verify.problems.empty() ? "manifest" : verify.problems[0]);
    auto opened = store->OpenSession(session, StatusInto(&error));
    if (!opened) {
      ADD_FAILURE() << error;
      return {};
    }
    const std::vector<int> durable = opened->DurableViews();
    for (const CaptureRecord& ack : acknowledged) {
      EXPECT_TRUE(std::count(durable.begin(), durable.end(), ack.view)) << "view " << ack.view;
      cv::Mat left, right;
      if (!opened->LoadCapture(ack.view, &left, &right, nullptr, &error)) {
        ADD_FAILURE() << "view " << ack.view << ": " << error;
        continue;
      }
      client::Fnv1a64Hasher hash;
      const cv::Mat packed = left.clone();
      hash.Update(packed.data, packed.total() * packed.elemSize());
      EXPECT_EQ(hash.value(), ack.left_hash)
          << "view " << ack.view << ": stored left image differs";
    }
    return durable;
  }

  daemon::SessionState SessionStateOf(const std::string& session) {
    std::string error;
    auto store = daemon::SessionStore::Open(fixture.data_dir(), StatusInto(&error));
    auto opened = store ? store->OpenSession(session, StatusInto(&error)) : nullptr;
    if (!opened) {
      ADD_FAILURE() << error;
      return daemon::SessionState::kFailed;
    }
    return opened->state();
  }

  // After a failed job: the daemon is idle and answers; `reason` is in the
  // job's message, its last progress message, StationStatus.last_error (the
  // status verb and the topic) and the `device`'s line of the topic.
  void ExpectFailureReported(const nlohmann::json& job, const std::string& device,
                             const std::vector<std::string>& reason) {
    const std::string message = job.value("message", "");
    const auto status = client.Send("status", nullptr, kObserverToken);
    ASSERT_TRUE(status) << "no answer to status after the failure\n" << fixture.Log();
    EXPECT_EQ(status->result["state"], "idle") << status->result.dump();
    const std::string last_error = status->result.value("last_error", "");
    const std::vector<std::string> progress = ProgressOf(job.value("id", ""));
    ASSERT_FALSE(progress.empty());
    ASSERT_TRUE(watcher.WaitFor(
        [&](const client::StatusUpdate& s) { return s.last_error == message; }, 10s))
        << "StationStatus never carried the job's message: " << message;
    std::string device_message;
    for (const auto& d : status->result["devices"])
      if (d.value("name", "") == device) device_message = d.value("message", "");
    for (const std::string& part : reason) {
      EXPECT_NE(message.find(part), std::string::npos) << "job message: " << message;
      EXPECT_NE(last_error.find(part), std::string::npos) << "last_error: " << last_error;
      EXPECT_NE(progress.back().find(part), std::string::npos) << "progress: " << progress.back();
    }
    EXPECT_FALSE(device_message.empty()) << status->result.dump();
    std::printf("  failure reported: %s\n  %s line: %s\n", message.c_str(), device.c_str(),
                device_message.c_str());
  }

  // The resumed job `id` completed `session`: done, every planned view
  // durable, none of `acknowledged` captured again.
  void ExpectResumed(const std::string& session, const std::string& id, int views,
                     const std::vector<CaptureRecord>& acknowledged) {
    const nlohmann::json job = WaitForJobEnd(client, kObserverToken, id, 180s);
    ASSERT_EQ(job.value("state", ""), "done") << job.dump() << "\n" << fixture.Log();
    EXPECT_EQ(SessionStateOf(session), daemon::SessionState::kDone);
    const std::vector<CaptureRecord> all = Acknowledged(session);
    std::multiset<int> captured;
    for (const CaptureRecord& c : all) captured.insert(c.view);
    for (const CaptureRecord& ack : acknowledged)
      EXPECT_EQ(captured.count(ack.view), 1u) << "view " << ack.view << " captured again";
    EXPECT_EQ(ExpectNothingLost(session, all).size(), static_cast<std::size_t>(views));
  }

 private:
  static std::vector<CaptureRecord> Captures(StationClient& c, const std::string& session) {
    std::vector<CaptureRecord> out;
    for (const CaptureRecord& r : c.captures)
      if (r.session == session) out.push_back(r);
    return out;
  }
};

}  // namespace craftscan::testing
