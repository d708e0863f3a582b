// Faults the session store must survive: a read-only data dir, a full disk
// (a small tmpfs in a private mount namespace) and SIGKILL at random moments
// while captures are being stored.
#include <gtest/gtest.h>

#include <grp.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <sstream>

#include "session_test_util.h"
#include "status_util.h"

using craftscan::testing::Ok;
using craftscan::testing::StatusInto;

namespace craftscan::daemon {
namespace {

namespace fs = std::filesystem;
using namespace testing;  // NOLINT(build/namespaces): the helpers of session_test_util.h

// Collects failures in a forked child (where gtest assertions cannot report).
class Failures {
 public:
  void Check(bool ok, const std::string& what) {
    if (!ok) out_ << what << "\n";
  }
  std::string str() const { return out_.str(); }

 private:
  std::ostringstream out_;
};

std::string Mount(const char* source, const std::string& target, const char* type,
                  unsigned long flags, const char* options) {
  if (::mount(source, target.c_str(), type, flags, options) == 0) return {};
  return "mount " + std::string(type ? type : "(bind)") + " on " + target + ": " +
         std::strerror(errno);
}

// What a read-only data dir must do: refuse new work with a clear message
// naming the path and the reason, and change nothing.
std::string ReadOnlyScenario(SessionStore& store, const std::string& data_dir,
                             const std::string& id) {
  Failures f;
  std::string error;
  const bool root = ::geteuid() == 0;
  const std::string reason = root ? "Read-only file system" : "Permission denied";
  // The code travels from the failing system call: EROFS (a read-only
  // mount) or EACCES (permissions).
  const ErrorCode code = root ? ErrorCode::kReadOnly : ErrorCode::kPermissionDenied;
  const auto check_code = [&](const Status& status, const std::string& what) {
    f.Check(status.code() == code, what + " code: " + status.ToString());
    if (!status.ok()) error = status.message();
    return status.ok();
  };
  Status status;
  f.Check(SessionStore::Open(data_dir, &status) == nullptr, "Open succeeded on a read-only dir");
  check_code(status, "Open");
  f.Check(Contains(error, "is not writable") && Contains(error, reason), "Open error: " + error);
  f.Check(store.Create("more", "scan", nlohmann::json::object(), Clock::now(), &status) == nullptr,
          "Create succeeded");
  check_code(status, "Create");
  f.Check(Contains(error, store.sessions_dir()) && Contains(error, reason),
          "Create error: " + error);
  auto session = store.OpenSession(id, StatusInto(&error));  // reading works
  f.Check(session != nullptr, "OpenSession failed: " + error);
  if (!session) return f.str();
  const bool stored =
      check_code(session->StoreCapture(1, 90.0, NoiseImage(32, 24, CV_8UC1, 5),
                                       NoiseImage(32, 24, CV_8UC1, 6), {{"view", 1}}),
                 "StoreCapture");
  f.Check(!stored, "StoreCapture succeeded");
  f.Check(Contains(error, "capture of view 1") && Contains(error, "views/001") &&
              Contains(error, reason),
          "StoreCapture error: " + error);
  f.Check(!check_code(session->SetState(SessionState::kFailed, "x"), "SetState"),
          "SetState succeeded");
  f.Check(Contains(error, "cannot update the manifest") && Contains(error, "manifest.json") &&
              Contains(error, reason),
          "SetState error: " + error);
  f.Check(session->state() == SessionState::kCapturing, "state changed in memory");
  f.Check(!check_code(session->StoreOutput("report.json", "{}"), "StoreOutput") &&
              Contains(error, reason),
          "StoreOutput error: " + error);
  f.Check(!check_code(session->StoreDisparity(0, cv::Mat(4, 4, CV_32FC1, cv::Scalar(1))),
                      "StoreDisparity"),
          "StoreDisparity succeeded");
  PointCloud cloud;
  cloud.points_mm = {{1, 2, 3}};
  f.Check(!check_code(session->StoreCloud(0, cloud), "StoreCloud"), "StoreCloud succeeded");
  cv::Mat left, right;
  f.Check(session->LoadCapture(0, &left, &right, nullptr, &error), "LoadCapture: " + error);
  f.Check(BitExact(left, NoiseImage(32, 24, CV_8UC1, 1)), "view 0 changed");
  return f.str();
}

// Stores view 0 with the images the scenarios check; "" or what failed.
std::string StoreViewZero(Session& s) {
  std::string error;
  Ok(s.StoreCapture(0, 0.0, NoiseImage(32, 24, CV_8UC1, 1), NoiseImage(32, 24, CV_8UC1, 2),
                    {{"view", 0}}),
     &error);
  return error;
}

TEST_F(SessionFiles, ReadOnlyDataDirFailsClearlyAndLeavesEarlierFilesIntact) {
  auto s = NewCapturing("readonly", 2);
  ASSERT_NE(s, nullptr);
  ASSERT_EQ(StoreViewZero(*s), "");
  const std::string id = s->id();
  const std::string manifest_path = s->dir() + "/manifest.json";
  const std::string before = ReadAll(manifest_path);
  s.reset();

  std::string failures;
  if (::geteuid() != 0) {
    // An ordinary user: permissions stop writes.
    const fs::path dirs[] = {store_->sessions_dir(), fs::path(store_->sessions_dir()) / id,
                             fs::path(store_->sessions_dir()) / id / "views"};
    for (const auto& d : dirs) fs::permissions(d, fs::perms(0555));
    failures = ReadOnlyScenario(*store_, data_dir_, id);
    for (const auto& d : dirs) fs::permissions(d, fs::perms(0755));
  } else {
    // Root ignores permissions: a read-only bind mount of the data dir in a
    // private mount namespace (gone when the child exits).
    const testing::ChildOutcome outcome = testing::RunInMountNamespace(
        [&] {
          std::string why = Mount(data_dir_.c_str(), data_dir_, nullptr, MS_BIND, nullptr);
          if (why.empty()) {
            why = Mount(nullptr, data_dir_, nullptr, MS_BIND | MS_REMOUNT | MS_RDONLY, nullptr);
          }
          return why;
        },
        [&] { return ReadOnlyScenario(*store_, data_dir_, id); });
    if (outcome.skipped) GTEST_SKIP() << "read-only bind mount unavailable: " << outcome.message;
    failures = outcome.message;
  }
  EXPECT_EQ(failures, "");
  // Back outside: nothing changed.
  EXPECT_EQ(ReadAll(manifest_path), before);
  EXPECT_TRUE(store_->Verify(id).IsIntact());
  EXPECT_FALSE(fs::exists(fs::path(store_->sessions_dir()) / id / "views/001"));
  EXPECT_EQ(testing::CountTemporaries(data_dir_), 0);
  EXPECT_EQ(store_->List().size(), 1u);
}

// Fills the file system holding `dir` (creates `dir`/filler until ENOSPC).
bool FillUp(const std::string& dir) {
  const int fd = ::open((dir + "/filler").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  if (fd < 0) return false;
  const std::string chunk(4096, 'f');
  while (::write(fd, chunk.data(), chunk.size()) > 0) {
  }
  const bool full = errno == ENOSPC;
  ::close(fd);
  return full;
}

std::string DiskFullScenario(const std::string& data_dir, const std::string& calibration) {
  Failures f;
  std::string error;
  Status status;
  auto store = SessionStore::Open(data_dir, StatusInto(&error));
  f.Check(store != nullptr, "Open: " + error);
  if (!store) return f.str();
  auto s = store->Create("full", "scan", {{"views", 3}}, Clock::now(), StatusInto(&error));
  f.Check(s != nullptr, "Create: " + error);
  if (!s) return f.str();
  f.Check(Ok(s->SetState(SessionState::kCapturing, ""), &error), "SetState: " + error);
  f.Check(Ok(s->CopyCalibration(calibration, "rig"), &error), "CopyCalibration: " + error);
  const cv::Mat small_left = NoiseImage(40, 30, CV_8UC3, 1);
  const cv::Mat small_right = NoiseImage(40, 30, CV_8UC3, 2);
  f.Check(Ok(s->StoreCapture(0, 0.0, small_left, small_right, {{"view", 0}}), &error),
          "capture 0: " + error);
  const std::string manifest_before = ReadAll(s->dir() + "/manifest.json");

  // Two incompressible 256×256 colour images (~197 KB each as PNG) do not
  // fit in what is left of 320 KiB.
  const auto full = [&](const Status& status, const std::string& what) {
    f.Check(status.code() == ErrorCode::kDiskFull, what + " code: " + status.ToString());
    if (!status.ok()) error = status.message();
    return status.ok();
  };
  const bool stored = full(s->StoreCapture(1, 120.0, NoiseImage(256, 256, CV_8UC3, 3),
                                           NoiseImage(256, 256, CV_8UC3, 4), {{"view", 1}}),
                           "capture 1");
  f.Check(!stored, "capture 1 fit on the small disk");
  f.Check(Contains(error, "No space left on device") && Contains(error, s->dir() + "/views/001/"),
          "capture 1 error: " + error);
  f.Check(s->DurableViews() == std::vector<int>{0}, "durable views changed");
  f.Check(ReadAll(s->dir() + "/manifest.json") == manifest_before, "manifest changed");
  f.Check(fs::is_empty(s->dir() + "/views/001"), "the failed capture left files behind");
  f.Check(s->Verify().IsIntact(), "Verify after capture 1");
  cv::Mat left, right;
  f.Check(s->LoadCapture(0, &left, &right, nullptr, &error), "LoadCapture 0: " + error);
  f.Check(BitExact(left, small_left) && BitExact(right, small_right), "view 0 not bit-exact");

  // Completely full: the manifest itself cannot be rewritten. State changes,
  // outputs and even a recapture of view 0 (which first unlists it) fail
  // without touching what is there.
  f.Check(FillUp(data_dir), "could not fill the disk");
  f.Check(!full(s->SetState(SessionState::kFailed, "disk full"), "SetState"),
          "SetState on a full disk");
  f.Check(Contains(error, "cannot update the manifest") && Contains(error, "No space left"),
          "SetState error: " + error);
  f.Check(s->state() == SessionState::kCapturing, "state changed in memory");
  f.Check(!full(s->StoreOutput("report.json", std::string(8192, 'r')), "StoreOutput") &&
              Contains(error, "No space left on device") && Contains(error, "report.json"),
          "StoreOutput error: " + error);
  f.Check(!full(s->StoreCapture(0, 0.0, small_left, small_right, {{"view", 0}}), "recapture"),
          "recapture on a full disk");
  f.Check(!full(s->StoreDisparity(0, NoiseImage(64, 64, CV_32FC1, 9)), "StoreDisparity"),
          "disparity on a full disk");
  f.Check(store->Create("more", "scan", nlohmann::json::object(), Clock::now(), &status) == nullptr,
          "Create on a full disk");
  full(status, "Create");
  f.Check(ReadAll(s->dir() + "/manifest.json") == manifest_before, "manifest changed");
  f.Check(s->Verify().IsIntact(), "Verify on a full disk");
  f.Check(testing::CountTemporaries(data_dir) == 0, "temporaries left behind");

  // Space again: the job can record its failure.
  fs::remove(data_dir + "/filler");
  f.Check(Ok(s->SetState(SessionState::kFailed, "disk was full"), &error), "SetState: " + error);
  const std::string id = s->id();
  s.reset();
  auto again = store->OpenSession(id, StatusInto(&error));
  f.Check(again && again->state() == SessionState::kFailed && again->Verify().IsIntact(),
          "reopen: " + error);
  return f.str();
}

TEST_F(SessionFiles, FullDiskFailsClearlyAndLeavesEarlierFilesIntact) {
  const std::string small = Path("small");
  fs::create_directories(small);
  WriteBytes("rig.yaml", "baseline_mm: 60\n");
  const testing::ChildOutcome outcome = testing::RunInMountNamespace(
      [&] { return Mount("tmpfs", small, "tmpfs", 0, "size=320k,mode=0755"); },
      [&] { return DiskFullScenario(small, Path("rig.yaml")); });
  if (outcome.skipped) GTEST_SKIP() << "no small tmpfs: " << outcome.message;
  EXPECT_EQ(outcome.message, "");
  EXPECT_TRUE(fs::is_empty(small));  // the tmpfs never showed outside the child
}

// Child of the crash test: resumes the session and stores the captures that
// are missing, reporting each acknowledged view index through `ack_fd`.
[[noreturn]] void CaptureLoop(SessionStore& store, const std::string& id, int ack_fd) {
  std::string error;
  auto s = store.OpenSession(id, StatusInto(&error));
  if (!s) ::_exit(2);
  if (s->state() != SessionState::kCapturing &&
      !Ok(s->SetState(SessionState::kCapturing, "resume"), &error)) {
    ::_exit(3);
  }
  for (const int view : s->GetResumePoint(false).to_capture) {
    if (!Ok(s->StoreCapture(view, view * 10.0, NoiseImage(64, 48, CV_8UC3, 2 * view),
                            NoiseImage(64, 48, CV_8UC3, 2 * view + 1), {{"view", view}}),
            &error)) {
      ::_exit(4);
    }
    if (::write(ack_fd, &view, sizeof view) != sizeof view) ::_exit(5);
  }
  ::_exit(0);
}

// A folder the daemon may not write in (EACCES): every write path reports
// kPermissionDenied, none kIoError, and nothing changes. Root ignores
// permission bits, so as root the scenario runs in a child that has
// dropped to an unprivileged user (uid/gid 65534) in a private mount
// namespace; it is skipped when that is not possible.
std::string PermissionDeniedScenario(SessionStore& store, const std::string& data_dir,
                                     const std::string& id) {
  Failures f;
  const auto denied = [&](const Status& status, const std::string& what) {
    f.Check(status.code() == ErrorCode::kPermissionDenied, what + " code: " + status.ToString());
    f.Check(Contains(status.message(), "Permission denied"),
            what + " message: " + status.message());
  };
  Status status;
  f.Check(SessionStore::Open(data_dir, &status) == nullptr, "Open succeeded");
  denied(status, "Open");
  f.Check(store.Create("more", "scan", nlohmann::json::object(), Clock::now(), &status) == nullptr,
          "Create succeeded");
  denied(status, "Create");
  auto session = store.OpenSession(id, &status);  // reading works
  f.Check(session != nullptr, "OpenSession failed: " + status.ToString());
  if (!session) return f.str();
  denied(session->StoreCapture(1, 90.0, NoiseImage(32, 24, CV_8UC1, 5),
                               NoiseImage(32, 24, CV_8UC1, 6), {{"view", 1}}),
         "StoreCapture");
  denied(session->SetState(SessionState::kFailed, "x"), "SetState");
  denied(session->StoreOutput("report.json", "{}"), "StoreOutput");
  f.Check(session->state() == SessionState::kCapturing, "state changed in memory");
  return f.str();
}

TEST_F(SessionFiles, PermissionDeniedFolderGivesPermissionDenied) {
  auto s = NewCapturing("denied", 2);
  ASSERT_NE(s, nullptr);
  ASSERT_EQ(StoreViewZero(*s), "");
  const std::string id = s->id();
  const std::string before = ReadAll(s->dir() + "/manifest.json");
  s.reset();
  // Readable and searchable by anyone, writable by no one but root.
  const fs::path dirs[] = {store_->sessions_dir(), fs::path(store_->sessions_dir()) / id,
                           fs::path(store_->sessions_dir()) / id / "views"};
  for (const auto& d : dirs) fs::permissions(d, fs::perms(0555));
  std::string failures;
  bool skipped = false;
  std::string skip_reason;
  if (::geteuid() != 0) {
    failures = PermissionDeniedScenario(*store_, data_dir_, id);
  } else {
    const testing::ChildOutcome outcome = testing::RunInMountNamespace(
        [&]() -> std::string {
          // Every folder above the data dir must be searchable by the user.
          for (fs::path p = fs::path(data_dir_); p != p.root_path(); p = p.parent_path()) {
            struct stat st {};
            if (::stat(p.c_str(), &st) != 0 || (st.st_mode & S_IXOTH) == 0) {
              // (Built with append: GCC 12 warns falsely on `"'" + string`, PR 105651.)
              std::string why("'");
              return why.append(p.string()).append("' is not searchable by an unprivileged user");
            }
          }
          if (::setgroups(0, nullptr) != 0 || ::setresgid(65534, 65534, 65534) != 0 ||
              ::setresuid(65534, 65534, 65534) != 0) {
            return std::string("cannot drop to uid 65534: ") + std::strerror(errno);
          }
          return std::string();
        },
        [&] { return PermissionDeniedScenario(*store_, data_dir_, id); });
    skipped = outcome.skipped;
    skip_reason = outcome.message;
    failures = outcome.message;
  }
  for (const auto& d : dirs) fs::permissions(d, fs::perms(0755));
  if (skipped) GTEST_SKIP() << "no unprivileged child: " << skip_reason;
  EXPECT_EQ(failures, "");
  EXPECT_EQ(ReadAll(fs::path(store_->sessions_dir()) / id / "manifest.json"), before);
  EXPECT_TRUE(store_->Verify(id).IsIntact());
  EXPECT_EQ(testing::CountTemporaries(data_dir_), 0);
}

TEST_F(SessionFiles, SigkillAtRandomMomentsNeverLosesAnAcknowledgedCapture) {
  constexpr int kViews = 36;
  constexpr int kRounds = 10;
  auto created = NewCapturing("crash", kViews);
  ASSERT_NE(created, nullptr);
  const std::string id = created->id();
  created.reset();

  const unsigned seed = std::random_device{}();
  SCOPED_TRACE("seed " + std::to_string(seed));
  std::mt19937 rng(seed);
  std::set<int> acked;
  int killed_mid_write = 0;   // kills that left a temporary file behind
  int killed_before_ack = 0;  // kills between a durable manifest entry and its ack
  bool finished = false;
  for (int round = 0; round < kRounds && !finished; ++round) {
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::close(fds[0]);
      CaptureLoop(*store_, id, fds[1]);
    }
    ::close(fds[1]);
    // Let it acknowledge 0..2 captures, then kill it within the next ~60 ms
    // (a capture takes a few tens of ms here, mostly fsync): inside a PNG
    // write, an fsync, the manifest rename, before the acknowledgement...
    const int wait_for = std::uniform_int_distribution<int>(0, 2)(rng);
    int view = 0;
    for (int i = 0; i < wait_for && ::read(fds[0], &view, sizeof view) == sizeof view; ++i) {
      acked.insert(view);
    }
    ::usleep(std::uniform_int_distribution<int>(0, 60000)(rng));
    ::kill(pid, SIGKILL);
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    // Acknowledgements sent before the kill are still in the pipe.
    while (::read(fds[0], &view, sizeof view) == sizeof view) acked.insert(view);
    ::close(fds[0]);
    if (WIFEXITED(status)) {
      ASSERT_EQ(WEXITSTATUS(status), 0) << "child failed in round " << round;
      finished = true;
    }
    killed_mid_write += testing::CountTemporaries(store_->sessions_dir()) > 0;

    // What the daemon does on restart, then what resume does.
    store_->MarkInterrupted(nullptr);
    const VerifyResult verify = store_->Verify(id);
    ASSERT_TRUE(verify.IsIntact())
        << "round " << round << ": " << ::testing::PrintToString(verify.problems);
    std::string error;
    auto s = store_->OpenSession(id, StatusInto(&error));
    ASSERT_NE(s, nullptr) << error;
    EXPECT_EQ(s->state(), SessionState::kInterrupted);  // marked on "restart", even if finished
    const std::vector<int> durable = s->DurableViews();
    const std::set<int> durable_set(durable.begin(), durable.end());
    for (const int v : acked) {
      ASSERT_TRUE(durable_set.count(v)) << "acknowledged view " << v << " lost in round " << round;
      cv::Mat left, right;
      nlohmann::json meta;
      ASSERT_TRUE(s->LoadCapture(v, &left, &right, &meta, &error)) << error;
      EXPECT_TRUE(BitExact(left, NoiseImage(64, 48, CV_8UC3, 2 * v))) << "view " << v;
      EXPECT_TRUE(BitExact(right, NoiseImage(64, 48, CV_8UC3, 2 * v + 1))) << "view " << v;
      EXPECT_EQ(meta["view"], v);
    }
    // Durable but not acknowledged: at most the one being acknowledged when killed.
    EXPECT_LE(durable.size(), acked.size() + 1);
    killed_before_ack += durable.size() > acked.size();
    if (durable.size() > acked.size()) {  // the child resumes from what is durable
      for (const int v : durable) acked.insert(v);
    }
  }
  EXPECT_FALSE(acked.empty());
  std::cout << "[ figures  ] " << acked.size() << " captures acknowledged over the kills, "
            << killed_mid_write << " kills left a temporary behind, " << killed_before_ack
            << " came between a durable capture and its acknowledgement, finished: " << finished
            << "\n";
}

}  // namespace
}  // namespace craftscan::daemon
