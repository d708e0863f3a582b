// craftscand end to end: the real daemon binary on the simulated station,
// real DDS on loopback (a private domain), a fake NOTIFY_SOCKET.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iterator>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <opencv2/core.hpp>

#include "../sessions/status_util.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"
#include "daemon_fixture.h"
#include "mat_util.h"
#include "station_client.h"

using craftscan::testing::StatusInto;

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using daemon::SessionState;

struct Running {
  DaemonFixture fixture;
  StationClient client;
  Running(std::string image_size, std::string extra_sim)
      : fixture(std::move(image_size), std::move(extra_sim)) {}
};

// Starts the daemon and a client; fails the test (returns null) if either
// does not come up. extra_sim: more sim driver keys (", key: value…").
// The views of `session` among published records (CloudRecord,
// DisparityRecord, ...).
template <typename Record>
std::set<int> ViewsOf(const std::vector<Record>& records, const std::string& session) {
  std::set<int> views;
  for (const Record& r : records)
    if (r.session == session) views.insert(r.view);
  return views;
}

std::unique_ptr<Running> StartDaemon(const std::string& image_size, long watchdog_usec = 0,
                                     bool with_calibration = true, std::string extra_sim = "",
                                     bool box_volume = true, std::string scan_extra = "") {
  auto r = std::make_unique<Running>(image_size, std::move(extra_sim));
  r->fixture.box_volume = box_volume;
  r->fixture.scan_extra = std::move(scan_extra);
  std::string error;
  if (!r->fixture.Prepare(&error, with_calibration)) {
    ADD_FAILURE() << error;
    return nullptr;
  }
  if (!r->fixture.Start(&error, watchdog_usec, /*notify=*/watchdog_usec > 0)) {
    ADD_FAILURE() << error;
    return nullptr;
  }
  if (!r->client.Start(r->fixture.domain(), r->fixture.dds_config(), r->fixture.station(),
                       &error)) {
    ADD_FAILURE() << error;
    return nullptr;
  }
  if (!r->client.WaitForDaemon(30s)) {
    ADD_FAILURE() << "the daemon's command reader never matched; log:\n" << r->fixture.Log();
    return nullptr;
  }
  return r;
}

TEST(Daemon, ScanOfSixViewsPublishesEverythingAndStoresTheSession) {
  auto r = StartDaemon("1280x1024");
  ASSERT_TRUE(r);
  StationClient& client = r->client;
  const auto start = std::chrono::steady_clock::now();
  const auto reply = client.Send("scan", {{"object", "carved box"}, {"views", 6}, {"step_deg", 60}},
                                 kOperatorToken);
  ASSERT_TRUE(reply) << r->fixture.Log();
  ASSERT_EQ(reply->code_name, "ok") << reply->message;
  const std::string job_id = reply->result["id"];
  const std::string session_id = reply->result["session"];
  EXPECT_EQ(session_id.substr(16), "carved_box");

  const nlohmann::json job = WaitForJobEnd(client, kObserverToken, job_id, 600s);
  const double total_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(job.value("state", ""), "done") << job.dump(2) << "\n" << r->fixture.Log();
  const nlohmann::json result = job["result"];
  std::printf(
      "6-view 1280x1024 scan: %.1f s end to end; capture %.0f ms, match %.0f ms (both "
      "summed over views, overlapping), reconstruction %.0f ms: %s\n",
      total_s, result.value("capture_ms", 0.0), result.value("match_ms", 0.0),
      result.value("reconstruct_ms", 0.0), result["stage_ms"].dump().c_str());
  RecordProperty("scan_seconds", std::to_string(total_s));

  // Clouds: 6 views and the fused one, all of this session.
  ASSERT_TRUE(client.WaitFor(
      [&](StationClient& c) { return ViewsOf(c.clouds, session_id).size() == 7; }, 30s));
  // Progress per stage.
  {
    auto lock = client.Lock();
    std::set<std::string> stages;
    for (const auto& [id, stage] : client.progress)
      if (id == job_id) stages.insert(stage);
    for (const char* stage : {"capture", "match", "register", "write", "done"}) {
      EXPECT_TRUE(stages.count(stage)) << "no progress for stage " << stage;
    }
    EXPECT_EQ(client.captures.size(), 6u);
  }
  // Disparity maps: one per view, each the map the session stored.
  ASSERT_TRUE(client.WaitFor(
      [&](StationClient& c) { return ViewsOf(c.disparities, session_id).size() == 6; }, 30s));

  // The session on disk is done, intact, and holds what was published.
  std::string error;
  auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  EXPECT_TRUE(store->Verify(session_id).IsIntact());
  auto session = store->OpenSession(session_id, StatusInto(&error));
  ASSERT_TRUE(session) << error;
  EXPECT_EQ(session->state(), SessionState::kDone);
  EXPECT_EQ(session->DurableViews().size(), 6u);
  const daemon::Manifest manifest = session->manifest();
  for (const char* output : {"fused.ply", "mesh.ply", "report.json"}) {
    EXPECT_TRUE(manifest.outputs.count(output)) << output;
  }
  auto lock = client.Lock();
  for (const DisparityRecord& published : client.disparities) {
    if (published.session != session_id) continue;
    SCOPED_TRACE("disparity of view " + std::to_string(published.view));
    cv::Mat stored;
    ASSERT_TRUE(session->LoadDisparity(published.view, &stored, &error)) << error;
    EXPECT_EQ(published.width, stored.cols);
    EXPECT_EQ(published.height, stored.rows);
    std::int64_t valid = 0;
    std::uint64_t hash = 0;
    SummarizeDisparity(stored, &valid, &hash);
    EXPECT_EQ(published.valid_pixels, valid);
    EXPECT_GT(valid, stored.total() / 20) << "the box fills part of every view";
    EXPECT_EQ(published.hash, hash) << "published and stored maps differ";
    EXPECT_LT(published.min_disparity, published.max_disparity);
    EXPECT_GT(published.f_px, 0);
    EXPECT_GT(published.baseline_mm, 0);
  }
  for (const CloudRecord& published : client.clouds) {
    if (published.session != session_id) continue;
    PointCloud stored;
    if (published.view >= 0) {
      ASSERT_TRUE(session->LoadCloud(published.view, &stored, &error)) << error;
    } else {
      std::string bytes;
      ASSERT_TRUE(ReadPly(session->dir() + "/fused.ply", &stored, &error)) << error;
    }
    ASSERT_EQ(stored.size(), published.cloud.size()) << "view " << published.view;
    ASSERT_GT(stored.size(), 1000u) << "view " << published.view;
    EXPECT_EQ(stored.points_mm, published.cloud.points_mm) << "view " << published.view;
  }
}

// The flat object and the weakly textured one of the three this station
// exists for, through the daemon with its default pipeline (the working
// volume a new station starts with, radius 120 mm, height 200 mm): both
// scans finish, the fused cloud's oriented box agrees with the object, and
// the report estimates its floaters. Tolerances from the bench at 640x512
// (craftscan-bench scan --image-size 640x512 --seed 4242: OBB errors egg
// 3.0 / 1.6 / 0.4 mm, embroidery 0.3 / 0.4 / 2.7 mm) with a margin for other
// seeds.
TEST(Daemon, EmbroideryAndEggScanWithTheDefaultConfiguration) {
  struct Case {
    const char* object;
    std::array<double, 3> truth_mm;  // oriented box extents, descending
    std::array<double, 3> tolerance_mm;
    // The sim's pattern projector (texture frames stored) and exposure
    // bracketing at ×8 (scan.exposure_bracket), as for black paint.
    bool projector = false;
  };
  // The truths are the bench's truth OBBs at 640x512 (the box of the surface
  // some view's left camera sees): the embroidery, a 110 mm disc 2.6 mm at
  // its thickest; the egg, 60 mm tall and 45 across, of which the cameras see
  // the part from 3.5 mm above the platter up, 55.6 mm. The egg's lower end
  // is its weakest: a band seen only at grazing angles, with a few mixed
  // pixels below it where the egg meets the platter, so its long axis moves
  // by about +-1 mm between seeds (craftscan-bench scan --image-size 640x512
  // --projector --bracket 8: 56.4, 55.3, 56.3 mm at seeds 4242, 7, 99).
  // The box is upright (the turntable's axis), so the egg's long axis is its
  // height, and at 640x512 its fused cloud keeps a skirt under the belly
  // within 3 mm of the platter (the matcher's smear onto the shadowed
  // platter, facing down-outward ~50°, which two views agree on: 85 points
  // at seed 4242), which the upright box takes in: 59.1-59.3 mm here and in
  // the bench at 640x512 (55.6 at 1280x1024, README 11.9 "Stop 62"). The
  // height is checked against what the egg can be: no less than the part the
  // cameras see less 2 mm (53.6) and no more than the egg itself, 60 mm,
  // plus 0.5.
  for (const Case& c : {Case{"embroidery", {109.7, 109.6, 2.5}, {1.5, 1.5, 5.0}},
                        Case{"egg", {57.05, 44.9, 44.9}, {3.45, 3.0, 3.0}},
                        Case{"egg", {57.05, 44.9, 44.9}, {3.45, 1.0, 1.0}, true}}) {
    SCOPED_TRACE(std::string(c.object) + (c.projector ? " with the projector" : ""));
    auto r =
        StartDaemon("640x512", 0, true,
                    std::string(", object: ") + c.object + (c.projector ? ", projector: 1" : ""),
                    /*box_volume=*/false, c.projector ? ", exposure_bracket: [8]" : "");
    ASSERT_TRUE(r);
    const auto reply = r->client.Send(
        "scan", {{"object", c.object}, {"views", 6}, {"step_deg", 60}}, kOperatorToken);
    ASSERT_TRUE(reply) << r->fixture.Log();
    ASSERT_EQ(reply->code_name, "ok") << reply->message;
    const nlohmann::json job =
        WaitForJobEnd(r->client, kObserverToken, reply->result["id"].get<std::string>(), 600s);
    ASSERT_EQ(job.value("state", ""), "done") << job.dump(2) << "\n" << r->fixture.Log();

    std::string error;
    auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    auto session =
        store->OpenSession(reply->result["session"].get<std::string>(), StatusInto(&error));
    ASSERT_TRUE(session) << error;
    for (int k = 0; k < 6; ++k) {
      cv::Mat left, right, texture;
      nlohmann::json meta;
      ASSERT_TRUE(session->LoadCapture(k, &left, &right, &meta, &error, &texture)) << error;
      EXPECT_EQ(texture.empty(), !c.projector) << "view " << k;
      // Without a configured bracket the station brackets on its own
      // (scan.auto_bracket): each view says how dark its platter was and
      // whether it was exposed ×8 too.
      bool bracketed = c.projector;
      if (!c.projector) {
        ASSERT_TRUE(meta.contains("auto_bracket")) << "view " << k << ": " << meta.dump();
        const double dark = meta["auto_bracket"]["dark_untextured_pct"].get<double>();
        EXPECT_TRUE(dark >= 0 && dark <= 100) << meta.dump();
        bracketed = meta["auto_bracket"]["bracketed"].get<bool>();
        EXPECT_EQ(bracketed, dark >= AutoBracketOptions{}.min_share_pct) << meta.dump();
      } else {
        EXPECT_FALSE(meta.contains("auto_bracket")) << meta.dump();
      }
      EXPECT_EQ(meta.value("exposure_bracket", nlohmann::json::array()),
                bracketed ? nlohmann::json::array({8.0}) : nlohmann::json::array())
          << "view " << k << ": " << meta.dump();
      if (c.projector) {
        EXPECT_FALSE(BitExact(texture, left)) << "view " << k;
      }
    }
    std::ifstream in(session->dir() + "/report.json");
    const nlohmann::json report = nlohmann::json::parse(in, nullptr, false);
    ASSERT_FALSE(report.is_discarded());
    const nlohmann::json extents = report["measurement"]["oriented_box"]["extents_mm"];
    ASSERT_EQ(extents.size(), 3u) << report.dump(2);
    std::array<double, 3> e{extents[0].get<double>(), extents[1].get<double>(),
                            extents[2].get<double>()};
    std::sort(e.begin(), e.end(), std::greater<>());
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(e[k], c.truth_mm[k], c.tolerance_mm[k]) << "extent " << k;
    ASSERT_TRUE(report.contains("quality")) << report.dump(2);
    EXPECT_LT(report["quality"]["far_from_mesh_pct"].get<double>(), 25.0);
    EXPECT_GT(report["free_space_check"]["removed_points"].get<double>(), 0);
    // Fusion's counts: the voxels multi-view support dropped, and the fused
    // cloud as large as the kept voxels.
    EXPECT_GT(report["fusion"]["unsupported_voxels_dropped"].get<double>(), 0) << report.dump(2);
    EXPECT_GE(report["fusion"].value("platter_shadow_voxels_dropped", -1.0), 0) << report.dump(2);
    EXPECT_EQ(report["fusion"]["output_points"].get<double>(),
              report["fused_points"].get<double>());
    std::printf(
        "%s%s: OBB %.1f x %.1f x %.1f mm, %.2f %% of the fused points > 1 mm from the mesh\n",
        c.object, c.projector ? " (projector)" : "", e[0], e[1], e[2],
        report["quality"]["far_from_mesh_pct"].get<double>());
  }
}

// A scan's own exposure bracket (the scan command's exposure_bracket, over
// the station's default of none): every view is captured at ×1 and ×4 and
// stored merged, the multiples recorded in the session's params (for a
// resume) and in every view's meta, and the camera is back at its exposure
// afterwards.
TEST(Daemon, AScanTakesItsOwnExposureBracketAndRecordsIt) {
  auto r = StartDaemon("640x512");
  ASSERT_TRUE(r);
  StationClient& c = r->client;
  std::string error;
  auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  const auto run = [&](const std::string& verb, const nlohmann::json& args) {
    const auto reply = c.Send(verb, args, kOperatorToken);
    EXPECT_TRUE(reply && reply->code_name == "ok") << (reply ? reply->message : "no reply") << "\n"
                                                   << r->fixture.Log();
    if (!reply || reply->code_name != "ok") return std::unique_ptr<daemon::Session>();
    const nlohmann::json job =
        WaitForJobEnd(c, kObserverToken, reply->result["id"].get<std::string>(), 300s);
    EXPECT_EQ(job.value("state", ""), "done") << job.dump(2) << "\n" << r->fixture.Log();
    return store->OpenSession(reply->result["session"].get<std::string>(), StatusInto(&error));
  };
  // One exposure (the station's default): the plain image's mean.
  auto plain = run("capture", {{"object", "plain"}});
  ASSERT_TRUE(plain) << error;
  cv::Mat plain_left, plain_right;
  ASSERT_TRUE(plain->LoadCapture(0, &plain_left, &plain_right, nullptr, &error)) << error;
  EXPECT_EQ(plain->params().value("exposure_bracket", nlohmann::json()), nlohmann::json::array());

  auto bracketed = run(
      "scan", {{"object", "bracketed"}, {"views", 2}, {"step_deg", 30}, {"exposure_bracket", {4}}});
  ASSERT_TRUE(bracketed) << error;
  EXPECT_EQ(bracketed->params().value("exposure_bracket", nlohmann::json()),
            nlohmann::json::array({4.0}));
  for (int k = 0; k < 2; ++k) {
    cv::Mat left, right;
    nlohmann::json meta;
    ASSERT_TRUE(bracketed->LoadCapture(k, &left, &right, &meta, &error)) << error;
    EXPECT_EQ(meta.value("exposure_bracket", nlohmann::json()), nlohmann::json::array({4.0}))
        << meta.dump();
    EXPECT_DOUBLE_EQ(meta.value("exposure_us", 0.0), 10000) << "the reference exposure";
    // Merged and gamma-encoded: the scene's darks lifted well above the
    // plain capture's (the same scene, turned by at most 30°).
    EXPECT_GT(cv::mean(left)[1], cv::mean(plain_left)[1] + 15) << "view " << k;
  }
  // The camera is back at its exposure.
  const auto camera = c.Send("camera", nlohmann::json::object(), kOperatorToken);
  ASSERT_TRUE(camera);
  ASSERT_EQ(camera->code_name, "ok") << camera->message;
  EXPECT_DOUBLE_EQ(camera->result.value("exposure_us", 0.0), 10000);
}

TEST(Daemon, BadCommandsGetClearErrorsAndTheDaemonKeepsServing) {
  auto r = StartDaemon("640x512");
  ASSERT_TRUE(r);
  StationClient& c = r->client;
  struct Case {
    std::string verb, arguments, token, code;
  };
  const std::vector<Case> cases = {
      {"status", "", "wrong-token-0123456789", "unauthenticated"},
      {"status", "", "", "unauthenticated"},
      {"explode", "", kAdminToken, "unknown_verb"},
      {"scan", "{}", kObserverToken, "forbidden"},
      {"calibrate", "", kOperatorToken, "forbidden"},
      {"scan", "{\"views\": \"six\"}", kOperatorToken, "bad_argument"},
      {"scan", "{\"views\": 1000}", kOperatorToken, "bad_argument"},
      {"scan", "{\"colour\": 1}", kOperatorToken, "bad_argument"},
      {"scan", "{\"exposure_bracket\": 8}", kOperatorToken, "bad_argument"},
      {"scan", "{\"exposure_bracket\": [2, \"x\"]}", kOperatorToken, "bad_argument"},
      {"scan", "{\"exposure_bracket\": [2, 4, 8, 16, 32]}", kOperatorToken, "bad_argument"},
      {"scan", "{\"exposure_bracket\": [8, 4]}", kOperatorToken, "failed"},
      {"scan", "{\"exposure_bracket\": [0.5]}", kOperatorToken, "failed"},
      {"scan", "{\"step_deg\": 1e999}", kOperatorToken, "bad_request"},
      {"scan", "[1, 2]", kOperatorToken, "bad_request"},
      {"scan", "{\"views\": 6", kOperatorToken, "bad_request"},
      {"resume", "{\"session\": \"../../etc\"}", kOperatorToken, "bad_argument"},
      {"resume", "{\"session\": \"20260101-000000-nothing\"}", kOperatorToken, "not_found"},
      {"get", "{\"session\": \"20260101-000000-nothing\"}", kObserverToken, "not_found"},
      {"turntable", "{\"action\": \"spin\"}", kOperatorToken, "bad_argument"},
      {"camera", "{\"exposure_us\": -5}", kOperatorToken, "bad_argument"},
      {"scan", "{\"object\": \"" + std::string(70000, 'x') + "\"}", kOperatorToken, "too_large"},
      {"cancel", "", kOperatorToken, "failed"},
  };
  for (const Case& k : cases) {
    const auto reply = c.SendRaw(k.verb, k.arguments, k.token);
    ASSERT_TRUE(reply) << k.verb << " " << k.arguments.substr(0, 60) << ": no reply";
    EXPECT_EQ(reply->code_name, k.code)
        << k.verb << " " << k.arguments.substr(0, 60) << ": " << reply->message;
    EXPECT_FALSE(reply->message.empty());
  }
  // A scan with a traversal attempt in the object name stays in sessions/.
  auto scan = c.Send("capture", {{"object", "../../../etc/passwd"}}, kOperatorToken);
  ASSERT_TRUE(scan);
  ASSERT_EQ(scan->code_name, "ok") << scan->message;
  const std::string session = scan->result["session"];
  EXPECT_EQ(session.find('/'), std::string::npos);
  EXPECT_EQ(session.find(".."), std::string::npos);
  // Busy while it runs.
  const auto busy = c.Send("scan", {{"views", 6}}, kOperatorToken);
  ASSERT_TRUE(busy);
  EXPECT_EQ(busy->code_name, "busy") << busy->message;
  const nlohmann::json job = WaitForJobEnd(c, kObserverToken, scan->result["id"], 120s);
  EXPECT_EQ(job.value("state", ""), "done") << job.dump() << r->fixture.Log();
  EXPECT_TRUE(std::filesystem::exists(r->fixture.data_dir() + "/sessions/" + session +
                                      "/views/000/left.png"));
  // Still serving.
  const auto status = c.Send("status", nullptr, kObserverToken);
  ASSERT_TRUE(status);
  EXPECT_EQ(status->code_name, "ok");
  EXPECT_EQ(status->result["state"], "idle");
  const auto sessions = c.Send("sessions", nullptr, kObserverToken);
  ASSERT_TRUE(sessions);
  EXPECT_EQ(sessions->result["sessions"].size(), 1u);
}

// Every verb, every role: a role below the verb's gets `forbidden`; a role
// that suffices passes the role check and gets to argument checking (an
// unknown key makes that `bad_argument`, so nothing runs). The expected table
// is DESIGN's, written out here independently of the daemon's.
TEST(Daemon, TokenRolesAreEnforcedOnEveryVerb) {
  auto r = StartDaemon("320x256");
  ASSERT_TRUE(r);
  StationClient& c = r->client;
  const std::vector<std::pair<std::string, int>> verbs = {
      // 0 observer, 1 operator, 2 admin
      {"status", 0},    {"sessions", 0}, {"devices", 0},   {"get", 0},
      {"capture", 1},   {"scan", 1},     {"cancel", 1},    {"resume", 1},
      {"turntable", 1}, {"camera", 1},   {"calibrate", 2}, {"calibrate-turntable", 2}};
  const std::vector<std::string> tokens = {kObserverToken, kOperatorToken, kAdminToken};
  int forbidden = 0, passed = 0;
  for (const auto& [verb, needed] : verbs) {
    for (int role = 0; role < 3; ++role) {
      const auto reply = c.SendRaw(verb, "{\"no_such_key\": 1}", tokens[role]);
      ASSERT_TRUE(reply) << verb << " as role " << role << ": no reply";
      const std::string expected = role < needed ? "forbidden" : "bad_argument";
      EXPECT_EQ(reply->code_name, expected)
          << verb << " as role " << role << ": " << reply->message;
      (expected == "forbidden" ? forbidden : passed) += reply->code_name == expected;
    }
  }
  EXPECT_EQ(forbidden, 4 * 0 + 6 * 1 + 2 * 2);  // observer verbs forbid nobody
  EXPECT_EQ(passed, 4 * 3 + 6 * 2 + 2 * 1);
  // Nothing ran.
  const auto sessions = c.Send("sessions", nullptr, kObserverToken);
  ASSERT_TRUE(sessions);
  EXPECT_EQ(sessions->result["sessions"].size(), 0u);
}

// resume answers not_found only for a session that is not there: a session
// whose id holds "unknown" (its object's name) and cannot be resumed
// because it is done is `failed`, saying why. (The answer was once guessed
// from the error's text, so this one was not_found.)
TEST(Daemon, ResumeOfADoneSessionNamedUnknownIsFailedNotNotFound) {
  auto r = StartDaemon("320x256");
  ASSERT_TRUE(r);
  StationClient& c = r->client;
  const auto capture = c.Send("capture", {{"object", "unknown"}}, kOperatorToken);
  ASSERT_TRUE(capture);
  ASSERT_EQ(capture->code_name, "ok") << capture->message;
  const std::string session = capture->result["session"];
  ASSERT_NE(session.find("unknown"), std::string::npos) << session;
  const nlohmann::json job = WaitForJobEnd(c, kObserverToken, capture->result["id"], 120s);
  ASSERT_EQ(job.value("state", ""), "done") << job.dump() << r->fixture.Log();
  const auto resume = c.Send("resume", {{"session", session}}, kOperatorToken);
  ASSERT_TRUE(resume);
  EXPECT_EQ(resume->code_name, "failed") << resume->message;
  EXPECT_NE(resume->message.find("already done"), std::string::npos) << resume->message;
  const auto missing = c.Send("resume", {{"session", "20260101-000000-unknown"}}, kOperatorToken);
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->code_name, "not_found") << missing->message;
}

// A cancel during a long turntable move stops the table (the driver's abort)
// instead of waiting for the move: at 6 deg/s the 90-degree move to view 1
// takes 15 s, and the job must end well before that. The session stays
// resumable with view 0 intact.
TEST(Daemon, CancelDuringAMoveAbortsTheMove) {
  auto r = StartDaemon("320x256", 0, true, ", turntable_speed_deg_s: 6");
  ASSERT_TRUE(r);
  StationClient& c = r->client;
  const auto scan =
      c.Send("scan", {{"object", "box"}, {"views", 4}, {"step_deg", 90}}, kOperatorToken);
  ASSERT_TRUE(scan);
  ASSERT_EQ(scan->code_name, "ok") << scan->message;
  const std::string id = scan->result["id"];
  // Wait until the move to view 1 has begun.
  bool moving = false;
  for (int i = 0; i < 600 && !moving; ++i) {
    {
      auto lock = c.Lock();
      for (const std::string& message : c.progress_messages) {
        moving = moving || message.find("moving to 90") != std::string::npos;
      }
    }
    if (!moving) std::this_thread::sleep_for(100ms);
  }
  ASSERT_TRUE(moving) << "the scan never began its move to view 1\n" << r->fixture.Log();
  std::this_thread::sleep_for(1s);
  const auto move_started = std::chrono::steady_clock::now();
  const auto cancel = c.Send("cancel", nullptr, kOperatorToken);
  ASSERT_TRUE(cancel);
  ASSERT_EQ(cancel->code_name, "ok") << cancel->message;
  const nlohmann::json job = WaitForJobEnd(c, kObserverToken, id, 60s);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - move_started).count();
  EXPECT_NE(job.value("state", ""), "running");
  EXPECT_NE(job.value("message", "").find("cancelled"), std::string::npos) << job.dump();
  // The rest of the move would have taken about 14 s.
  EXPECT_LT(seconds, 8.0) << "the cancel waited for the move to end";
  const std::string session = scan->result["session"];
  std::string error;
  auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store) << error;
  auto opened = store->OpenSession(session, StatusInto(&error));
  ASSERT_TRUE(opened) << error;
  EXPECT_EQ(opened->state(), SessionState::kInterrupted);
  EXPECT_EQ(opened->DurableViews().size(), 1u);
}

TEST(Daemon, SigkillDuringAScanLosesNothingAndResumeCompletesItWithoutRecapturing) {
  auto r = StartDaemon("640x512");
  ASSERT_TRUE(r);
  const auto reply = r->client.Send("scan", {{"object", "egg"}, {"views", 6}}, kOperatorToken);
  ASSERT_TRUE(reply);
  ASSERT_EQ(reply->code_name, "ok") << reply->message;
  const std::string session_id = reply->result["session"];
  // Kill it once three captures were acknowledged.
  ASSERT_TRUE(r->client.WaitFor([](StationClient& c) { return c.captures.size() >= 3; }, 120s))
      << r->fixture.Log();
  std::vector<CaptureRecord> acknowledged;
  {
    auto lock = r->client.Lock();
    acknowledged = r->client.captures;
  }
  const int status = r->fixture.Stop(SIGKILL);
  ASSERT_TRUE(WIFSIGNALED(status));

  // Every acknowledged capture is on disk and intact.
  std::string error;
  {
    auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
    ASSERT_TRUE(store) << error;
    const daemon::VerifyResult verify = store->Verify(session_id);
    EXPECT_TRUE(verify.IsIntact()) << (verify.problems.empty() ? "" : verify.problems[0]);
    auto session = store->OpenSession(session_id, StatusInto(&error));
    ASSERT_TRUE(session) << error;
    const std::vector<int> durable = session->DurableViews();
    for (const CaptureRecord& ack : acknowledged) {
      EXPECT_TRUE(std::count(durable.begin(), durable.end(), ack.view)) << "view " << ack.view;
    }
  }

  // Restart: the session is interrupted; resume completes it.
  ASSERT_TRUE(r->fixture.Start(&error)) << error;
  ASSERT_TRUE(
      r->client.WaitFor([](StationClient& c) { return c.last_status_state == "idle"; }, 60s))
      << r->fixture.Log();
  const auto sessions = r->client.Send("sessions", nullptr, kObserverToken);
  ASSERT_TRUE(sessions);
  ASSERT_EQ(sessions->result["sessions"].size(), 1u);
  EXPECT_EQ(sessions->result["sessions"][0]["state"], "interrupted");
  std::size_t captures_before = 0;
  {
    auto lock = r->client.Lock();
    captures_before = r->client.captures.size();
  }
  const auto resume = r->client.Send("resume", {{"session", session_id}}, kOperatorToken);
  ASSERT_TRUE(resume);
  ASSERT_EQ(resume->code_name, "ok") << resume->message;
  const nlohmann::json job = WaitForJobEnd(r->client, kObserverToken, resume->result["id"], 300s);
  ASSERT_EQ(job.value("state", ""), "done")
      << job.dump() << r->fixture.Log() << "\ndaemon alive: " << (::kill(r->fixture.pid(), 0) == 0);
  {
    auto lock = r->client.Lock();
    std::set<int> recaptured;
    for (std::size_t i = captures_before; i < r->client.captures.size(); ++i) {
      recaptured.insert(r->client.captures[i].view);
    }
    for (const CaptureRecord& ack : acknowledged) {
      EXPECT_FALSE(recaptured.count(ack.view)) << "view " << ack.view << " was captured again";
    }
    EXPECT_EQ(recaptured.size() + acknowledged.size(), 6u);
  }
  auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store);
  auto session = store->OpenSession(session_id, StatusInto(&error));
  ASSERT_TRUE(session) << error;
  EXPECT_EQ(session->state(), SessionState::kDone);
  EXPECT_EQ(session->DurableViews().size(), 6u);
  EXPECT_TRUE(session->Verify().IsIntact());
}

// Calibration from scratch on the simulated station: the held board
// (stereo) and the board on the platter (turntable axis), against the sim
// rig's exact calibration.
TEST(Daemon, CalibratesTheStationFromBoardViews) {
  // 640x512: the daemon's calibration jobs run alike at any size; the
  // accuracy at full size is SimCalibration's (tests/integration).
  auto r = StartDaemon("640x512", 0, /*with_calibration=*/false);
  ASSERT_TRUE(r);
  StationClient& c = r->client;
  const auto refused = c.Send("scan", {{"views", 6}}, kOperatorToken);
  ASSERT_TRUE(refused);
  EXPECT_EQ(refused->code_name, "failed");
  EXPECT_NE(refused->message.find("no calibration"), std::string::npos) << refused->message;

  const auto calibrate = c.Send("calibrate", nullptr, kAdminToken);
  ASSERT_TRUE(calibrate);
  ASSERT_EQ(calibrate->code_name, "ok") << calibrate->message;
  nlohmann::json job = WaitForJobEnd(c, kObserverToken, calibrate->result["id"], 600s);
  ASSERT_EQ(job.value("state", ""), "done") << job.dump(2) << r->fixture.Log();
  const nlohmann::json stereo = job["result"];
  std::printf("calibrate: %s\n", stereo.dump().c_str());

  const auto axis = c.Send("calibrate-turntable", nullptr, kAdminToken);
  ASSERT_TRUE(axis);
  ASSERT_EQ(axis->code_name, "ok") << axis->message;
  job = WaitForJobEnd(c, kObserverToken, axis->result["id"], 300s);
  ASSERT_EQ(job.value("state", ""), "done") << job.dump(2) << r->fixture.Log();
  std::printf("calibrate-turntable: %s\n", job["result"].dump().c_str());

  // The current calibration against the rig's exact one.
  std::string error;
  StereoCalibration measured;
  ASSERT_TRUE(
      LoadCalibration(r->fixture.data_dir() + "/calibration/current.yaml", &measured, &error))
      << error;
  sim::SimDriverOptions options;
  ASSERT_TRUE(sim::SimDriverOptionsFromConfig({{"image_size", "640x512"}}, &options, &error));
  auto station = sim::SimStation::Create(sim::SimRigOptions(options), &error);
  ASSERT_TRUE(station) << error;
  const StereoCalibration& truth = station->calibration();
  const double fx = measured.left.camera_matrix(0, 0), fx_true = truth.left.camera_matrix(0, 0);
  EXPECT_NEAR(fx / fx_true, 1.0, 0.003) << fx << " vs " << fx_true;
  EXPECT_NEAR(cv::norm(measured.T), cv::norm(truth.T), 0.2);
  EXPECT_LT(stereo.value("rms_stereo_px", 1e9), 0.3);
  ASSERT_TRUE(measured.turntable.valid);
  const double cos_angle =
      measured.turntable.direction_in_rig.dot(truth.turntable.direction_in_rig);
  EXPECT_LT(std::acos(std::min(1.0, cos_angle)) * 180 / CV_PI, 0.2);
  const cv::Vec3d d = measured.turntable.point_in_rig_mm - truth.turntable.point_in_rig_mm;
  // The point may slide along the axis only with the platter height error.
  EXPECT_LT(cv::norm(d), 2.0) << d;
  const auto status = c.Send("status", nullptr, kObserverToken);
  ASSERT_TRUE(status);
  EXPECT_EQ(status->result["calibration_id"], job["result"]["calibration_id"]);
}

// The camera vanishes mid-scan (sim: after 3 frames per connection) and
// comes back on the second reconnect attempt: the scan goes on, no view lost.
TEST(DaemonFaults, CameraLostMidScanIsRecoveredAndTheScanCompletes) {
  auto r = StartDaemon("640x512", 0, true,
                       ", disconnect_after: 3, reconnect_failures: 1, reconnect_attempts: 3, "
                       "reconnect_delay_ms: 50");
  ASSERT_TRUE(r);
  const auto reply = r->client.Send("scan", {{"object", "box"}, {"views", 6}}, kOperatorToken);
  ASSERT_TRUE(reply);
  ASSERT_EQ(reply->code_name, "ok") << reply->message;
  const nlohmann::json job = WaitForJobEnd(r->client, kObserverToken, reply->result["id"], 300s);
  EXPECT_EQ(job.value("state", ""), "done") << job.dump() << r->fixture.Log();
  EXPECT_NE(r->fixture.Log().find("reconnected"), std::string::npos) << r->fixture.Log();
  std::string error;
  auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store);
  auto session = store->OpenSession(reply->result["session"], StatusInto(&error));
  ASSERT_TRUE(session) << error;
  EXPECT_EQ(session->DurableViews().size(), 6u);
  EXPECT_TRUE(session->Verify().IsIntact());
}

// The camera vanishes for good: the job fails with the reason, the session
// is interrupted with every capture intact, the daemon keeps serving; once
// the camera is back (restart without the fault), resume completes it.
TEST(DaemonFaults, CameraGoneForGoodInterruptsTheScanAndResumeFinishesIt) {
  auto r = StartDaemon("640x512", 0, true,
                       ", disconnect_after: 2, reconnect_failures: 100, reconnect_attempts: 2, "
                       "reconnect_delay_ms: 20");
  ASSERT_TRUE(r);
  const auto reply = r->client.Send("scan", {{"object", "box"}, {"views", 6}}, kOperatorToken);
  ASSERT_TRUE(reply);
  ASSERT_EQ(reply->code_name, "ok") << reply->message;
  const std::string session_id = reply->result["session"];
  const nlohmann::json job = WaitForJobEnd(r->client, kObserverToken, reply->result["id"], 300s);
  EXPECT_EQ(job.value("state", ""), "failed") << job.dump();
  EXPECT_NE(job.value("message", "").find("camera lost"), std::string::npos) << job.dump();
  const auto status = r->client.Send("status", nullptr, kObserverToken);
  ASSERT_TRUE(status);
  EXPECT_NE(status->result.value("last_error", "").find("camera lost"), std::string::npos)
      << status->result.dump();
  std::string error;
  {
    auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
    ASSERT_TRUE(store);
    auto session = store->OpenSession(session_id, StatusInto(&error));
    ASSERT_TRUE(session) << error;
    EXPECT_EQ(session->state(), SessionState::kInterrupted);
    EXPECT_EQ(session->DurableViews(), (std::vector<int>{0, 1}));
    EXPECT_TRUE(session->Verify().IsIntact());
  }
  // The camera comes back: a daemon without the fault resumes the session.
  ASSERT_EQ(r->fixture.Stop(SIGTERM), 0) << r->fixture.Log();
  DaemonFixture& f = r->fixture;
  {
    std::string text = ReadFile(f.root() + "/craftscand.yaml");
    for (std::size_t at; (at = text.find(", disconnect_after")) != std::string::npos;) {
      text.erase(at, text.find('}', at) - at);
    }
    std::ofstream(f.root() + "/craftscand.yaml") << text;
  }
  ASSERT_TRUE(f.Start(&error)) << error;
  ASSERT_TRUE(
      r->client.WaitFor([](StationClient& c) { return c.last_status_state == "idle"; }, 60s));
  const auto resume = r->client.Send("resume", {{"session", session_id}}, kOperatorToken);
  ASSERT_TRUE(resume);
  ASSERT_EQ(resume->code_name, "ok") << resume->message;
  const nlohmann::json resumed =
      WaitForJobEnd(r->client, kObserverToken, resume->result["id"], 300s);
  EXPECT_EQ(resumed.value("state", ""), "done") << resumed.dump() << f.Log();
}

// A turntable alarm stops the scan safely with the reason; nothing
// recorded is lost.
TEST(DaemonFaults, TurntableAlarmStopsTheScanWithTheReason) {
  auto r = StartDaemon("640x512", 0, true, ", turntable_alarm: 1");
  ASSERT_TRUE(r);
  const auto reply = r->client.Send("scan", {{"object", "box"}, {"views", 6}}, kOperatorToken);
  ASSERT_TRUE(reply);
  ASSERT_EQ(reply->code_name, "ok") << reply->message;
  const nlohmann::json job = WaitForJobEnd(r->client, kObserverToken, reply->result["id"], 120s);
  EXPECT_EQ(job.value("state", ""), "failed") << job.dump();
  EXPECT_NE(job.value("message", "").find("ALARM"), std::string::npos) << job.dump();
  const auto status = r->client.Send("status", nullptr, kObserverToken);
  ASSERT_TRUE(status);
  EXPECT_EQ(status->result["state"], "idle");
  std::string error;
  auto store = daemon::SessionStore::Open(r->fixture.data_dir(), StatusInto(&error));
  ASSERT_TRUE(store);
  auto session = store->OpenSession(reply->result["session"], StatusInto(&error));
  ASSERT_TRUE(session) << error;
  EXPECT_EQ(session->state(), SessionState::kInterrupted);
  EXPECT_TRUE(session->Verify().IsIntact());
}

TEST(Daemon, TellsSystemdReadyWatchdogAndStoppingInOrder) {
  auto r = StartDaemon("640x512", /*watchdog_usec=*/400000);
  ASSERT_TRUE(r);
  FakeNotifySocket& manager = r->fixture.notify();
  std::vector<std::string> order;
  auto note = [&](const NotifyMessage& m) {
    for (const char* a : {"READY=1", "WATCHDOG=1", "STOPPING=1"})
      if (m.Has(a) && (order.empty() || order.back() != a)) order.push_back(a);
  };
  const auto ready = manager.WaitFor("READY=1", 30s);
  ASSERT_TRUE(ready) << r->fixture.Log();
  EXPECT_EQ(ready->pid, r->fixture.pid());
  note(*ready);
  EXPECT_TRUE(ready->Value("STATUS").has_value());
  const auto ping = manager.WaitFor("WATCHDOG=1", 5s);
  ASSERT_TRUE(ping);
  note(*ping);
  ::kill(r->fixture.pid(), SIGTERM);
  while (auto m = manager.Receive(10s)) {
    note(*m);
    if (m->Has("STOPPING=1")) break;
  }
  const int status = r->fixture.Stop(SIGTERM);
  ASSERT_TRUE(WIFEXITED(status)) << r->fixture.Log();
  EXPECT_EQ(WEXITSTATUS(status), 0);
  EXPECT_EQ(order, (std::vector<std::string>{"READY=1", "WATCHDOG=1", "STOPPING=1"}));
}

}  // namespace
}  // namespace craftscan::testing
