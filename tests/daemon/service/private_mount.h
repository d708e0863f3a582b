// A private mount namespace and a small tmpfs in it, for tests that fill or
// remount a data directory without touching the host (the disk-full stage
// tests, the daemon's storage tests).
#pragma once

#include <sched.h>
#include <sys/mount.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>

namespace craftscan::testing {

// Moves the calling thread into a private mount namespace: directly as root,
// else through a new user namespace (which needs a single-threaded process,
// as at the start of a test). Processes started from this thread afterwards
// share it. Returns "" or why not (the test then skips).
inline std::string EnterPrivateMountNamespace() {
  if (::unshare(CLONE_NEWNS) != 0) {
    const uid_t uid = ::geteuid();
    const gid_t gid = ::getegid();
    if (::unshare(CLONE_NEWUSER | CLONE_NEWNS) != 0) {
      return std::string("no mount namespace (unshare: ") + std::strerror(errno) + ")";
    }
    std::ofstream("/proc/self/setgroups") << "deny";
    std::ofstream("/proc/self/uid_map") << "0 " << uid << " 1";
    std::ofstream("/proc/self/gid_map") << "0 " << gid << " 1";
  }
  // Private, so that nothing mounted here propagates to the host.
  if (::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0) {
    return std::string("cannot make mounts private: ") + std::strerror(errno);
  }
  return {};
}

// A tmpfs of `size` ("16m") on `dir` (an existing folder) for the life of
// the object; unmounted lazily, so a child still inside cannot keep it.
class ScopedTmpfs {
 public:
  ScopedTmpfs(std::string dir, const std::string& size) : dir_(std::move(dir)) {
    const std::string options = "size=" + size + ",mode=0755";
    if (::mount("craftscan-test", dir_.c_str(), "tmpfs", 0, options.c_str()) != 0) {
      error_ = "mount tmpfs on " + dir_ + ": " + std::strerror(errno);
      return;
    }
    mounted_ = true;
  }
  ~ScopedTmpfs() {
    if (mounted_) ::umount2(dir_.c_str(), MNT_DETACH);
  }
  ScopedTmpfs(const ScopedTmpfs&) = delete;
  ScopedTmpfs& operator=(const ScopedTmpfs&) = delete;

  const std::string& error() const { return error_; }

  // Remounts it read-only or read-write. A read-only remount is refused
  // (EBUSY) while a file on it is open for writing: tried again every
  // millisecond for up to `patience`.
  bool SetReadOnly(bool read_only, std::string* error,
                   std::chrono::milliseconds patience = std::chrono::seconds(20)) {
    const unsigned long flags = MS_REMOUNT | MS_BIND | (read_only ? MS_RDONLY : 0);
    const auto deadline = std::chrono::steady_clock::now() + patience;
    for (;;) {
      if (::mount(nullptr, dir_.c_str(), nullptr, flags, nullptr) == 0) return true;
      if (errno != EBUSY || std::chrono::steady_clock::now() > deadline) {
        *error = std::string("remount ") + (read_only ? "ro" : "rw") + " " + dir_ + ": " +
                 std::strerror(errno);
        return false;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }

 private:
  std::string dir_, error_;
  bool mounted_ = false;
};

}  // namespace craftscan::testing
