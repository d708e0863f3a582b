// Helpers for the session store tests: deterministic images, bit-exact
// comparison, a store in a fresh folder, and running a scenario in a forked
// child with its own mount namespace (read-only bind mounts, small tmpfs).
#pragma once

#include <fcntl.h>
#include <sched.h>
#include <sys/mount.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "craftscan/daemon/session_store.h"
#include "status_util.h"
#include "test_util.h"

using craftscan::testing::Ok;
using craftscan::testing::StatusInto;

namespace craftscan::daemon::testing {

using Clock = std::chrono::system_clock;

// A reproducible noise image (incompressible: PNG cannot shrink it much).
// Uses cv::randu only (single-threaded), so it is safe in a forked child.
inline cv::Mat NoiseImage(int width, int height, int type, std::uint64_t seed) {
  cv::Mat image(height, width, type);
  cv::RNG rng(seed + 1);
  const double high = CV_MAT_DEPTH(type) == CV_16U ? 65536.0 : 256.0;
  rng.fill(image, cv::RNG::UNIFORM, 0.0, high);
  return image;
}

// True iff a and b have the same size, type and bytes.
inline bool BitExact(const cv::Mat& a, const cv::Mat& b) {
  if (a.size() != b.size() || a.type() != b.type()) return false;
  for (int y = 0; y < a.rows; ++y) {
    if (std::memcmp(a.ptr(y), b.ptr(y), a.cols * a.elemSize()) != 0) return false;
  }
  return true;
}

inline std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

inline bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

// Counts WriteFileAtomically temporaries (".x.tmp-XXXXXX") below `dir`.
inline int CountTemporaries(const std::filesystem::path& dir) {
  int n = 0;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(dir, ec);
       !ec && it != std::filesystem::end(it); it.increment(ec)) {
    const std::string name = it->path().filename().string();
    n += name.size() > 12 && name[0] == '.' && name.find(".tmp-") != std::string::npos;
  }
  return n;
}

// A fixture with a data dir and an open store in it.
class SessionFiles : public craftscan::testing::TempDirTest {
 protected:
  void SetUp() override {
    TempDirTest::SetUp();
    data_dir_ = Path("data");
    std::filesystem::create_directories(data_dir_);
    std::string error;
    store_ = SessionStore::Open(data_dir_, StatusInto(&error));
    ASSERT_NE(store_, nullptr) << error;
  }

  // A session in state capturing, for the object `object`.
  std::unique_ptr<Session> NewCapturing(const std::string& object, int views = 4) {
    std::string error;
    auto session = store_->Create(object, "scan", {{"views", views}, {"step_deg", 90.0}},
                                  std::chrono::system_clock::now(), StatusInto(&error));
    EXPECT_NE(session, nullptr) << error;
    if (session) {
      EXPECT_TRUE(Ok(session->SetState(SessionState::kCapturing, ""), &error)) << error;
    }
    return session;
  }

  std::string data_dir_;
  std::unique_ptr<SessionStore> store_;
};

// Outcome of RunInMountNamespace.
struct ChildOutcome {
  bool skipped = false;
  std::string message;  // skip reason, or failures ("" = passed)
};

// Forks; the child enters a private mount namespace (as root directly, else
// through a user namespace), runs `setup` (mounts; returns "" or why it
// could not, which skips) and then `body` (returns "" on success or what
// failed), and reports through a pipe. Nothing the child mounts is visible
// outside it, and it all disappears when the child exits. Use only
// fork-safe code in the child (no OpenCV parallel_for, no gtest asserts).
inline ChildOutcome RunInMountNamespace(const std::function<std::string()>& setup,
                                        const std::function<std::string()>& body) {
  int fds[2];
  if (::pipe(fds) != 0) return {false, std::string("pipe: ") + std::strerror(errno)};
  const pid_t pid = ::fork();
  if (pid < 0) return {false, std::string("fork: ") + std::strerror(errno)};
  if (pid == 0) {
    ::close(fds[0]);
    const auto report = [&](const std::string& text) {
      const char* p = text.data();
      std::size_t left = text.size();
      while (left > 0) {
        const ssize_t n = ::write(fds[1], p, left);
        if (n <= 0) break;
        p += n;
        left -= static_cast<std::size_t>(n);
      }
      ::_exit(0);
    };
    if (::unshare(CLONE_NEWNS) != 0) {
      const uid_t uid = ::geteuid();
      const gid_t gid = ::getegid();
      if (::unshare(CLONE_NEWUSER | CLONE_NEWNS) != 0) {
        report(std::string("SKIP:no mount namespace (unshare: ") + std::strerror(errno) + ")");
      }
      std::ofstream("/proc/self/setgroups") << "deny";
      std::ofstream("/proc/self/uid_map") << "0 " << uid << " 1";
      std::ofstream("/proc/self/gid_map") << "0 " << gid << " 1";
    }
    if (::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0) {
      report(std::string("SKIP:cannot make mounts private: ") + std::strerror(errno));
    }
    const std::string why = setup();
    if (!why.empty()) report("SKIP:" + why);
    report(body());
  }
  ::close(fds[1]);
  std::string text;
  char buffer[4096];
  for (;;) {
    const ssize_t n = ::read(fds[0], buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    text.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fds[0]);
  int status = 0;
  ::waitpid(pid, &status, 0);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    return {false, "child died (status " + std::to_string(status) + ") after: " + text};
  }
  if (text.rfind("SKIP:", 0) == 0) return {true, text.substr(5)};
  return {false, text};
}

}  // namespace craftscan::daemon::testing
