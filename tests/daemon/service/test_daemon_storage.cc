// craftscand when its data directory fails it: a full disk and a read-only
// data directory, while the daemon runs and at its start. The real daemon
// on the simulated station (320x256 images, no mesh), its data directory a
// small tmpfs in a private mount namespace of the test thread (craftscand
// and craftscanctl are started from that thread, so they share it; nothing
// is visible outside, and it goes with the test process).
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sched.h>
#include <sys/mount.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "../sessions/status_util.h"
#include "craftscan/client/station_client.h"
#include "craftscan/daemon/session_store.h"
#include "ctl_runner.h"
#include "daemon_fixture.h"
#include "private_mount.h"
#include "station_client.h"

using craftscan::testing::Ok;
using craftscan::testing::StatusInto;

namespace craftscan::testing {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using daemon::SessionState;
using testing::EnterPrivateMountNamespace;
using testing::ScopedTmpfs;

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// One test's station: the mount namespace, the tmpfs data directory, the
// daemon (320x256, no mesh), a command client and a status watch.
class StorageStation {
 public:
  // extra_sim: more sim driver keys (DaemonFixture).
  explicit StorageStation(std::string extra_sim = "") : fixture_("320x256", std::move(extra_sim)) {
    fixture_.pipeline_extra = ", mesh: false";
  }
  ~StorageStation() {
    // The daemon leaves before its data directory does.
    fixture_.Stop(SIGKILL);
  }

  DaemonFixture& fixture() { return fixture_; }
  StationClient& client() { return client_; }
  StatusWatcher& watch() { return watch_; }
  ScopedTmpfs& tmpfs() { return *tmpfs_; }
  std::string data_dir() const { return fixture_.data_dir(); }

  // Enters the namespace and mounts a tmpfs of `size` on the data directory
  // (none with an empty `size`), then writes the config and calibration. ""
  // or why to skip; a failure after the namespace exists is a test failure
  // (*error).
  std::string Setup(const std::string& size, std::string* error) {
    if (!size.empty()) {
      const std::string why = EnterPrivateMountNamespace();
      if (!why.empty()) return why;
      tmpfs_ = std::make_unique<ScopedTmpfs>(data_dir(), size);
      if (!tmpfs_->error().empty()) return tmpfs_->error();
    }
    std::error_code ec;
    if (!fs::create_directories(data_dir() + "/calibration", ec) && ec) {
      *error = "mkdir " + data_dir() + "/calibration: " + ec.message();
    } else if (!fixture_.Prepare(error)) {
      *error = "prepare: " + *error;
    }
    return {};
  }

  // Starts the daemon and both clients and waits for discovery.
  bool Start(std::string* error, bool notify = false) {
    if (!fixture_.Start(error, 0, notify)) return false;
    if (!client_started_) {
      if (!client_.Start(fixture_.domain(), fixture_.dds_config(), fixture_.station(), error) ||
          !watch_.Start(fixture_.domain(), fixture_.station(), error)) {
        return false;
      }
      client_started_ = true;
    }
    if (!client_.WaitForDaemon(30s)) {
      *error = "the daemon's command reader never matched; log:\n" + fixture_.Log();
      return false;
    }
    return true;
  }

  // Sends a command; the reply, or a record with code_name "no reply".
  ReplyRecord Send(const std::string& verb, const nlohmann::json& args, const std::string& token) {
    auto reply = client_.Send(verb, args, token, 20s);
    if (!reply) return ReplyRecord{-1, "no reply", "", {}};
    return *reply;
  }

  // Starts `verb` (scan, capture, resume) and waits for the job's end.
  nlohmann::json RunJob(const std::string& verb, const nlohmann::json& args,
                        std::chrono::seconds timeout = 180s) {
    const ReplyRecord reply = Send(verb, args, kOperatorToken);
    if (reply.code_name != "ok") {
      return {{"state", "refused"}, {"message", reply.code_name + ": " + reply.message}};
    }
    nlohmann::json job =
        WaitForJobEnd(client_, kObserverToken, reply.result.value("id", ""), timeout);
    job["session"] = reply.result.value("session", "");
    return job;
  }

  // Runs craftscanctl with `args` against this station (observer token).
  CtlRun Ctl(const std::vector<std::string>& args) {
    std::vector<std::string> all = {
        "--station",    fixture_.station(),    "--domain",  std::to_string(fixture_.domain()),
        "--dds-config", fixture_.dds_config(), "--timeout", "20",
        "--token",      kObserverToken};
    all.insert(all.end(), args.begin(), args.end());
    CtlProcess process(fixture_.root(), "ctl" + std::to_string(++ctl_runs_), all);
    return process.Wait(60s);
  }

  // The views of `session` whose captures were acknowledged (published).
  std::set<int> Acknowledged(const std::string& session) {
    auto lock = client_.Lock();
    std::set<int> views;
    for (const CaptureRecord& c : client_.captures) {
      if (c.session == session) views.insert(c.view);
    }
    return views;
  }

 private:
  DaemonFixture fixture_;
  std::unique_ptr<ScopedTmpfs> tmpfs_;  // unmounted before the fixture removes its folder
  StationClient client_;
  StatusWatcher watch_;
  bool client_started_ = false;
  int ctl_runs_ = 0;
};

// StorageStation::Setup in a test: skips without a namespace, fails on errors.
#define SETUP_STATION(station, size)                              \
  do {                                                            \
    std::string setup_error;                                      \
    const std::string skip = (station).Setup(size, &setup_error); \
    if (!skip.empty()) GTEST_SKIP() << skip;                      \
    ASSERT_TRUE(setup_error.empty()) << setup_error;              \
  } while (false)

// What the test process finds on disk: the session's state, whether every
// listed file is intact, and its durable views.
struct OnDisk {
  std::string state = "unreadable";
  std::string error;  // manifest error, or why it could not be read
  bool intact = false;
  std::vector<int> durable;
  int temporaries = 0;  // leftover ".x.tmp-XXXXXX" files in its folder
};

OnDisk Inspect(const std::string& data_dir, const std::string& id) {
  OnDisk out;
  auto store = daemon::SessionStore::Open(data_dir, StatusInto(&out.error));
  if (!store) return out;
  const daemon::VerifyResult verify = store->Verify(id);
  out.intact = verify.IsIntact();
  if (!verify.problems.empty()) out.error = verify.problems[0];
  auto session = store->OpenSession(id, StatusInto(&out.error));
  if (!session) return out;
  out.state = daemon::ToString(session->state());
  if (out.error.empty()) out.error = session->manifest().error;
  out.durable = session->DurableViews();
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(session->dir(), ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    const std::string name = it->path().filename().string();
    out.temporaries += name.size() > 12 && name[0] == '.' && Contains(name, ".tmp-");
  }
  return out;
}

std::uint64_t FreeBytes(const std::string& dir) {
  struct statvfs st {};
  if (::statvfs(dir.c_str(), &st) != 0) return 0;
  return static_cast<std::uint64_t>(st.f_bavail) * st.f_frsize;
}

// Bytes allocated to the files below `dir`.
std::uint64_t AllocatedBytes(const std::string& dir) {
  std::uint64_t total = 0;
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(dir, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    struct stat st {};
    if (::lstat(it->path().c_str(), &st) == 0)
      total += static_cast<std::uint64_t>(st.st_blocks) * 512;
  }
  return total;
}

// A file of `bytes` allocated bytes at `path`. "" or what failed.
std::string Fill(const std::string& path, std::uint64_t bytes) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) return "open " + path + ": " + std::strerror(errno);
  const int rc = ::posix_fallocate(fd, 0, static_cast<off_t>(bytes));
  ::close(fd);
  return rc == 0 ? "" : "fallocate " + path + ": " + std::strerror(rc);
}

const std::string kNoSpace = std::strerror(ENOSPC);
const std::string kReadOnly = std::strerror(EROFS);

// The disk fills during a scan: the job fails naming it, the session is
// interrupted with every acknowledged capture intact, earlier sessions are
// untouched, the daemon keeps serving; once space is freed, resume
// completes the session without recapturing anything.
TEST(DaemonStorage, DiskFullInterruptsTheScanAndResumeCompletesItOnceSpaceIsFreed) {
  StorageStation station;
  SETUP_STATION(station, "40m");
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  const std::string data_dir = station.data_dir();

  // An earlier scan, complete.
  const nlohmann::json earlier = station.RunJob("scan", {{"object", "earlier"}, {"views", 4}});
  ASSERT_EQ(earlier.value("state", ""), "done") << earlier.dump() << station.fixture().Log();
  const std::string earlier_id = earlier["session"];

  // Fill the disk up to about 2.5 views (files and manifest rewrites).
  const std::uint64_t view_bytes =
      AllocatedBytes(data_dir + "/sessions/" + earlier_id + "/views/000");
  ASSERT_GT(view_bytes, 100000u);
  const std::uint64_t budget = view_bytes * 5 / 2 + 64 * 1024;
  const std::uint64_t free_before = FreeBytes(data_dir);
  ASSERT_GT(free_before, budget + (4u << 20)) << "tmpfs too small";
  const std::string filler = data_dir + "/filler";
  ASSERT_EQ(Fill(filler, free_before - budget), "");
  std::printf("one view takes %.0f kB; %.0f kB left free for an 8-view scan\n", view_bytes / 1e3,
              FreeBytes(data_dir) / 1e3);

  const nlohmann::json full = station.RunJob("scan", {{"object", "filler"}, {"views", 8}});
  const std::string id = full.value("session", "");
  ASSERT_FALSE(id.empty()) << full.dump();
  const std::string message = full.value("message", "");
  ASSERT_EQ(full.value("state", ""), "failed") << full.dump() << station.fixture().Log();
  EXPECT_TRUE(Contains(message, kNoSpace)) << message;
  EXPECT_TRUE(Contains(message, "disk full: free space in the data directory '" + data_dir + "'"))
      << message;
  EXPECT_TRUE(Contains(message, "resume " + id)) << message;
  std::printf("the scan stopped with: %s\nthe reserve was %s to record its end\n", message.c_str(),
              Contains(station.fixture().Log(), "freed the reserve") ? "freed" : "not needed");
  const std::set<int> acknowledged = station.Acknowledged(id);
  EXPECT_GE(acknowledged.size(), 1u) << "the budget should hold at least one view";
  EXPECT_LT(acknowledged.size(), 8u);

  // The reason reached every channel: the Reply to status, the job's last
  // JobProgress, StationStatus and craftscanctl.
  const ReplyRecord status = station.Send("status", nullptr, kObserverToken);
  ASSERT_EQ(status.code_name, "ok") << status.message;
  EXPECT_TRUE(Contains(status.result.value("last_error", ""), kNoSpace)) << status.result.dump();
  EXPECT_EQ(status.result.value("state", ""), "idle") << status.result.dump();
  {
    auto lock = station.client().Lock();
    const auto& progress = station.client().progress;
    bool found = false;
    for (std::size_t i = 0; i < progress.size(); ++i) {
      found |= progress[i].second == "failed" &&
               Contains(station.client().progress_messages[i], kNoSpace);
    }
    EXPECT_TRUE(found) << "no JobProgress 'failed' naming the full disk";
  }
  EXPECT_TRUE(station.watch().WaitForLatest(
      [&](const client::StatusUpdate& s) { return Contains(s.last_error, kNoSpace); }, 10s))
      << station.watch().Last().last_error;
  const CtlRun ctl = station.Ctl({"status"});
  EXPECT_EQ(ctl.exit_code, 0) << ctl.err;
  EXPECT_TRUE(Contains(ctl.out, kNoSpace)) << ctl.out << ctl.err;

  // The daemon keeps serving: sessions and get answer correctly.
  const ReplyRecord sessions = station.Send("sessions", nullptr, kObserverToken);
  ASSERT_EQ(sessions.code_name, "ok") << sessions.message;
  std::map<std::string, std::string> states;
  for (const nlohmann::json& s : sessions.result["sessions"]) states[s["id"]] = s["state"];
  EXPECT_EQ(states[earlier_id], "done");
  EXPECT_EQ(states[id], "interrupted");
  const ReplyRecord get = station.Send("get", {{"session", earlier_id}}, kObserverToken);
  ASSERT_EQ(get.code_name, "ok") << get.message;
  EXPECT_EQ(get.result.value("intact", false), true) << get.result.dump();

  // On disk: the earlier session untouched, every acknowledged capture of
  // this one durable and intact, nothing half-written left.
  const OnDisk before = Inspect(data_dir, earlier_id);
  EXPECT_EQ(before.state, "done");
  EXPECT_TRUE(before.intact) << before.error;
  OnDisk interrupted = Inspect(data_dir, id);
  EXPECT_EQ(interrupted.state, "interrupted") << interrupted.error;
  EXPECT_TRUE(interrupted.intact) << interrupted.error;
  EXPECT_TRUE(Contains(interrupted.error, kNoSpace)) << interrupted.error;
  EXPECT_EQ(interrupted.temporaries, 0);
  for (int view : acknowledged) {
    EXPECT_TRUE(std::count(interrupted.durable.begin(), interrupted.durable.end(), view))
        << "acknowledged view " << view << " is not durable";
  }

  // Space freed: resume completes the session and recaptures nothing.
  ASSERT_EQ(::unlink(filler.c_str()), 0);
  std::size_t captures_before = 0;
  {
    auto lock = station.client().Lock();
    captures_before = station.client().captures.size();
  }
  const nlohmann::json resumed = station.RunJob("resume", {{"session", id}});
  ASSERT_EQ(resumed.value("state", ""), "done") << resumed.dump() << station.fixture().Log();
  {
    auto lock = station.client().Lock();
    const auto& captures = station.client().captures;
    for (std::size_t i = captures_before; i < captures.size(); ++i) {
      EXPECT_FALSE(acknowledged.count(captures[i].view))
          << "view " << captures[i].view << " was captured again";
    }
  }
  const OnDisk done = Inspect(data_dir, id);
  EXPECT_EQ(done.state, "done");
  EXPECT_TRUE(done.intact) << done.error;
  EXPECT_EQ(done.durable, (std::vector<int>{0, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_TRUE(Inspect(data_dir, earlier_id).intact);
}

// The disk fills up completely while a capture waits for its frame (the
// sim camera takes 4 s), so even the manifest entry recording the end
// finds no space: the daemon frees the reserve it keeps for that, the
// session is still marked interrupted, and resume completes it later.
TEST(DaemonStorage, ACaptureOnACompletelyFullDiskIsStillRecordedInterrupted) {
  StorageStation station(", stall_ms: 4000");
  SETUP_STATION(station, "20m");
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  const std::string data_dir = station.data_dir();
  const ReplyRecord capture = station.Send("capture", {{"object", "stalled"}}, kOperatorToken);
  ASSERT_EQ(capture.code_name, "ok") << capture.message;
  const std::string job_id = capture.result["id"];
  const std::string id = capture.result["session"];
  ASSERT_TRUE(station.client().WaitFor(
      [&](StationClient& c) {
        return std::count(c.progress.begin(), c.progress.end(),
                          std::make_pair(job_id, std::string("capture"))) > 0;
      },
      30s));
  const std::string filler = data_dir + "/filler";
  ASSERT_EQ(Fill(filler, FreeBytes(data_dir)), "");
  EXPECT_EQ(FreeBytes(data_dir), 0u);

  const nlohmann::json job = WaitForJobEnd(station.client(), kObserverToken, job_id, 60s);
  const std::string message = job.value("message", "");
  ASSERT_EQ(job.value("state", ""), "failed") << job.dump() << station.fixture().Log();
  EXPECT_TRUE(Contains(message, "session " + id + " interrupted: view 0: ")) << message;
  EXPECT_TRUE(Contains(message, kNoSpace)) << message;
  EXPECT_TRUE(Contains(station.fixture().Log(),
                       "disk full: freed the reserve to mark session " + id + " interrupted"))
      << station.fixture().Log();
  EXPECT_TRUE(station.Acknowledged(id).empty());
  ASSERT_EQ(::unlink(filler.c_str()), 0);
  const OnDisk stopped = Inspect(data_dir, id);
  EXPECT_EQ(stopped.state, "interrupted") << stopped.error;
  EXPECT_TRUE(stopped.intact) << stopped.error;
  EXPECT_TRUE(stopped.durable.empty());
  EXPECT_EQ(stopped.temporaries, 0);

  const nlohmann::json resumed = station.RunJob("resume", {{"session", id}});
  ASSERT_EQ(resumed.value("state", ""), "done") << resumed.dump() << station.fixture().Log();
  const OnDisk done = Inspect(data_dir, id);
  EXPECT_EQ(done.state, "done");
  EXPECT_TRUE(done.intact) << done.error;
  EXPECT_EQ(done.durable, std::vector<int>{0});
}

// The data directory turns read-only while the daemon serves (a disk
// remounted read-only after an error): the running scan stops naming it,
// new work is refused naming it, everything stored stays intact and the
// daemon keeps serving; once writable again, resume completes the scan.
TEST(DaemonStorage, DataDirTurningReadOnlyStopsTheScanClearlyAndResumeCompletesIt) {
  StorageStation station;
  SETUP_STATION(station, "40m");
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  const std::string data_dir = station.data_dir();
  const nlohmann::json earlier = station.RunJob("capture", {{"object", "earlier"}});
  ASSERT_EQ(earlier.value("state", ""), "done") << earlier.dump() << station.fixture().Log();
  const std::string earlier_id = earlier["session"];

  // A 12-view scan; read-only once its first capture is acknowledged.
  const ReplyRecord scan = station.Send("scan", {{"object", "egg"}, {"views", 12}}, kOperatorToken);
  ASSERT_EQ(scan.code_name, "ok") << scan.message;
  const std::string id = scan.result["session"];
  ASSERT_TRUE(station.client().WaitFor(
      [&](StationClient& c) {
        return std::any_of(c.captures.begin(), c.captures.end(),
                           [&](const CaptureRecord& r) { return r.session == id; });
      },
      60s))
      << station.fixture().Log();
  ASSERT_TRUE(station.tmpfs().SetReadOnly(true, &error)) << error;
  const nlohmann::json job =
      WaitForJobEnd(station.client(), kObserverToken, scan.result["id"], 120s);
  const std::string message = job.value("message", "");
  ASSERT_EQ(job.value("state", ""), "failed") << job.dump() << station.fixture().Log();
  EXPECT_TRUE(Contains(message, kReadOnly)) << message;
  EXPECT_TRUE(Contains(message, "the data directory '" + data_dir + "' is read-only")) << message;
  std::printf("the scan stopped with: %s\n", message.c_str());
  const std::set<int> acknowledged = station.Acknowledged(id);
  EXPECT_LT(acknowledged.size(), 12u);

  // New work is refused naming the problem; the rest is served.
  for (const char* verb : {"capture", "scan"}) {
    const ReplyRecord refused = station.Send(verb, {{"object", "more"}}, kOperatorToken);
    EXPECT_EQ(refused.code_name, "failed") << verb << ": " << refused.message;
    EXPECT_TRUE(Contains(refused.message, data_dir + "/sessions")) << refused.message;
    EXPECT_TRUE(Contains(refused.message, kReadOnly)) << refused.message;
  }
  const ReplyRecord status = station.Send("status", nullptr, kObserverToken);
  ASSERT_EQ(status.code_name, "ok") << status.message;
  EXPECT_TRUE(Contains(status.result.value("last_error", ""), kReadOnly)) << status.result.dump();
  const ReplyRecord sessions = station.Send("sessions", nullptr, kObserverToken);
  ASSERT_EQ(sessions.code_name, "ok") << sessions.message;
  EXPECT_EQ(sessions.result["sessions"].size(), 2u) << sessions.result.dump();
  const ReplyRecord get = station.Send("get", {{"session", earlier_id}}, kObserverToken);
  ASSERT_EQ(get.code_name, "ok") << get.message;
  EXPECT_EQ(get.result.value("intact", false), true) << get.result.dump();
  const ReplyRecord get_scan = station.Send("get", {{"session", id}}, kObserverToken);
  ASSERT_EQ(get_scan.code_name, "ok") << get_scan.message;
  EXPECT_EQ(get_scan.result.value("intact", false), true) << get_scan.result.dump();

  // Writable again: everything acknowledged is there, and resume finishes.
  ASSERT_TRUE(station.tmpfs().SetReadOnly(false, &error)) << error;
  const OnDisk stopped = Inspect(data_dir, id);
  EXPECT_TRUE(stopped.intact) << stopped.error;
  for (int view : acknowledged) {
    EXPECT_TRUE(std::count(stopped.durable.begin(), stopped.durable.end(), view))
        << "acknowledged view " << view << " is not durable";
  }
  EXPECT_TRUE(Inspect(data_dir, earlier_id).intact);
  // Its end could not be written (read-only), so it is still "capturing" on
  // disk; resume takes it all the same.
  EXPECT_TRUE(stopped.state == "capturing" || stopped.state == "interrupted") << stopped.state;
  const nlohmann::json resumed = station.RunJob("resume", {{"session", id}});
  ASSERT_EQ(resumed.value("state", ""), "done") << resumed.dump() << station.fixture().Log();
  const OnDisk done = Inspect(data_dir, id);
  EXPECT_EQ(done.state, "done");
  EXPECT_TRUE(done.intact) << done.error;
  EXPECT_EQ(done.durable.size(), 12u);
}

// craftscand started on a read-only data directory serves degraded: ready
// with the reason, status and devices answered, storage verbs refused with
// `unavailable` naming the directory and the error; it opens the store by
// itself once the directory is writable (and marks the unfinished session
// it finds interrupted).
TEST(DaemonStorage, StartsDegradedOnAReadOnlyDataDirAndRecoversWhenItIsWritable) {
  StorageStation station;
  SETUP_STATION(station, "20m");
  const std::string data_dir = station.data_dir();
  std::string error, left_over;
  {
    auto store = daemon::SessionStore::Open(data_dir, StatusInto(&error));
    ASSERT_TRUE(store) << error;
    auto session = store->Create("left over", "scan", {{"views", 2}, {"step_deg", 180.0}},
                                 std::chrono::system_clock::now(), StatusInto(&error));
    ASSERT_TRUE(session) << error;
    ASSERT_TRUE(Ok(session->SetState(SessionState::kCapturing, ""), &error)) << error;
    left_over = session->id();
  }
  ASSERT_TRUE(station.tmpfs().SetReadOnly(true, &error)) << error;
  ASSERT_TRUE(station.Start(&error, /*notify=*/true)) << error;

  FakeNotifySocket& manager = station.fixture().notify();
  const auto ready = manager.WaitFor("READY=1", 30s);
  ASSERT_TRUE(ready) << station.fixture().Log();
  const std::string ready_status = ready->Value("STATUS").value_or("");
  EXPECT_EQ(ready_status.rfind("degraded: ", 0), 0u) << ready_status;
  EXPECT_TRUE(Contains(ready_status, data_dir)) << ready_status;
  EXPECT_TRUE(Contains(ready_status, kReadOnly)) << ready_status;
  EXPECT_TRUE(station.watch().WaitForLatest(
      [&](const client::StatusUpdate& s) {
        return s.state == "degraded" && Contains(s.last_error, kReadOnly);
      },
      20s))
      << station.watch().Last().state << ": " << station.watch().Last().last_error;

  const ReplyRecord status = station.Send("status", nullptr, kObserverToken);
  ASSERT_EQ(status.code_name, "ok") << status.message;
  EXPECT_EQ(status.result.value("state", ""), "degraded");
  EXPECT_EQ(status.result["storage"].value("ok", true), false) << status.result.dump();
  EXPECT_TRUE(Contains(status.result["storage"].value("error", ""), kReadOnly));
  const ReplyRecord devices = station.Send("devices", nullptr, kObserverToken);
  ASSERT_EQ(devices.code_name, "ok") << devices.message;
  EXPECT_EQ(devices.result["devices"].size(), 2u);
  const ReplyRecord move =
      station.Send("turntable", {{"action", "move"}, {"angle_deg", 30}}, kOperatorToken);
  EXPECT_EQ(move.code_name, "ok") << move.message;
  struct Refused {
    const char* verb;
    nlohmann::json args;
    const char* token;
  };
  const std::vector<Refused> refusals = {
      {"scan", {{"object", "box"}, {"views", 4}}, kOperatorToken},
      {"capture", {{"object", "box"}}, kOperatorToken},
      {"resume", {{"session", left_over}}, kOperatorToken},
      {"calibrate", nullptr, kAdminToken},
      {"sessions", nullptr, kObserverToken},
      {"get", {{"session", left_over}}, kObserverToken},
  };
  for (const Refused& r : refusals) {
    const ReplyRecord reply = station.Send(r.verb, r.args, r.token);
    EXPECT_EQ(reply.code_name, "unavailable") << r.verb << ": " << reply.message;
    EXPECT_TRUE(Contains(reply.message, data_dir)) << r.verb << ": " << reply.message;
    EXPECT_TRUE(Contains(reply.message, kReadOnly)) << r.verb << ": " << reply.message;
  }
  const CtlRun ctl = station.Ctl({"status"});
  EXPECT_EQ(ctl.exit_code, 0) << ctl.err;
  EXPECT_TRUE(Contains(ctl.out, "degraded")) << ctl.out;
  EXPECT_TRUE(Contains(ctl.out, kReadOnly)) << ctl.out;

  // Writable: within one retry (10 s) the station is idle and serves sessions.
  ASSERT_TRUE(station.tmpfs().SetReadOnly(false, &error)) << error;
  const auto writable = std::chrono::steady_clock::now();
  EXPECT_TRUE(station.watch().WaitForLatest(
      [&](const client::StatusUpdate& s) { return s.state == "idle" && s.last_error.empty(); },
      30s))
      << station.watch().Last().state << ": " << station.watch().Last().last_error;
  std::printf("store opened %.1f s after the directory became writable\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - writable).count());
  manager.Drain();
  const ReplyRecord sessions = station.Send("sessions", nullptr, kObserverToken);
  ASSERT_EQ(sessions.code_name, "ok") << sessions.message;
  ASSERT_EQ(sessions.result["sessions"].size(), 1u) << sessions.result.dump();
  EXPECT_EQ(sessions.result["sessions"][0].value("state", ""), "interrupted");
  const nlohmann::json capture = station.RunJob("capture", {{"object", "after"}});
  EXPECT_EQ(capture.value("state", ""), "done") << capture.dump() << station.fixture().Log();
  manager.Drain();
  EXPECT_TRUE(Inspect(data_dir, capture.value("session", "")).intact);
}

// A data directory that does not exist yet (a disk not mounted at boot):
// degraded until it appears, then the calibration in it is loaded and
// captures work. No namespace needed.
TEST(DaemonStorage, StartsDegradedWithoutItsDataDirAndRecoversWhenItAppears) {
  StorageStation station;
  SETUP_STATION(station, "");
  const std::string data_dir = station.data_dir();
  fs::rename(data_dir, data_dir + ".later");
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  ASSERT_TRUE(station.watch().WaitForLatest(
      [](const client::StatusUpdate& s) { return s.state == "degraded"; }, 20s))
      << station.fixture().Log();
  const ReplyRecord refused =
      station.Send("scan", {{"object", "box"}, {"views", 4}}, kOperatorToken);
  EXPECT_EQ(refused.code_name, "unavailable") << refused.message;
  EXPECT_TRUE(Contains(refused.message, data_dir)) << refused.message;
  EXPECT_TRUE(Contains(refused.message, std::strerror(ENOENT))) << refused.message;
  EXPECT_EQ(station.Send("status", nullptr, kObserverToken).result.value("calibration_id", "x"),
            "");

  fs::rename(data_dir + ".later", data_dir);
  ASSERT_TRUE(station.watch().WaitForLatest(
      [](const client::StatusUpdate& s) { return s.state == "idle" && s.last_error.empty(); }, 30s))
      << station.fixture().Log();
  const ReplyRecord status = station.Send("status", nullptr, kObserverToken);
  EXPECT_EQ(status.result.value("calibration_id", ""), "current") << status.result.dump();
  const nlohmann::json capture = station.RunJob("capture", {{"object", "box"}});
  EXPECT_EQ(capture.value("state", ""), "done") << capture.dump() << station.fixture().Log();
}

// A bad configuration stays a hard failure: exit code 2, naming the problem,
// before anything is served.
TEST(DaemonStorage, ABadConfigIsStillRefusedAtStart) {
  DaemonFixture fixture("320x256");
  std::string error;
  ASSERT_TRUE(fixture.Prepare(&error, /*with_calibration=*/false)) << error;
  std::ofstream(fixture.root() + "/craftscand.yaml", std::ios::app) << "pipeline: [unclosed\n";
  ASSERT_TRUE(fixture.Start(&error)) << error;
  // Wait for the exit without reaping, so that Stop collects the status.
  siginfo_t info{};
  const auto deadline = std::chrono::steady_clock::now() + 30s;
  while (std::chrono::steady_clock::now() < deadline) {
    info.si_pid = 0;
    if (::waitid(P_PID, static_cast<id_t>(fixture.pid()), &info, WEXITED | WNOHANG | WNOWAIT) ==
            0 &&
        info.si_pid != 0) {
      break;
    }
    std::this_thread::sleep_for(20ms);
  }
  ASSERT_NE(info.si_pid, 0) << "craftscand still runs with a bad config:\n" << fixture.Log();
  const int status = fixture.Stop(SIGKILL);
  ASSERT_TRUE(WIFEXITED(status)) << fixture.Log();
  EXPECT_EQ(WEXITSTATUS(status), 2) << fixture.Log();
  EXPECT_TRUE(Contains(fixture.Log(), "craftscand.yaml")) << fixture.Log();
}

}  // namespace
}  // namespace craftscan::testing
