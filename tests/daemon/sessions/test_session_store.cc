// SessionStore and Session: layout, round trips, journal, interruption,
// leftovers of crashes, corrupt manifests, verification and resume points.
#include <gtest/gtest.h>

#include <sys/stat.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <thread>

#include <nlohmann/json.hpp>

#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/sha256.h"
#include "session_test_util.h"
#include "status_util.h"

using craftscan::testing::Ok;
using craftscan::testing::StatusInto;

namespace craftscan::daemon {
namespace {

namespace fs = std::filesystem;
using namespace testing;  // NOLINT(build/namespaces): the helpers of session_test_util.h

nlohmann::json Meta(int view) {
  return {{"view", view}, {"exposure_us", 8000 + view}, {"stamp_ns", 1714555800000000000LL + view}};
}

bool Capture(Session& s, int view, std::string* error) {
  return Ok(s.StoreCapture(view, view * 90.0, NoiseImage(40, 30, CV_8UC3, 2 * view),
                           NoiseImage(40, 30, CV_8UC3, 2 * view + 1), Meta(view)),
            error);
}

TEST_F(SessionFiles, OpenRefusesDataDirsThatAreMissingOrNotDirectories) {
  std::string error;
  EXPECT_EQ(SessionStore::Open(Path("missing"), StatusInto(&error)), nullptr);
  EXPECT_TRUE(Contains(error, "missing") && Contains(error, "No such file or directory")) << error;
  WriteBytes("plain", "x");
  EXPECT_EQ(SessionStore::Open(Path("plain"), StatusInto(&error)), nullptr);
  EXPECT_TRUE(Contains(error, "is not a directory")) << error;
  EXPECT_EQ(SessionStore::Open("", StatusInto(&error)), nullptr);
  // data_dir/sessions exists as a file: not usable.
  fs::create_directories(Path("odd"));
  WriteBytes("odd/sessions", "x");
  EXPECT_EQ(SessionStore::Open(Path("odd"), StatusInto(&error)), nullptr);
  EXPECT_TRUE(Contains(error, "odd/sessions") && Contains(error, "File exists")) << error;
  EXPECT_TRUE(fs::is_directory(fs::path(data_dir_) / "sessions"));
  EXPECT_EQ(testing::CountTemporaries(data_dir_), 0);  // the writability probe is gone
}

TEST_F(SessionFiles, HostileObjectNamesStayInsideTheSessionsFolder) {
  const auto now = Clock::now();
  const std::string names[] = {
      "../../etc",           "a/b", ".hidden",   "-rf", "\xc3\x84gg \xe5\xb5\x8c",
      std::string(300, 'n'), "",    "/abs/path", "..",  "x\\..\\y"};
  std::set<std::string> ids;
  for (const auto& name : names) {
    std::string error;
    auto s = store_->Create(name, "capture", nlohmann::json::object(), now, StatusInto(&error));
    ASSERT_NE(s, nullptr) << name << ": " << error;
    EXPECT_TRUE(IsValidSessionId(s->id())) << s->id();
    EXPECT_EQ(fs::path(s->dir()).parent_path(), fs::path(store_->sessions_dir()));
    EXPECT_TRUE(fs::is_regular_file(fs::path(s->dir()) / "manifest.json"));
    EXPECT_EQ(s->manifest().object_name, name);
    EXPECT_EQ(s->manifest().object, SanitizeObjectName(name));
    ids.insert(s->id());
  }
  EXPECT_EQ(ids.size(), std::size(names));
  // Nothing was created anywhere but in sessions/ (and nothing hidden there).
  int entries = 0;
  for (const auto& e : fs::directory_iterator(data_dir_)) {
    EXPECT_EQ(e.path().filename(), "sessions");
    ++entries;
  }
  EXPECT_EQ(entries, 1);
  int sessions = 0;
  for (const auto& e : fs::directory_iterator(store_->sessions_dir())) {
    EXPECT_NE(e.path().filename().string()[0], '.') << e.path();
    ++sessions;
  }
  EXPECT_EQ(sessions, static_cast<int>(std::size(names)));
}

TEST_F(SessionFiles, IdsGetSuffixesOnCollisionAndInvalidArgumentsAreRefused) {
  // 2024-05-01 09:30:00 UTC.
  const Clock::time_point now{std::chrono::seconds(1714555800)};
  std::string error;
  auto a = store_->Create("egg", "scan", {{"views", 3}}, now, StatusInto(&error));
  auto b = store_->Create("egg", "scan", {{"views", 3}}, now, StatusInto(&error));
  auto c = store_->Create("egg", "scan", {{"views", 3}}, now, StatusInto(&error));
  ASSERT_TRUE(a && b && c) << error;
  EXPECT_EQ(a->id(), "20240501-093000-egg");
  EXPECT_EQ(b->id(), "20240501-093000-egg-2");
  EXPECT_EQ(c->id(), "20240501-093000-egg-3");
  EXPECT_EQ(c->manifest().id, c->id());
  EXPECT_EQ(a->manifest().created_utc, "2024-05-01T09:30:00.000Z");
  EXPECT_EQ(a->state(), SessionState::kCreated);
  EXPECT_EQ(a->params()["views"], 3);

  EXPECT_EQ(store_->Create("egg", "Scan!", nlohmann::json::object(), now, StatusInto(&error)),
            nullptr);
  EXPECT_TRUE(Contains(error, "job verb")) << error;
  EXPECT_EQ(store_->Create("egg", "", nlohmann::json::object(), now, StatusInto(&error)), nullptr);
  EXPECT_EQ(store_->Create("egg", "scan", nlohmann::json::array({1}), now, StatusInto(&error)),
            nullptr);
  EXPECT_TRUE(Contains(error, "JSON object") && Contains(error, "array")) << error;
  EXPECT_EQ(store_->List().size(), 3u);
}

TEST_F(SessionFiles, StoreAndLoadRoundTripBitExactly) {
  auto s = NewCapturing("round trip", 3);
  ASSERT_NE(s, nullptr);
  std::string error;
  WriteBytes("rig.yaml", "%YAML:1.0\nbaseline_mm: 60.25\n");
  ASSERT_TRUE(Ok(s->CopyCalibration(Path("rig.yaml"), "rig-a"), &error)) << error;
  EXPECT_EQ(ReadAll(s->CalibrationPath()), "%YAML:1.0\nbaseline_mm: 60.25\n");
  fs::remove(Path("rig.yaml"));  // copied, never referenced
  EXPECT_TRUE(fs::exists(fs::path(s->dir()) / "calibration.yaml"));

  // 8-bit colour, 16-bit grey and 8-bit BGRA pairs.
  const int types[3] = {CV_8UC3, CV_16UC1, CV_8UC4};
  std::vector<cv::Mat> lefts, rights;
  for (int v = 0; v < 3; ++v) {
    lefts.push_back(NoiseImage(97, 61, types[v], 10 * v));
    rights.push_back(NoiseImage(97, 61, types[v], 10 * v + 1));
    ASSERT_TRUE(Ok(s->StoreCapture(v, 120.0 * v, lefts[v], rights[v], Meta(v)), &error)) << error;
  }
  cv::Mat disparity = NoiseImage(97, 61, CV_32FC1, 99);
  disparity.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  disparity.at<float>(1, 1) = -std::numeric_limits<float>::infinity();
  disparity.at<float>(2, 2) = 1e-42f;  // denormal
  ASSERT_TRUE(Ok(s->StoreDisparity(1, disparity), &error)) << error;
  PointCloud cloud;
  for (int i = 0; i < 500; ++i) {
    cloud.points_mm.push_back({i * 0.1f, -i * 1e-3f, 300.0f + i / 7.0f});
    cloud.normals.push_back({0, std::sin(i * 0.1f), std::cos(i * 0.1f)});
    cloud.colors_rgb.push_back({static_cast<uchar>(i), 7, static_cast<uchar>(255 - i % 256)});
  }
  ASSERT_TRUE(Ok(s->StoreCloud(1, cloud), &error)) << error;
  const std::string report = "{\"length_mm\": 81.5}\n";
  ASSERT_TRUE(Ok(s->StoreOutput("report.json", report), &error)) << error;
  ASSERT_TRUE(Ok(s->StoreOutput("previews/view001.png", std::string("\x89PNG\0\1", 6)), &error))
      << error;
  ASSERT_TRUE(Ok(s->StoreOutputWith("fused.ply",
                                    [&](const std::string& path) {
                                      return WriteFileAtomically(path, EncodePly(cloud, true));
                                    }),
                 &error))
      << error;

  const auto check = [&](const Session& session) {
    for (int v = 0; v < 3; ++v) {
      cv::Mat left, right;
      nlohmann::json meta;
      ASSERT_TRUE(session.LoadCapture(v, &left, &right, &meta, &error)) << error;
      EXPECT_TRUE(BitExact(left, lefts[v])) << "view " << v;
      EXPECT_TRUE(BitExact(right, rights[v])) << "view " << v;
      EXPECT_EQ(meta, Meta(v));
      EXPECT_EQ(session.manifest().views.at(v).angle_deg, 120.0 * v);
    }
    cv::Mat d;
    ASSERT_TRUE(session.LoadDisparity(1, &d, &error)) << error;
    EXPECT_TRUE(BitExact(d, disparity));
    PointCloud back;
    ASSERT_TRUE(session.LoadCloud(1, &back, &error)) << error;
    ASSERT_EQ(back.size(), cloud.size());
    EXPECT_EQ(0, std::memcmp(back.points_mm.data(), cloud.points_mm.data(), 500 * 12));
    EXPECT_EQ(0, std::memcmp(back.normals.data(), cloud.normals.data(), 500 * 12));
    EXPECT_EQ(0, std::memcmp(back.colors_rgb.data(), cloud.colors_rgb.data(), 500 * 3));
    std::string bytes;
    ASSERT_TRUE(session.LoadOutput("report.json", &bytes, &error)) << error;
    EXPECT_EQ(bytes, report);
    ASSERT_TRUE(session.LoadOutput("previews/view001.png", &bytes, &error)) << error;
    EXPECT_EQ(bytes, std::string("\x89PNG\0\1", 6));
    EXPECT_EQ(session.DurableViews(), (std::vector<int>{0, 1, 2}));
    const VerifyResult verify = session.Verify();
    EXPECT_TRUE(verify.IsIntact()) << ::testing::PrintToString(verify.problems);
    EXPECT_EQ(verify.files_checked, 1 + 9 + 2 + 3);  // calibration, 3 views, 2 view files, outputs
  };
  check(*s);
  // Missing things are errors, not crashes.
  cv::Mat m1, m2;
  EXPECT_FALSE(s->LoadDisparity(0, &m1, &error));
  EXPECT_TRUE(Contains(error, "view 0 has no durable disparity.pfm")) << error;
  EXPECT_FALSE(s->LoadCapture(7, &m1, &m2, nullptr, &error));
  std::string none;
  EXPECT_FALSE(s->LoadOutput("mesh.ply", &none, &error));
  EXPECT_TRUE(Contains(error, "no durable output named 'mesh.ply'")) << error;

  // The same after closing and reopening from disk.
  const std::string id = s->id();
  s.reset();
  auto reopened = store_->OpenSession(id, StatusInto(&error));
  ASSERT_NE(reopened, nullptr) << error;
  check(*reopened);
  EXPECT_TRUE(store_->Verify(id).IsIntact());
  EXPECT_EQ(reopened->manifest().calibration_id, "rig-a");
  // The layout of DESIGN.md.
  const fs::path dir = reopened->dir();
  for (const char* file :
       {"manifest.json", "calibration.yaml", "views/000/left.png", "views/000/right.png",
        "views/000/meta.json", "views/001/disparity.pfm", "views/001/cloud.ply", "fused.ply",
        "report.json", "previews/view001.png"}) {
    EXPECT_TRUE(fs::is_regular_file(dir / file)) << file;
  }
  EXPECT_EQ(testing::CountTemporaries(dir), 0);
}

// A station with a pattern projector stores the texture frame with the
// capture; a view without one loads an empty texture; a new capture of the
// view without a texture takes the old one off the manifest.
TEST_F(SessionFiles, TextureFramesTravelWithTheirCapture) {
  auto s = NewCapturing("textured", 2);
  ASSERT_NE(s, nullptr);
  std::string error;
  const cv::Mat left = NoiseImage(64, 48, CV_8UC3, 1), right = NoiseImage(64, 48, CV_8UC3, 2);
  const cv::Mat texture = NoiseImage(64, 48, CV_8UC3, 3);
  ASSERT_TRUE(Ok(s->StoreCapture(0, 0.0, left, right, Meta(0), texture), &error)) << error;
  ASSERT_TRUE(Ok(s->StoreCapture(1, 60.0, left, right, Meta(1)), &error)) << error;
  const auto check = [&](const Session& session) {
    cv::Mat l, r, t;
    ASSERT_TRUE(session.LoadCapture(0, &l, &r, nullptr, &error, &t)) << error;
    EXPECT_TRUE(BitExact(t, texture));
    EXPECT_TRUE(BitExact(l, left));
    ASSERT_TRUE(session.LoadCapture(1, &l, &r, nullptr, &error, &t)) << error;
    EXPECT_TRUE(t.empty());
    EXPECT_EQ(session.manifest().views.at(0).files.count("texture.png"), 1u);
    EXPECT_TRUE(session.Verify().IsIntact());
  };
  check(*s);
  const std::string id = s->id();
  s.reset();
  auto reopened = store_->OpenSession(id, StatusInto(&error));
  ASSERT_NE(reopened, nullptr) << error;
  check(*reopened);
  // A texture PNG cannot hold, or of another size than the pair, is refused.
  EXPECT_FALSE(
      Ok(reopened->StoreCapture(1, 60.0, left, right, Meta(1), cv::Mat(48, 64, CV_32FC2)), &error));
  EXPECT_TRUE(Contains(error, "texture image has type")) << error;
  EXPECT_FALSE(
      Ok(reopened->StoreCapture(1, 60.0, left, right, Meta(1), NoiseImage(32, 24, CV_8UC3, 4)),
         &error));
  EXPECT_TRUE(Contains(error, "the texture image is 32x24, the left image 64x48")) << error;
  cv::Mat unchanged;
  cv::Mat l1, r1;
  ASSERT_TRUE(reopened->LoadCapture(1, &l1, &r1, nullptr, &error, &unchanged)) << error;
  EXPECT_TRUE(unchanged.empty());
  ASSERT_TRUE(Ok(reopened->StoreCapture(0, 0.0, left, right, Meta(0)), &error)) << error;
  EXPECT_EQ(reopened->manifest().views.at(0).files.count("texture.png"), 0u);
  cv::Mat l, r, t = texture.clone();
  ASSERT_TRUE(reopened->LoadCapture(0, &l, &r, nullptr, &error, &t)) << error;
  EXPECT_TRUE(t.empty());
}

TEST_F(SessionFiles, ManifestJournalFollowsTheJobAndDoneIsFinal) {
  auto s = NewCapturing("journal", 1);
  ASSERT_NE(s, nullptr);
  std::string error;
  WriteBytes("rig.yaml", "calib");
  ASSERT_TRUE(Ok(s->CopyCalibration(Path("rig.yaml"), "rig-b"), &error)) << error;
  ASSERT_TRUE(Capture(*s, 0, &error)) << error;
  ASSERT_TRUE(Ok(s->SetState(SessionState::kReconstructing, "registering 1 view"), &error))
      << error;
  ASSERT_TRUE(Ok(s->StoreOutput("fused.ply", "ply"), &error)) << error;
  ASSERT_TRUE(Ok(s->SetState(SessionState::kDone, ""), &error)) << error;

  // The manifest on disk, read as plain JSON.
  const auto j = nlohmann::json::parse(ReadAll(s->dir() + "/manifest.json"));
  EXPECT_EQ(j["format"], "craftscan-session");
  EXPECT_EQ(j["format_version"], 1);
  EXPECT_EQ(j["id"], s->id());
  EXPECT_EQ(j["state"], "done");
  EXPECT_EQ(j["job"], "scan");
  EXPECT_EQ(j["calibration"]["id"], "rig-b");
  EXPECT_EQ(j["calibration"]["size"], 5);
  EXPECT_EQ(j["views"][0]["files"]["left.png"]["size"],
            fs::file_size(s->dir() + "/views/000/left.png"));
  std::vector<std::string> events;
  std::string last_time;
  for (const auto& e : j["journal"]) {
    events.push_back(e["event"]);
    EXPECT_GE(e["time"].get<std::string>(), last_time);  // ISO 8601 sorts as text
    last_time = e["time"];
  }
  EXPECT_EQ(events, (std::vector<std::string>{"created", "capturing", "calibration",
                                              "reconstructing", "output", "done"}));
  EXPECT_EQ(j["journal"][3]["detail"], "registering 1 view");
  EXPECT_EQ(j["journal"][4]["detail"], "fused.ply");
  EXPECT_GE(j["updated"].get<std::string>(), last_time);

  // Done is final: no transitions, no stores; nothing on disk changes.
  const std::string before = ReadAll(s->dir() + "/manifest.json");
  EXPECT_FALSE(Ok(s->SetState(SessionState::kCapturing, ""), &error));
  EXPECT_TRUE(Contains(error, "cannot go from done to capturing")) << error;
  EXPECT_FALSE(Capture(*s, 1, &error));
  EXPECT_TRUE(Contains(error, "in state done")) << error;
  EXPECT_FALSE(Ok(s->StoreOutput("mesh.ply", "ply"), &error));
  EXPECT_EQ(ReadAll(s->dir() + "/manifest.json"), before);
  EXPECT_EQ(s->state(), SessionState::kDone);

  // A turn added (the object laid in another pose): the one way out of
  // done, with the new params in the same write; what was listed stays.
  nlohmann::json params = s->params();
  params["turns"] = nlohmann::json::array({{{"turn", 1}}, {{"turn", 2}}});
  EXPECT_FALSE(Ok(s->ReopenForTurn(nlohmann::json::array(), "x"), &error));
  EXPECT_TRUE(Contains(error, "params must be a JSON object")) << error;
  ASSERT_TRUE(Ok(s->ReopenForTurn(params, "turn 2"), &error)) << error;
  EXPECT_EQ(s->state(), SessionState::kCapturing);
  EXPECT_EQ(s->params()["turns"].size(), 2u);
  EXPECT_EQ(s->manifest().outputs.count("fused.ply"), 1u);
  EXPECT_EQ(s->manifest().journal.back().detail, "turn 2");
  EXPECT_FALSE(Ok(s->ReopenForTurn(params, "again"), &error)) << "only from done";
  EXPECT_TRUE(Contains(error, "only to a done session, not one capturing")) << error;
  ASSERT_TRUE(Capture(*s, 1, &error)) << error;
  params["turns"][1]["state"] = "refused";
  ASSERT_TRUE(Ok(s->SetParams(params, "turn 2 refused"), &error)) << error;
  EXPECT_EQ(s->manifest().journal.back().event, "params");
  ASSERT_TRUE(Ok(s->SetState(SessionState::kDone, "turn 1's model"), &error)) << error;
  EXPECT_TRUE(s->GetResumePoint(true).damaged.empty());
  EXPECT_EQ(s->DurableViews(), (std::vector<int>{0, 1}));

  // Failure keeps its reason; resume clears it.
  auto f = NewCapturing("fails", 1);
  ASSERT_NE(f, nullptr);
  ASSERT_TRUE(Ok(f->SetState(SessionState::kFailed, "camera lost"), &error)) << error;
  EXPECT_EQ(f->manifest().error, "camera lost");
  ASSERT_TRUE(Ok(f->SetState(SessionState::kCapturing, "resume"), &error)) << error;
  EXPECT_EQ(f->manifest().error, "");
}

TEST_F(SessionFiles, MarkInterruptedMarksOnlyUnfinishedSessionsNotHeldOpen) {
  std::string error;
  const auto make = [&](const std::string& name, std::vector<SessionState> path) {
    auto s = store_->Create(name, "scan", {{"views", 2}}, Clock::now(), StatusInto(&error));
    EXPECT_NE(s, nullptr) << error;
    for (SessionState state : path) EXPECT_TRUE(Ok(s->SetState(state, "test"), &error)) << error;
    return s;
  };
  using S = SessionState;
  const std::string created = make("created", {})->id();
  const std::string capturing = make("capturing", {S::kCapturing})->id();
  const std::string reconstructing = make("recon", {S::kCapturing, S::kReconstructing})->id();
  const std::string done = make("done", {S::kCapturing, S::kDone})->id();
  const std::string failed = make("failed", {S::kCapturing, S::kFailed})->id();
  const std::string interrupted = make("interrupted", {S::kInterrupted})->id();
  auto live = make("live", {S::kCapturing});  // a running job holds it open
  const std::string live_id = live->id();
  auto corrupt = make("corrupt", {S::kCapturing});
  const std::string corrupt_id = corrupt->id();
  corrupt.reset();
  WriteBytes(fs::relative(store_->sessions_dir() + "/" + corrupt_id + "/manifest.json", dir_),
             "{\"format\": \"craftscan-se");

  std::vector<std::string> problems;
  std::vector<std::string> marked = store_->MarkInterrupted(&problems);
  std::vector<std::string> expected{created, capturing, reconstructing};
  std::sort(expected.begin(), expected.end());
  EXPECT_EQ(marked, expected);
  ASSERT_EQ(problems.size(), 1u) << ::testing::PrintToString(problems);
  EXPECT_TRUE(Contains(problems[0], corrupt_id) && Contains(problems[0], "not valid JSON"))
      << problems[0];

  std::map<std::string, std::string> states;
  for (const auto& summary : store_->List()) states[summary.id] = summary.state;
  EXPECT_EQ(states[created], "interrupted");
  EXPECT_EQ(states[capturing], "interrupted");
  EXPECT_EQ(states[reconstructing], "interrupted");
  EXPECT_EQ(states[done], "done");
  EXPECT_EQ(states[failed], "failed");
  EXPECT_EQ(states[interrupted], "interrupted");
  EXPECT_EQ(states[live->id()], "capturing");
  EXPECT_EQ(states[corrupt_id], "corrupt");
  EXPECT_EQ(live->state(), SessionState::kCapturing);

  auto s = store_->OpenSession(reconstructing, StatusInto(&error));
  ASSERT_NE(s, nullptr) << error;
  const Manifest m = s->manifest();
  EXPECT_EQ(m.journal.back().event, "interrupted");
  EXPECT_EQ(m.journal.back().detail, "craftscand stopped while the session was reconstructing");
  EXPECT_EQ(m.error, m.journal.back().detail);
  // The interrupted journal entry of the already-interrupted session was not repeated.
  auto i = store_->OpenSession(interrupted, StatusInto(&error));
  ASSERT_NE(i, nullptr) << error;
  EXPECT_EQ(i->manifest().journal.size(), 2u);
  // Resume.
  EXPECT_TRUE(Ok(s->SetState(SessionState::kReconstructing, "resume"), &error)) << error;
  // The next start marks what was active then: the resumed one and the
  // live one, now that nobody holds them.
  s.reset();
  live.reset();
  expected = {reconstructing, live_id};
  std::sort(expected.begin(), expected.end());
  EXPECT_EQ(store_->MarkInterrupted(nullptr), expected);
}

TEST_F(SessionFiles, LeftoverTemporariesFromACrashDoNotConfuseLoadingAndAreCleanedUp) {
  auto s = NewCapturing("leftovers", 2);
  ASSERT_NE(s, nullptr);
  std::string error;
  ASSERT_TRUE(Capture(*s, 0, &error)) << error;
  const std::string id = s->id();
  const std::string dir = s->dir();
  s.reset();
  // What a crash in the middle of writes leaves: temporaries beside files
  // (WriteFileAtomically names), a half-created session folder, a view
  // folder whose files never became durable.
  const fs::path rel = fs::relative(dir, dir_);
  WriteBytes((rel / "views/000/.left.png.tmp-AbC123").string(), "half a PNG");
  WriteBytes((rel / ".manifest.json.tmp-XyZ789").string(), "{\"format\": \"craftscan-session\"");
  fs::create_directories(fs::path(dir) / "views/001");
  WriteBytes((rel / "views/001/.right.png.tmp-QQQQQQ").string(), "x");
  const fs::path half = fs::path(store_->sessions_dir()) / ".20240501-093000-x.tmp-Qw1234";
  fs::create_directories(half);
  WriteBytes(fs::relative(half / "manifest.json", dir_).string(), "{}");

  const auto list = store_->List();
  ASSERT_EQ(list.size(), 1u);
  EXPECT_EQ(list[0].id, id);
  EXPECT_EQ(list[0].views_captured, 1);
  EXPECT_TRUE(store_->Verify(id).IsIntact());
  auto again = store_->OpenSession(id, StatusInto(&error));
  ASSERT_NE(again, nullptr) << error;
  cv::Mat left, right;
  ASSERT_TRUE(again->LoadCapture(0, &left, &right, nullptr, &error)) << error;
  EXPECT_TRUE(BitExact(left, NoiseImage(40, 30, CV_8UC3, 0)));
  const ResumePoint resume = again->GetResumePoint(true);
  EXPECT_EQ(resume.to_capture, (std::vector<int>{1}));
  EXPECT_TRUE(resume.damaged.empty());
  again.reset();

  EXPECT_EQ(testing::CountTemporaries(store_->sessions_dir()), 4);
  store_->MarkInterrupted(nullptr);
  EXPECT_EQ(testing::CountTemporaries(store_->sessions_dir()), 0);
  EXPECT_FALSE(fs::exists(half));
  EXPECT_TRUE(store_->Verify(id).IsIntact());
}

TEST_F(SessionFiles, CorruptManifestsAreListedWithTheReasonNotFatal) {
  std::string error;
  const std::string good = NewCapturing("good", 1)->id();
  const std::string truncated = NewCapturing("truncated", 1)->id();
  const std::string missing = NewCapturing("missing", 1)->id();
  const std::string wrong_id = NewCapturing("wrongid", 1)->id();
  const fs::path sessions = store_->sessions_dir();
  const std::string text = ReadAll((sessions / truncated / "manifest.json").string());
  std::ofstream(sessions / truncated / "manifest.json") << text.substr(0, text.size() / 3);
  fs::remove(sessions / missing / "manifest.json");
  const std::string other = ReadAll((sessions / good / "manifest.json").string());
  std::ofstream(sessions / wrong_id / "manifest.json") << other;
  fs::create_directories(sessions / "notes");

  std::map<std::string, SessionSummary> by_id;
  for (const auto& summary : store_->List()) by_id[summary.id] = summary;
  ASSERT_EQ(by_id.size(), 5u);
  EXPECT_EQ(by_id[good].state, "capturing");
  EXPECT_EQ(by_id[good].object_name, "good");
  EXPECT_EQ(by_id[good].job, "scan");
  EXPECT_FALSE(by_id[good].created_utc.empty());
  EXPECT_EQ(by_id[truncated].state, "corrupt");
  EXPECT_TRUE(Contains(by_id[truncated].problem, "not valid JSON")) << by_id[truncated].problem;
  EXPECT_EQ(by_id[missing].state, "corrupt");
  EXPECT_TRUE(Contains(by_id[missing].problem, "No such file or directory"));
  EXPECT_EQ(by_id[wrong_id].state, "corrupt");
  EXPECT_TRUE(Contains(by_id[wrong_id].problem, "differs from the folder name"));
  EXPECT_EQ(by_id["notes"].state, "corrupt");
  EXPECT_TRUE(Contains(by_id["notes"].problem, "not a session id"));

  EXPECT_EQ(store_->OpenSession(truncated, StatusInto(&error)), nullptr);
  EXPECT_TRUE(Contains(error, "session " + truncated + " is corrupt") &&
              Contains(error, "manifest.json"))
      << error;
  EXPECT_FALSE(store_->Verify(truncated).IsIntact());
  EXPECT_FALSE(store_->Verify(truncated).manifest_ok);
  EXPECT_TRUE(store_->Verify(good).IsIntact());
  EXPECT_NE(store_->OpenSession(good, StatusInto(&error)), nullptr) << error;
}

TEST_F(SessionFiles, VerifyDetectsTruncatedModifiedAndMissingFiles) {
  auto s = NewCapturing("verify", 3);
  ASSERT_NE(s, nullptr);
  std::string error;
  for (int v = 0; v < 3; ++v) {
    ASSERT_TRUE(Capture(*s, v, &error)) << error;
    ASSERT_TRUE(Ok(s->StoreDisparity(v, NoiseImage(40, 30, CV_32FC1, 50 + v)), &error)) << error;
  }
  ASSERT_TRUE(s->Verify().IsIntact());
  const fs::path dir = s->dir();
  // Truncate view 0's left image, flip one byte of view 1's disparity map
  // (same size), delete view 2's meta.json.
  fs::resize_file(dir / "views/000/left.png", fs::file_size(dir / "views/000/left.png") - 10);
  {
    std::fstream f(dir / "views/001/disparity.pfm",
                   std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(-7, std::ios::end);
    const char c = static_cast<char>(f.get());
    f.seekp(-7, std::ios::end);
    f.put(static_cast<char>(c ^ 0x20));
  }
  fs::remove(dir / "views/002/meta.json");

  for (const VerifyResult& result : {s->Verify(), store_->Verify(s->id())}) {
    EXPECT_TRUE(result.manifest_ok);
    EXPECT_FALSE(result.IsIntact());
    ASSERT_EQ(result.problems.size(), 3u) << ::testing::PrintToString(result.problems);
    EXPECT_TRUE(Contains(result.problems[0], "views/000/left.png") &&
                Contains(result.problems[0], "truncated"))
        << result.problems[0];
    EXPECT_TRUE(Contains(result.problems[1], "views/001/disparity.pfm") &&
                Contains(result.problems[1], "checksum"))
        << result.problems[1];
    EXPECT_TRUE(Contains(result.problems[2], "views/002/meta.json") &&
                Contains(result.problems[2], "No such file"))
        << result.problems[2];
    EXPECT_EQ(result.files_checked, 3 * 4 - 1);
  }
  cv::Mat a, b;
  EXPECT_FALSE(s->LoadCapture(0, &a, &b, nullptr, &error));
  EXPECT_TRUE(Contains(error, "left.png") && Contains(error, "manifest says")) << error;
  EXPECT_FALSE(s->LoadDisparity(1, &a, &error));
  EXPECT_TRUE(Contains(error, "checksum differs")) << error;

  // Resume treats damaged files as not durable: recapture 0 and 2, rematch 1.
  const ResumePoint resume = s->GetResumePoint(true);
  EXPECT_EQ(resume.to_capture, (std::vector<int>{0, 2}));
  EXPECT_EQ(resume.next_capture, 0);
  EXPECT_EQ(resume.to_match, (std::vector<int>{1}));
  EXPECT_EQ(resume.damaged.size(), 3u);
  // Without verification the manifest alone says all is there.
  EXPECT_TRUE(s->GetResumePoint(false).to_capture.empty());
}

// Every "sha256" key below `j`, removed: a manifest as craftscand wrote it
// before SHA-256 (same format_version, FNV-1a 64 only).
void DropSha256(nlohmann::json* j) {
  if (j->is_object()) {
    j->erase("sha256");
    for (auto& [key, value] : j->items()) DropSha256(&value);
  } else if (j->is_array()) {
    for (auto& value : *j) DropSha256(&value);
  }
}

// A session with a calibration copy, two captures with disparity maps and
// two outputs; returns its id (the session is closed).
std::string FullSession(SessionStore& store, const std::string& rig_yaml, std::string* error) {
  auto s = store.Create("fixity", "scan", {{"views", 2}}, std::chrono::system_clock::now(),
                        StatusInto(error));
  if (!s || !Ok(s->SetState(SessionState::kCapturing, ""), error) ||
      !Ok(s->CopyCalibration(rig_yaml, "rig-a"), error)) {
    return "";
  }
  for (int v = 0; v < 2; ++v) {
    if (!Capture(*s, v, error) ||
        !Ok(s->StoreDisparity(v, NoiseImage(40, 30, CV_32FC1, 50 + v)), error)) {
      return "";
    }
  }
  if (!Ok(s->StoreOutput("fused.ply", "ply\nend_header\n"), error) ||
      !Ok(s->StoreOutput("previews/a.png", std::string(300, 'p')), error)) {
    return "";
  }
  return s->id();
}

TEST_F(SessionFiles, NewManifestsCarrySha256OfEveryFileAndVerifyIt) {
  WriteBytes("rig.yaml", "%YAML:1.0\nbaseline_mm: 60.25\n");
  std::string error;
  const std::string id = FullSession(*store_, Path("rig.yaml"), &error);
  ASSERT_FALSE(id.empty()) << error;
  const fs::path dir = fs::path(data_dir_) / "sessions" / id;
  // Read back as plain JSON: every record has a sha256 equal to the file's.
  const nlohmann::json j = nlohmann::json::parse(ReadAll((dir / "manifest.json").string()));
  std::map<std::string, std::string> listed;  // relative path → sha256
  listed["calibration.yaml"] = j["calibration"].value("sha256", "");
  for (const auto& view : j["views"]) {
    char folder[16];
    std::snprintf(folder, sizeof folder, "views/%03d/", view["index"].get<int>());
    for (const auto& [name, record] : view["files"].items()) {
      listed[folder + name] = record.value("sha256", "");
    }
  }
  for (const auto& [name, record] : j["outputs"].items()) listed[name] = record.value("sha256", "");
  EXPECT_EQ(listed.size(), 1u + 2 * 4 + 2);
  for (const auto& [relative, sha256] : listed) {
    EXPECT_EQ(sha256, Sha256Hex(ReadAll((dir / relative).string()))) << relative;
  }
  EXPECT_TRUE(store_->Verify(id).IsIntact());

  // One flipped byte in an output and one in the calibration copy (sizes
  // unchanged): each named, with SHA-256 as the check that caught it.
  WriteFileAtomically((dir / "previews/a.png").string(), std::string(299, 'p') + "q", &error);
  WriteFileAtomically((dir / "calibration.yaml").string(), "%YAML:1.0\nbaseline_mm: 60.26\n",
                      &error);
  const VerifyResult result = store_->Verify(id);
  ASSERT_EQ(result.problems.size(), 2u) << ::testing::PrintToString(result.problems);
  EXPECT_TRUE(
      Contains(result.problems[0], "calibration.yaml") &&
      Contains(result.problems[0], "SHA-256 " + Sha256Hex("%YAML:1.0\nbaseline_mm: 60.26\n")))
      << result.problems[0];
  EXPECT_TRUE(Contains(result.problems[1], "previews/a.png: checksum differs") &&
              Contains(result.problems[1], "the manifest says " + listed["previews/a.png"]))
      << result.problems[1];
}

TEST_F(SessionFiles, OldFnvOnlyManifestsLoadVerifyAndNameACorruptFile) {
  WriteBytes("rig.yaml", "%YAML:1.0\nbaseline_mm: 60.25\n");
  std::string error;
  const std::string id = FullSession(*store_, Path("rig.yaml"), &error);
  ASSERT_FALSE(id.empty()) << error;
  const fs::path dir = fs::path(data_dir_) / "sessions" / id;
  nlohmann::json j = nlohmann::json::parse(ReadAll((dir / "manifest.json").string()));
  DropSha256(&j);
  const std::string old_text = j.dump(2);
  ASSERT_EQ(old_text.find("sha256"), std::string::npos);
  ASSERT_NE(old_text.find("fnv1a64"), std::string::npos);
  ASSERT_TRUE(WriteFileAtomically((dir / "manifest.json").string(), old_text, &error)) << error;

  // Loads, verifies intact, its files load; records have no SHA-256.
  EXPECT_TRUE(store_->Verify(id).IsIntact())
      << ::testing::PrintToString(store_->Verify(id).problems);
  auto s = store_->OpenSession(id, StatusInto(&error));
  ASSERT_NE(s, nullptr) << error;
  EXPECT_TRUE(s->manifest().outputs.at("fused.ply").sha256.empty());
  EXPECT_EQ(s->manifest().outputs.at("fused.ply").fnv1a64, Fnv1a64("ply\nend_header\n"));
  cv::Mat left, right;
  EXPECT_TRUE(s->LoadCapture(1, &left, &right, nullptr, &error)) << error;

  // A modified file (same size) is named, caught by FNV-1a 64.
  WriteFileAtomically((dir / "fused.ply").string(), "ply\nend_headex\n", &error);
  const VerifyResult result = s->Verify();
  ASSERT_EQ(result.problems.size(), 1u) << ::testing::PrintToString(result.problems);
  EXPECT_TRUE(Contains(result.problems[0], "fused.ply: checksum differs") &&
              Contains(result.problems[0], "FNV-1a 64"))
      << result.problems[0];

  // A file stored into the old session gets a SHA-256; the old records
  // keep theirs (none) and still verify.
  ASSERT_TRUE(Ok(s->StoreOutput("report.json", "{}"), &error)) << error;
  EXPECT_EQ(s->manifest().outputs.at("report.json").sha256, Sha256Hex("{}"));
  EXPECT_TRUE(s->manifest().views.at(0).files.at(kLeftPng).sha256.empty());
}

TEST_F(SessionFiles, ResumePointNamesTheFirstStepNotYetDurable) {
  auto s = NewCapturing("resume", 5);
  ASSERT_NE(s, nullptr);
  std::string error;
  for (int v : {0, 1, 2, 4}) ASSERT_TRUE(Capture(*s, v, &error)) << error;
  for (int v : {0, 1}) ASSERT_TRUE(Ok(s->StoreDisparity(v, NoiseImage(8, 8, CV_32FC1, v)), &error));
  PointCloud cloud;
  cloud.points_mm = {{1, 2, 3}};
  ASSERT_TRUE(Ok(s->StoreCloud(0, cloud), &error)) << error;

  ResumePoint r = s->GetResumePoint(false);
  EXPECT_EQ(r.planned_views, 5);
  EXPECT_EQ(r.next_capture, 3);
  EXPECT_EQ(r.to_capture, (std::vector<int>{3}));
  EXPECT_EQ(r.to_match, (std::vector<int>{2, 4}));
  EXPECT_EQ(r.to_reproject, (std::vector<int>{1}));
  EXPECT_FALSE(r.CapturesComplete());

  // A new capture of view 1 makes its disparity stale; a new disparity of
  // view 0 makes its cloud stale.
  ASSERT_TRUE(Capture(*s, 1, &error)) << error;
  ASSERT_TRUE(Ok(s->StoreDisparity(0, NoiseImage(8, 8, CV_32FC1, 7)), &error)) << error;
  ASSERT_TRUE(Capture(*s, 3, &error)) << error;
  r = s->GetResumePoint(true);
  EXPECT_EQ(r.next_capture, 5);
  EXPECT_TRUE(r.to_capture.empty());
  EXPECT_TRUE(r.CapturesComplete());
  EXPECT_EQ(r.to_match, (std::vector<int>{1, 2, 3, 4}));
  EXPECT_EQ(r.to_reproject, (std::vector<int>{0}));

  // Derived files need a capture; indices are range-checked.
  EXPECT_FALSE(Ok(s->StoreDisparity(7, NoiseImage(8, 8, CV_32FC1, 1)), &error));
  EXPECT_TRUE(Contains(error, "view 7 has no durable capture")) << error;
  EXPECT_FALSE(Ok(s->StoreCloud(9, cloud), &error));
  EXPECT_FALSE(Capture(*s, 1000, &error));
  EXPECT_TRUE(Contains(error, "outside 0..999")) << error;
  EXPECT_FALSE(Capture(*s, -1, &error));

  // Without a planned view count the next capture is the first gap.
  auto open =
      store_->Create("open", "capture", nlohmann::json::object(), Clock::now(), StatusInto(&error));
  ASSERT_NE(open, nullptr) << error;
  ASSERT_TRUE(Ok(open->SetState(SessionState::kCapturing, ""), &error));
  for (int v : {0, 1, 3}) ASSERT_TRUE(Capture(*open, v, &error)) << error;
  r = open->GetResumePoint(false);
  EXPECT_EQ(r.planned_views, -1);
  EXPECT_EQ(r.next_capture, 2);
  EXPECT_TRUE(r.to_capture.empty());
  EXPECT_FALSE(r.CapturesComplete());
}

TEST_F(SessionFiles, BadInputsAndBadIdsGiveClearErrors) {
  auto s = NewCapturing("inputs", 2);
  ASSERT_NE(s, nullptr);
  std::string error;
  const cv::Mat ok = NoiseImage(8, 8, CV_8UC1, 1);
  EXPECT_FALSE(Ok(s->StoreCapture(0, 0, cv::Mat(), ok, Meta(0)), &error));
  EXPECT_TRUE(Contains(error, "left image is empty")) << error;
  EXPECT_FALSE(Ok(s->StoreCapture(0, 0, ok, NoiseImage(8, 8, CV_32FC1, 1), Meta(0)), &error));
  EXPECT_TRUE(Contains(error, "right image has type CV_32FC1")) << error;
  EXPECT_FALSE(Ok(s->StoreCapture(0, 0, ok, ok, nlohmann::json::array()), &error));
  EXPECT_TRUE(Contains(error, "meta is not a JSON object")) << error;
  ASSERT_TRUE(Ok(s->StoreCapture(0, 0, ok, ok, Meta(0)), &error)) << error;
  EXPECT_FALSE(Ok(s->StoreDisparity(0, NoiseImage(8, 8, CV_8UC1, 1)), &error));
  EXPECT_TRUE(Contains(error, "CV_32FC1")) << error;
  PointCloud bad;
  bad.points_mm = {{1, 2, 3}};
  bad.normals = {{0, 0, 1}, {0, 1, 0}};
  EXPECT_FALSE(Ok(s->StoreCloud(0, bad), &error));
  for (const char* name : {"../escape.txt", "/tmp/x", "manifest.json", "views/000/left.png"}) {
    EXPECT_FALSE(Ok(s->StoreOutput(name, "x"), &error)) << name;
    EXPECT_TRUE(Contains(error, "output name")) << error;
  }
  EXPECT_FALSE(fs::exists(fs::path(dir_) / "escape.txt"));
  EXPECT_FALSE(Ok(s->CopyCalibration(Path("nope.yaml"), "x"), &error));
  EXPECT_TRUE(Contains(error, "nope.yaml") && Contains(error, "No such file")) << error;
  // A writer that fails: its error is passed on and nothing is recorded.
  EXPECT_FALSE(Ok(s->StoreOutputWith("mesh.ply",
                                     [](const std::string&) {
                                       return Status(ErrorCode::kInternal, "mesher gave up");
                                     }),
                  &error));
  EXPECT_TRUE(Contains(error, "mesher gave up")) << error;
  EXPECT_TRUE(s->manifest().outputs.empty());
  // A store of the same output while one is in progress is refused.
  bool inner = true;
  ASSERT_TRUE(Ok(
      s->StoreOutputWith(
          "report.json",
          [&](const std::string& path) {
            const Status nested = s->StoreOutput("report.json", "{}");
            inner = nested.ok();
            EXPECT_EQ(nested.code(), ErrorCode::kFailedPrecondition);
            EXPECT_TRUE(Contains(nested.message(), "report.json is being stored by another call"))
                << nested.message();
            return WriteFileAtomically(path, "{}");
          }),
      &error))
      << error;
  EXPECT_FALSE(inner);

  for (const std::string id : {"../x", "a/b", "..", "", "20240501-093000-../../etc"}) {
    EXPECT_EQ(store_->OpenSession(id, StatusInto(&error)), nullptr) << id;
    EXPECT_TRUE(Contains(error, "invalid session id")) << error;
    EXPECT_FALSE(store_->Verify(id).IsIntact());
  }
  EXPECT_EQ(store_->OpenSession("20000101-000000-nothing", StatusInto(&error)), nullptr);
  EXPECT_TRUE(Contains(error, "unknown session 20000101-000000-nothing")) << error;
  EXPECT_EQ(store_->OpenSession(s->id(), StatusInto(&error)), nullptr);
  EXPECT_TRUE(Contains(error, "is open elsewhere")) << error;
  const std::string id = s->id();
  s.reset();
  EXPECT_NE(store_->OpenSession(id, StatusInto(&error)), nullptr) << error;
}

// The refusals that are not the disk's carry their own codes, so the daemon
// never gives storage advice for them.
TEST_F(SessionFiles, RefusalsCarryTheirCodes) {
  Status status;
  EXPECT_EQ(SessionStore::Open("", &status), nullptr);
  EXPECT_EQ(status.code(), ErrorCode::kInvalidArgument) << status.ToString();
  EXPECT_EQ(SessionStore::Open(Path("missing"), &status), nullptr);
  EXPECT_EQ(status.code(), ErrorCode::kNotFound) << status.ToString();
  WriteBytes("plain", "x");
  EXPECT_EQ(SessionStore::Open(Path("plain"), &status), nullptr);
  EXPECT_EQ(status.code(), ErrorCode::kInvalidArgument) << status.ToString();
  EXPECT_EQ(store_->Create("egg", "Scan!", nlohmann::json::object(), Clock::now(), &status),
            nullptr);
  EXPECT_EQ(status.code(), ErrorCode::kInvalidArgument) << status.ToString();
  EXPECT_EQ(store_->OpenSession("../etc", &status), nullptr);
  EXPECT_EQ(status.code(), ErrorCode::kInvalidArgument) << status.ToString();
  EXPECT_EQ(store_->OpenSession("20000101-000000-nothing", &status), nullptr);
  EXPECT_EQ(status.code(), ErrorCode::kNotFound) << status.ToString();

  auto s = NewCapturing("codes", 2);
  ASSERT_NE(s, nullptr);
  EXPECT_EQ(store_->OpenSession(s->id(), &status), nullptr);  // held by `s`
  EXPECT_EQ(status.code(), ErrorCode::kFailedPrecondition) << status.ToString();
  EXPECT_EQ(s->StoreDisparity(0, NoiseImage(8, 8, CV_32FC1, 1)).code(),
            ErrorCode::kFailedPrecondition);  // no capture yet
  EXPECT_EQ(s->StoreDisparity(0, NoiseImage(8, 8, CV_8UC1, 1)).code(), ErrorCode::kInvalidArgument);
  EXPECT_EQ(
      s->StoreCapture(-1, 0, NoiseImage(8, 8, CV_8UC1, 1), NoiseImage(8, 8, CV_8UC1, 1), Meta(0))
          .code(),
      ErrorCode::kInvalidArgument);
  EXPECT_EQ(s->StoreOutput("../escape.txt", "x").code(), ErrorCode::kInvalidArgument);
  EXPECT_EQ(s->CopyCalibration(Path("nope.yaml"), "x").code(), ErrorCode::kNotFound);
  ASSERT_TRUE(s->SetState(SessionState::kDone, "").ok());
  const Status refused = s->SetState(SessionState::kCapturing, "");
  EXPECT_EQ(refused.code(), ErrorCode::kFailedPrecondition) << refused.ToString();
  EXPECT_TRUE(Contains(refused.message(), "cannot go from done to capturing")) << refused.message();
  EXPECT_EQ(s->StoreOutput("report.json", "{}").code(), ErrorCode::kFailedPrecondition);
}

TEST_F(SessionFiles, StoresOfDistinctViewsRunConcurrently) {
  constexpr int kThreads = 4;
  constexpr int kViewsPerThread = 6;
  auto s = NewCapturing("threads", kThreads * kViewsPerThread);
  ASSERT_NE(s, nullptr);
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < kViewsPerThread; ++i) {
        const int view = t + kThreads * i;
        std::string error;
        PointCloud cloud;
        cloud.points_mm = {{static_cast<float>(view), 0, 0}};
        if (!Capture(*s, view, &error) ||
            !Ok(s->StoreDisparity(view, NoiseImage(16, 8, CV_32FC1, view)), &error) ||
            !Ok(s->StoreCloud(view, cloud), &error)) {
          ADD_FAILURE() << error;
          ++failures;
        }
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(failures, 0);
  const ResumePoint r = s->GetResumePoint(true);
  EXPECT_TRUE(r.CapturesComplete());
  EXPECT_TRUE(r.to_match.empty() && r.to_reproject.empty() && r.damaged.empty());
  EXPECT_EQ(s->DurableViews().size(), static_cast<std::size_t>(kThreads * kViewsPerThread));
  // The manifest on disk holds every view (no lost update).
  const std::string id = s->id();
  s.reset();
  std::string error;
  auto back = store_->OpenSession(id, StatusInto(&error));
  ASSERT_NE(back, nullptr) << error;
  EXPECT_EQ(back->manifest().views.size(), static_cast<std::size_t>(kThreads * kViewsPerThread));
  for (const auto& [index, view] : back->manifest().views) EXPECT_EQ(view.files.size(), 5u);
}

}  // namespace
}  // namespace craftscan::daemon
